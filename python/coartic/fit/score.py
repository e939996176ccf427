"""How well a fitted table predicts recordings it was not fitted on (issue 10: tables that carry over).

``score_utterances(table, utterances)`` evaluates the table on loaded utterances and gives the
RMSE per utterance, per phoneme (the samples inside that phoneme's segments) and per channel,
each both as measured and after removing a per-utterance offset (a recorded channel is measured
from a rest reference estimated once per utterance: a constant error over a whole utterance says
little about the model). Per channel also after *calibrating* the speaker: a + b·prediction with
(a, b) fitted by linear least squares on the scored data themselves, what a table fitted on other
speakers can do for a new one given a little of their speech. ``speaker`` maps the predictions by
one of the table's own speakers (``coartic.speakers``: the fit's a_s + b_s·F, or their own
targets); without it a table fitted with speakers predicts its population (a = 0, b = 1, the
table's targets). ``score_recordings`` loads recordings first, with the label map the table
records (``coartic fit`` records its spec's), so corpus labels are mapped as in the fit.

``Score.save(out)`` writes ``score_channels.csv``, ``score_utterances.csv``,
``score_phonemes.csv``, ``score.txt`` and three figures: measured against predicted, residual over
time, RMSE per phoneme. ``coartic score`` is the command over these functions.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.model import Utterance, evaluate_corpus
from coartic.table import ParameterTable

F64 = NDArray[np.float64]


@dataclass
class Score:
    """Predictions of one table on some utterances; every figure computed from ``residuals``."""

    table: ParameterTable
    channels: tuple[str, ...]
    utterances: list[Utterance]
    predicted: dict[str, list[F64]]  # channel -> one array per utterance
    notes: list[str] = field(default_factory=list)
    speaker: str | None = None  # the table's speaker whose mapping the predictions carry

    def calibration(self, channel: str) -> tuple[float, float]:
        """(a, b) of measured ≈ a + b·predicted over every valid sample of ``channel``: the speaker
        calibrated on its own data (``coartic.fit.problem.affine_coefficients``)."""
        from coartic.fit.problem import affine_coefficients

        f = np.concatenate(self.predicted[channel])
        y = np.concatenate([u.observed[channel] for u in self.utterances]).astype(np.float64)
        ok = np.concatenate([u.valid[channel] for u in self.utterances]) & np.isfinite(y) & np.isfinite(f)
        a, b = affine_coefficients(np.zeros(f.size, dtype=np.int64), 1, ok.astype(np.float64),
                                   np.where(ok, f, 0.0), np.where(ok, y, 0.0))
        return float(a[0]), float(b[0])

    def residuals(self, channel: str, u: int, offset: bool = False) -> F64:
        """Predicted − measured for utterance ``u`` (NaN where not measured); with ``offset``, minus
        its mean over the utterance (the per-utterance offset removed)."""
        utt = self.utterances[u]
        r = np.where(utt.valid[channel], self.predicted[channel][u] - utt.observed[channel], np.nan)
        if offset and np.isfinite(r).any():
            r = r - np.nanmean(r)
        return r

    def offset(self, channel: str, u: int) -> float:
        r = self.residuals(channel, u)
        return float(np.nanmean(r)) if np.isfinite(r).any() else float("nan")

    # ------------------------------------------------------------------ tables
    def utterance_rows(self) -> list[dict[str, Any]]:
        rows = []
        for ch in self.channels:
            for u, utt in enumerate(self.utterances):
                r, ro = self.residuals(ch, u), self.residuals(ch, u, offset=True)
                n = int(np.isfinite(r).sum())
                rows.append({"channel": ch, "utterance": utt.name, "file": utt.meta.get("file", ""), "samples": n,
                             "rmse_mm": _rms(r), "rmse_offset_removed_mm": _rms(ro), "offset_mm": self.offset(ch, u)})
        return rows

    def phoneme_rows(self) -> list[dict[str, Any]]:
        """Per channel and phoneme, over the samples inside that phoneme's segments."""
        rows = []
        for ch in self.channels:
            acc: dict[str, list[float]] = {}
            for u, utt in enumerate(self.utterances):
                r, ro = self.residuals(ch, u), self.residuals(ch, u, offset=True)
                seg = segment_of(utt)
                for i, lab in enumerate(utt.labels):
                    m = (seg == i) & np.isfinite(r)
                    a = acc.setdefault(lab, [0.0, 0.0, 0.0])
                    a[0] += float(np.sum(r[m] ** 2))
                    a[1] += float(np.sum(ro[m] ** 2))
                    a[2] += float(m.sum())
            for lab, (s, so, n) in sorted(acc.items(), key=lambda kv: -kv[1][0] / max(kv[1][2], 1)):
                rows.append({"channel": ch, "phoneme": lab, "samples": int(n),
                             "rmse_mm": float(np.sqrt(s / n)) if n else float("nan"),
                             "rmse_offset_removed_mm": float(np.sqrt(so / n)) if n else float("nan")})
        return rows

    def channel_rows(self) -> list[dict[str, Any]]:
        rows = []
        for ch in self.channels:
            r = np.concatenate([self.residuals(ch, u) for u in range(len(self.utterances))])
            ro = np.concatenate([self.residuals(ch, u, offset=True) for u in range(len(self.utterances))])
            a, b = self.calibration(ch)
            f = np.concatenate(self.predicted[ch])
            rc = np.where(np.isfinite(r), a + (b - 1.0) * f + r, np.nan)  # a + b·F − y
            rows.append({"channel": ch, "utterances": len(self.utterances), "samples": int(np.isfinite(r).sum()),
                         "rmse_mm": _rms(r), "rmse_offset_removed_mm": _rms(ro), "rmse_calibrated_mm": _rms(rc),
                         "calibration_offset_mm": a, "calibration_scale": b})
        return rows

    def rmse(self, channel: str, offset: bool = False) -> float:
        row = next(r for r in self.channel_rows() if r["channel"] == channel)
        return float(row["rmse_offset_removed_mm" if offset else "rmse_mm"])

    def text(self) -> str:
        who = f", speaker {self.speaker}" if self.speaker is not None else ""
        lines = [f"[[Score]] table {self.table.source}{who} on {len(self.utterances)} utterance(s)"]
        lines += [f"    note: {n}" for n in self.notes]
        for r in self.channel_rows():
            lines.append(f"    {r['channel']}: RMSE {r['rmse_mm']:.4f} mm, offset removed {r['rmse_offset_removed_mm']:.4f} mm, "
                         f"speaker-calibrated {r['rmse_calibrated_mm']:.4f} mm (a = {r['calibration_offset_mm']:+.3f} mm, "
                         f"b = {r['calibration_scale']:.4f}) ({r['samples']} samples)")
        lines.append("[[Utterances]]")
        for r in self.utterance_rows():
            lines.append(f"    {r['channel']} {r['utterance']}: RMSE {r['rmse_mm']:.4f} mm, offset removed "
                         f"{r['rmse_offset_removed_mm']:.4f} mm (offset {r['offset_mm']:+.3f} mm)")
        return "\n".join(lines) + "\n"

    # ------------------------------------------------------------------ output
    def save(self, out: str | PathLike[str], figures: bool = True) -> dict[str, Path]:
        """Write the three CSVs, ``score.txt`` and (``figures``) the PNGs into ``out``, each file atomically."""
        from coartic.outputs import atomic_write_text

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"channels": out / "score_channels.csv", "utterances": out / "score_utterances.csv",
                 "phonemes": out / "score_phonemes.csv", "text": out / "score.txt"}
        atomic_write_text(paths["channels"], _csv(self.channel_rows()))
        atomic_write_text(paths["utterances"], _csv(self.utterance_rows()))
        atomic_write_text(paths["phonemes"], _csv(self.phoneme_rows()))
        atomic_write_text(paths["text"], self.text())
        if figures:
            paths |= score_figures(self, out)
        return paths


def segment_of(utt: Utterance) -> NDArray[np.int64]:
    """For each sample of ``utt``, the index of the segment it lies in (−1 outside every segment)."""
    i = np.searchsorted(utt.starts, utt.times, side="right") - 1
    inside = (i >= 0) & (utt.times < utt.ends[np.clip(i, 0, None)])
    return np.where(inside, i, -1).astype(np.int64)


def score_utterances(table: ParameterTable, utterances: Sequence[Utterance],
                     channels: Sequence[str] | None = None, speaker: str | None = None) -> Score:
    """Evaluate ``table`` on utterances whose labels are model phonemes and compare with their
    observed channels (default: the table's channels the utterances carry); with ``speaker``, the
    predictions are that speaker's (``coartic.speakers.speaker_mapping``: an unknown name, or a
    table without speakers, is an error)."""
    from coartic.speakers import speaker_mapping, table_speakers

    mapping = speaker_mapping(table, speaker)
    utts = list(utterances)
    if not utts:
        raise ValueError("no utterance to score")
    chans = tuple(channels) if channels is not None else tuple(
        c for c in table.channels if all(c in u.observed for u in utts))
    if not chans:
        raise ValueError(f"the utterances carry none of the table's channels ({', '.join(table.channels)})")
    for c in chans:
        if c not in table.channels:
            raise ValueError(f"{table.source}: no channel {c!r} (channels: {', '.join(table.channels)})")
        missing = [u.name for u in utts if c not in u.observed]
        if missing:
            raise ValueError(f"channel {c}: not measured in {', '.join(missing[:5])}")
    if mapping is None:
        predicted = {c: evaluate_corpus(table, c, utts) for c in chans}
    else:
        own = mapping.evaluation_table(table)
        predicted = {c: [mapping.apply(c, v) for v in evaluate_corpus(own, c, utts)] for c in chans}
    score = Score(table, chans, utts, predicted, speaker=speaker)
    if mapping is None and table_speakers(table):
        score.notes.append(f"the table was fitted on speakers {', '.join(table_speakers(table))}; without --speaker "
                           "it predicts the population (a = 0, b = 1, the table's targets)")
    return score


def score_recordings(table: ParameterTable | str | PathLike[str], files: Sequence[str | PathLike[str]],
                     labels: Sequence[str | PathLike[str]] | None = None, *, label_map: Any = None,
                     role_map: Any = None, channels: Sequence[str] | None = None, max_gap: float = 0.05,
                     speaker: str | None = None) -> Score:
    """Load recordings (each with its label file, or an EMU bundle's own labels) and score the table.

    The labels are mapped by ``label_map`` if given, else by the map the table records (the fit's),
    else they must be model phonemes.
    """
    from coartic.fit.data import load_rows
    from coartic.io.labelmap import LabelMap

    from coartic.speakers import speaker_mapping

    if not isinstance(table, ParameterTable):
        table = ParameterTable.load(Path(table))
    speaker_mapping(table, speaker)  # an unknown speaker is refused before anything is read
    if labels is not None and len(labels) != len(files):
        raise ValueError(f"{len(labels)} label files for {len(files)} recordings: give one --labels per recording")
    lmap = label_map if label_map is not None else LabelMap.recorded(table)
    chans = tuple(channels) if channels is not None else tuple(table.channels)
    rows = [{"file": str(f), "labels": None if labels is None else str(labels[i]), "stimulus": Path(f).stem}
            for i, f in enumerate(files)]
    utts = load_rows(rows, chans, label_map=lmap, role_map=role_map, max_gap=max_gap)
    score = score_utterances(table, utts, chans, speaker)
    if label_map is None and lmap is not None:
        score.notes.append(f"labels mapped by the table's recorded label map ({lmap.source})")
    return score


# ---------------------------------------------------------------------------------- figures
def score_figures(score: Score, out: Path) -> dict[str, Path]:
    """measured_vs_predicted.png, residual_time.png, residual_phoneme.png in ``out/figures``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from coartic.outputs import save_figure

    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    n = len(score.channels)
    paths: dict[str, Path] = {}

    def save(fig: Any, name: str) -> None:
        paths[name.removesuffix(".png")] = save_figure(fig, fig_dir / name)

    fig, axes = plt.subplots(1, n, figsize=(4 * n, 4), squeeze=False)
    for ax, ch in zip(axes[0], score.channels):
        for u, utt in enumerate(score.utterances):
            ok = utt.valid[ch]
            ax.plot(utt.observed[ch][ok], score.predicted[ch][u][ok], ".", ms=2, alpha=0.5)
        lo, hi = ax.get_xlim()
        ax.plot([lo, hi], [lo, hi], color="grey", lw=1)
        ax.set_xlabel(f"{ch} measured (mm)")
        ax.set_ylabel(f"{ch} predicted (mm)")
        ax.set_title(f"{ch}: RMSE {score.rmse(ch):.3f} mm ({score.rmse(ch, True):.3f} without offsets)", fontsize=9)
    fig.tight_layout()
    save(fig, "measured_vs_predicted.png")

    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n), squeeze=False)
    for ax, ch in zip(axes[:, 0], score.channels):
        for u, utt in enumerate(score.utterances[:20]):  # a readable number of lines
            ax.plot(utt.times - utt.times[0], score.residuals(ch, u), lw=0.8, label=utt.name)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_ylabel(f"{ch} residual (mm)")
        if len(score.utterances) <= 8:
            ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time from the utterance's first sample (s)")
    fig.tight_layout()
    save(fig, "residual_time.png")

    rows = score.phoneme_rows()
    fig, axes = plt.subplots(n, 1, figsize=(max(6.0, 0.35 * len(rows) / max(n, 1) + 2), 2.6 * n), squeeze=False)
    for ax, ch in zip(axes[:, 0], score.channels):
        mine = [r for r in rows if r["channel"] == ch]
        x = np.arange(len(mine))
        ax.bar(x - 0.2, [r["rmse_mm"] for r in mine], 0.4, label="as measured")
        ax.bar(x + 0.2, [r["rmse_offset_removed_mm"] for r in mine], 0.4, label="offset removed")
        ax.set_xticks(x, [r["phoneme"] for r in mine])
        ax.set_ylabel(f"{ch} RMSE (mm)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save(fig, "residual_phoneme.png")
    return paths


def _rms(r: F64) -> float:
    ok = np.isfinite(r)
    return float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan")


def _csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return buf.getvalue()
