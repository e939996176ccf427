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
import json
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.errors import CoarticError
from coartic.evaluation.baselines import Baselines, beats_step, flag_text
from coartic.model import Utterance, evaluate_corpus, utterances_for_table
from coartic.pauses import speech_samples
from coartic.table import ParameterTable

F64 = NDArray[np.float64]
# A measured channel whose samples span less than this (mm) is constant: not computed from the recording.
CONSTANT_MM = 1e-6


@dataclass
class Score:
    """Predictions of one table on some utterances; every figure computed from ``residuals``."""

    table: ParameterTable
    channels: tuple[str, ...]
    utterances: list[Utterance]
    predicted: dict[str, list[F64]]  # channel -> one array per utterance
    notes: list[str] = field(default_factory=list)
    speaker: str | None = None  # the table's speaker whose mapping the predictions carry
    # baseline -> channel -> predictions per utterance (coartic.evaluation.baselines; add_baselines)
    baselines: dict[str, dict[str, list[F64]]] = field(default_factory=dict)
    # baseline -> why it is not shown (e.g. warped: no other token of the sentence; every one when no
    # training data were found)
    absent: dict[str, str] = field(default_factory=dict)
    # why the scored recordings are from another session or speaker than the training (None: the
    # same): the step-model flag then compares with the offsets removed only (baselines.other_session)
    other_session: str | None = None

    def calibration(self, channel: str, predicted: list[F64] | None = None) -> tuple[float, float]:
        """(a, b) of measured ≈ a + b·predicted over every valid sample of ``channel``: the speaker
        calibrated on its own data (``coartic.estimation.speakers.affine_coefficients``). ``predicted``:
        other predictions of the same samples (a baseline's) instead of the table's."""
        from coartic.estimation.speakers import affine_coefficients

        f = np.concatenate(self.predicted[channel] if predicted is None else predicted)
        y = np.concatenate([u.observed[channel] for u in self.utterances]).astype(np.float64)
        ok = np.concatenate([u.valid[channel] for u in self.utterances]) & np.isfinite(y) & np.isfinite(f)
        a, b = affine_coefficients(np.zeros(f.size, dtype=np.int64), 1, ok.astype(np.float64),
                                   np.where(ok, f, 0.0), np.where(ok, y, 0.0))
        return float(a[0]), float(b[0])

    def residuals(self, channel: str, u: int, offset: bool = False, predicted: list[F64] | None = None) -> F64:
        """Predicted − measured for utterance ``u`` (NaN where not measured); with ``offset``, minus
        its mean over the utterance (the per-utterance offset removed). ``predicted``: as in
        ``calibration``."""
        utt = self.utterances[u]
        f = (self.predicted[channel] if predicted is None else predicted)[u]
        r = np.where(utt.valid[channel], f - utt.observed[channel], np.nan)
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
                seg = utt.sample_segments()
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

    def _figures(self, ch: str, predicted: list[F64] | None = None) -> dict[str, Any]:
        """RMSE as measured, offset removed and speaker-calibrated of the table's predictions of
        ``ch`` (or of ``predicted``, a baseline's), on the same samples."""
        n_u = range(len(self.utterances))
        r = np.concatenate([self.residuals(ch, u, predicted=predicted) for u in n_u])
        ro = np.concatenate([self.residuals(ch, u, offset=True, predicted=predicted) for u in n_u])
        a, b = self.calibration(ch, predicted)
        f = np.concatenate(self.predicted[ch] if predicted is None else predicted)
        rc = np.where(np.isfinite(r), a + (b - 1.0) * f + r, np.nan)  # a + b·F − y
        speech = np.concatenate([self.speech(u) for u in n_u])
        return {"samples": int(np.isfinite(r).sum()), "rmse_mm": _rms(r), "rmse_offset_removed_mm": _rms(ro),
                "rmse_calibrated_mm": _rms(rc), "calibration_offset_mm": a, "calibration_scale": b,
                # the samples inside speech segments only (every pause posture left out; the offset
                # removed is still the whole utterance's)
                "speech_samples": int(np.isfinite(r[speech]).sum()), "rmse_speech_mm": _rms(r[speech]),
                "rmse_speech_offset_removed_mm": _rms(ro[speech])}

    def speech(self, u: int) -> NDArray[np.bool_]:
        """The samples of utterance ``u`` inside a segment that is no pause (``coartic.pauses.speech_samples``)."""
        utt = self.utterances[u]
        return speech_samples(utt.labels, utt.sample_segments())

    def channel_rows(self) -> list[dict[str, Any]]:
        rows = []
        for ch in self.channels:
            fig = self._figures(ch)
            rows.append({"channel": ch, "utterances": len(self.utterances), "samples": fig["samples"],
                         **{k: v for k, v in fig.items() if k != "samples"}})
        return rows

    def baseline_rows(self) -> list[dict[str, Any]]:
        """Per channel, the table and each baseline (``coartic.evaluation.baselines``) on the same
        samples: RMSE as measured, offset removed and speaker-calibrated."""
        rows = []
        for ch in self.channels:
            rows.append({"channel": ch, "model": "table", **self._figures(ch)})
            for name, per in self.baselines.items():
                if ch in per:
                    rows.append({"channel": ch, "model": name, **self._figures(ch, per[ch])})
        return rows

    def flags(self) -> list[str]:
        """One line per channel on which the table does not beat the step model."""

        out = []
        for ch in self.channels:
            if ch not in self.baselines.get("step", {}):
                continue
            t, s = self._figures(ch), self._figures(ch, self.baselines["step"][ch])
            pair_t = (t["rmse_mm"], t["rmse_offset_removed_mm"])
            pair_s = (s["rmse_mm"], s["rmse_offset_removed_mm"])
            if not beats_step(pair_t, pair_s, offset_only=self.other_session is not None):
                speech = ((t["rmse_speech_mm"], t["rmse_speech_offset_removed_mm"]),
                          (s["rmse_speech_mm"], s["rmse_speech_offset_removed_mm"]))
                out.append(flag_text(ch, pair_t, pair_s, self.other_session, speech))
        return out

    def add_baselines(self, train: Sequence[Utterance]) -> None:
        """Fit the baselines on ``train`` (the table's training utterances) and predict these samples."""

        from coartic.evaluation.baselines import other_session

        b = Baselines.fit(train, self.channels)
        self.other_session = other_session(self.utterances, train)
        if self.other_session:
            self.notes.append(f"the step model is compared with the offsets removed only: {self.other_session}, so "
                              "the recordings' positions have another origin than the training's")
        self.baselines = {}
        self.absent = {}
        for ch in self.channels:
            for name, preds in b.predict(self.utterances, ch).items():
                self.baselines.setdefault(name, {})[ch] = preds
            for name, why in b.absent(self.utterances, ch).items():
                self.absent.setdefault(name, why)

    def caption(self) -> str:
        """What each baseline shown is, and why each one not shown is absent."""
        from coartic.evaluation.baselines import BASELINES, caption

        absent = dict(self.absent)
        if not self.baselines:  # none at all: the note that says why (no training spec found)
            why = next((n.partition(": ")[2] for n in self.notes if n.startswith("no baselines")),
                       "no training data given (--train SPEC)")
            absent = {b: why for b in BASELINES}
        return caption(list(self.baselines), absent)

    def summary(self) -> dict[str, Any]:
        """What ``summary.json`` holds: per channel the table's and the baselines' figures, the flags."""
        return {"table": str(self.table.source), "utterances": [u.name for u in self.utterances],
                "speaker": self.speaker, "notes": list(self.notes),
                "channels": {ch: {r["model"]: {k: v for k, v in r.items() if k not in ("channel", "model")}
                                  for r in self.baseline_rows() if r["channel"] == ch} for ch in self.channels},
                "baselines_absent": dict(self.absent),
                # the step model is compared with the offsets removed only when this says why
                "other_session": self.other_session,
                "beats_step_model": {ch: not any(f.startswith(f"{ch}:") for f in self.flags())
                                     for ch in self.channels if ch in self.baselines.get("step", {})},
                "flags": self.flags()}

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
                         f"b = {r['calibration_scale']:.4f}) ({r['samples']} samples); speech only (pauses left out) "
                         f"{r['rmse_speech_mm']:.4f} mm, offset removed {r['rmse_speech_offset_removed_mm']:.4f} mm "
                         f"({r['speech_samples']} samples)")
        base = [r for r in self.baseline_rows() if r["model"] != "table"]
        if base:
            lines.append("[[Baselines]] (fitted on the table's training data, scored on the same samples)")
            lines += [f"    {b}: not shown: {why}" for b, why in self.absent.items()]
            for r in base:
                lines.append(f"    {r['channel']} {r['model']}: RMSE {r['rmse_mm']:.4f} mm, offset removed "
                             f"{r['rmse_offset_removed_mm']:.4f} mm, speaker-calibrated {r['rmse_calibrated_mm']:.4f} mm; "
                             f"speech only {r['rmse_speech_mm']:.4f} mm, offset removed "
                             f"{r['rmse_speech_offset_removed_mm']:.4f} mm")
        lines += [f"    WARNING: {f}" for f in self.flags()]
        lines.append("[[Utterances]]")
        for r in self.utterance_rows():
            lines.append(f"    {r['channel']} {r['utterance']}: RMSE {r['rmse_mm']:.4f} mm, offset removed "
                         f"{r['rmse_offset_removed_mm']:.4f} mm (offset {r['offset_mm']:+.3f} mm)")
        return "\n".join(lines) + "\n"

    # ------------------------------------------------------------------ output
    def save(self, out: str | PathLike[str], figures: bool = True) -> dict[str, Path]:
        """Write the CSVs, ``score.txt``, ``summary.json`` and (``figures``) the PNGs into ``out``, each
        file atomically."""
        from coartic.outputs import atomic_write_text

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"channels": out / "score_channels.csv", "utterances": out / "score_utterances.csv",
                 "phonemes": out / "score_phonemes.csv", "text": out / "score.txt"}
        atomic_write_text(paths["channels"], _csv(self.channel_rows()))
        atomic_write_text(paths["utterances"], _csv(self.utterance_rows()))
        atomic_write_text(paths["phonemes"], _csv(self.phoneme_rows()))
        atomic_write_text(paths["text"], self.text())
        paths["baselines"] = out / "score_baselines.csv"
        atomic_write_text(paths["baselines"], _csv(self.baseline_rows()))
        paths["summary"] = out / "summary.json"
        atomic_write_text(paths["summary"], json.dumps(self.summary(), indent=2))
        if figures:
            paths |= score_figures(self, out)
        return paths


def score_utterances(table: ParameterTable, utterances: Sequence[Utterance],
                     channels: Sequence[str] | None = None, speaker: str | None = None,
                     train: Sequence[Utterance] | None = None) -> Score:
    """Evaluate ``table`` on utterances whose labels are model phonemes and compare with their
    observed channels (default: the table's channels the utterances carry); with ``speaker``, the
    predictions are that speaker's (``coartic.speakers.speaker_mapping``: an unknown name, or a
    table without speakers, is an error). With ``train`` (the utterances the table was fitted on),
    the baselines too (``coartic.evaluation.baselines``, ``Score.baseline_rows``)."""
    from coartic.emotions import evaluate_by_emotion
    from coartic.speakers import speaker_mapping, table_speakers

    mapping = speaker_mapping(table, speaker)
    utts = utterances_for_table(table, utterances)  # pauses as the table was fitted (coartic.pauses)
    if not utts:
        raise ScoreError("no utterance to score")
    chans = tuple(channels) if channels is not None else tuple(
        c for c in table.channels if all(c in u.observed for u in utts))
    if not chans:
        raise ScoreError(f"the utterances carry none of the table's channels ({', '.join(table.channels)})")
    for c in chans:
        if c not in table.channels:
            raise ScoreError(f"{table.source}: no channel {c!r} (channels: {', '.join(table.channels)})")
        missing = [u.name for u in utts if c not in u.observed]
        if missing:
            raise ScoreError(f"channel {c}: not measured in {', '.join(missing[:5])}")
    for c in chans:  # a calibrated figure of a channel the recording did not give would be meaningless
        y = np.concatenate([u.observed[c][u.valid[c]] for u in utts])
        y = y[np.isfinite(y)]
        if y.size == 0:
            raise ScoreError(f"channel {c}: no valid sample in {', '.join(u.name for u in utts[:5])}: it could "
                             "not be computed from the recordings; not scored")
        if float(np.ptp(y)) < CONSTANT_MM:
            raise ScoreError(f"channel {c} is {y[0]:.3g} mm in every sample of {', '.join(u.name for u in utts[:5])}: "
                             "it was not computed from the recordings (a missing or misnamed sensor? give "
                             "--role-map, or --channels without it); no RMSE, calibrated or not, is printed for it")
    if mapping is None:  # each utterance with its emotion's targets when the table has emotions
        predicted = {c: evaluate_by_emotion(table, c, utts) for c in chans}
    else:
        own = mapping.evaluation_table(table)
        predicted = {c: [mapping.apply(c, v) for v in evaluate_corpus(own, c, utts)] for c in chans}
    score = Score(table, chans, utts, predicted, speaker=speaker)
    if train is not None:
        score.add_baselines(utterances_for_table(table, train))
    if mapping is None and table_speakers(table):
        score.notes.append(f"the table was fitted on speakers {', '.join(table_speakers(table))}; without --speaker "
                           "it predicts the population (a = 0, b = 1, the table's targets)")
    return score


class ScoreError(CoarticError, ValueError):
    """A recording cannot be scored as asked: a phoneme the table lacks (named by its corpus label
    too), or a channel that was not computed from the recording."""


def score_recordings(table: ParameterTable | str | PathLike[str], files: Sequence[str | PathLike[str]],
                     labels: Sequence[str | PathLike[str]] | None = None, *, label_map: Any = None,
                     role_map: Any = None, channels: Sequence[str] | None = None, max_gap: float = 0.05,
                     speaker: str | None = None, train: str | PathLike[str] | None = None,
                     strict: bool = False) -> Score:
    """Load recordings (each with its label file, or an EMU bundle's own labels) and score the table.

    The labels are mapped by ``label_map`` if given, else by the map the table records (the fit's),
    else they must be model phonemes; the sensors are read with ``role_map`` if given, else with
    the role map and axes the table records (``RoleMap.recorded``). A phoneme the table lacks is
    replaced by its phonetic class's fallback the table has (the label map's, ``with_fallbacks``;
    said in the notes) unless ``strict``; one with none is a ScoreError naming the corpus
    label, the phoneme and the file. The baselines (``coartic.evaluation.baselines``) are fitted on the
    training corpus of ``train`` (a fit spec), by default the spec the table records if it is found.
    """
    from coartic.fit.data import load_rows
    from coartic.io.labelmap import LabelMap, resolve_label_map
    from coartic.io.roles import RoleMap
    from coartic.speakers import speaker_mapping

    if not isinstance(table, ParameterTable):
        table = ParameterTable.load(Path(table))
    speaker_mapping(table, speaker)  # an unknown speaker is refused before anything is read
    if labels is not None and len(labels) != len(files):
        raise ScoreError(f"{len(labels)} label files for {len(files)} recordings: give one --labels per recording")
    lmap = resolve_label_map(label_map) if label_map is not None else LabelMap.recorded(table)
    rmap = role_map if role_map is not None else RoleMap.recorded(table)
    chans = tuple(channels) if channels is not None else tuple(table.channels)
    rows = [{"file": str(f), "labels": None if labels is None else str(labels[i]), "stimulus": Path(f).stem}
            for i, f in enumerate(files)]
    utts = load_rows(rows, chans, label_map=lmap, role_map=rmap, max_gap=max_gap)
    notes = []
    if not strict:
        utts, note = with_fallbacks(utts, table, chans, lmap)
        notes += [note] if note else []
    for u, row in zip(utts, rows):
        for i, lab in enumerate(u.labels):
            if lab not in table.values or any(c not in table.values[lab] for c in chans):
                corpus = _corpus_label(row, i, rmap)
                raise ScoreError(f"{row['labels'] or row['file']}: segment {i + 1}, corpus label {corpus!r} "
                                 f"(phoneme {lab!r} by "
                                 f"{(lmap.source if lmap is not None else 'the model phonemes')}): the table "
                                 f"{table.source} has no {lab!r}"
                                 + ("" if strict else " and none of its fallbacks")
                                 + f"; its phonemes are {' '.join(table.phonemes)}")
    train_utts = None
    spec_path = Path(train) if train is not None else _recorded_spec(table)
    if spec_path is not None:
        from coartic.fit.data import load_utterances
        from coartic.fit.spec import load_spec

        try:
            train_utts = load_utterances(load_spec(spec_path).with_options(channels=chans))
        except (ValueError, OSError) as e:  # the recorded spec's corpus moved or changed: said, not fatal
            if train is not None:
                raise
            notes.append(f"no baselines: the training corpus of {spec_path} (recorded in the table) could not be "
                         f"loaded ({e}); give --train SPEC")
            spec_path = None
    if train_utts is not None:
        seen = {Path(u.meta.get("file", "")).resolve() for u in train_utts}
        inside = [Path(f).name for f in files if Path(f).resolve() in seen]
        if inside:
            notes.append(f"{', '.join(inside)} is in the table's training corpus: its figures are in-sample")
    score = score_utterances(table, utts, chans, speaker, train=train_utts)
    score.notes += notes
    if label_map is None and lmap is not None:
        score.notes.append(f"labels mapped by the table's recorded label map ({lmap.source})")
    if role_map is None and rmap is not None:
        score.notes.append(f"sensors read with the table's recorded role map ({rmap.source})")
    if spec_path is not None:
        score.notes.append(f"baselines fitted on the training corpus of {spec_path}")
    elif not any(n.startswith("no baselines") for n in score.notes):
        score.notes.append("no baselines: the table records no fit spec that exists here; give --train SPEC")
    return score


def _recorded_spec(table: ParameterTable) -> Path | None:
    spec = table.metadata.get("spec")
    return Path(spec) if isinstance(spec, str) and Path(spec).is_file() else None


def with_fallbacks(utterances: Sequence[Utterance], table: ParameterTable, channels: Sequence[str],
                   label_map: Any = None) -> tuple[list[Utterance], str | None]:
    """The utterances with each phoneme the table lacks replaced by its phonetic class's first
    fallback the table has, and the note that says which (None if none was); a phoneme with no such
    fallback stays, for the caller to refuse. The fallbacks are the label map's (every built-in map
    but ``model`` has them: labelmaps/fallbacks.tsv), else those ``animate`` uses (phones_italian.tsv)."""
    from coartic.runtime.animate import substitutions
    from coartic.runtime.festival import PhoneMap

    own = getattr(label_map, "fallbacks", None)
    fallbacks, source = (own, str(label_map.source)) if own else (
        PhoneMap.load().fallbacks, "phones_italian.tsv")
    used = substitutions([lab for u in utterances for lab in u.labels], table, channels, fallbacks)
    if not used:
        return list(utterances), None
    out = [Utterance([used.get(lab, lab) for lab in u.labels], u.starts, u.ends, u.times, u.name, u.observed,
                     u.valid, u.meta) for u in utterances]
    return out, ("the table has no " + ", ".join(f"/{k}/ (scored as /{v}/)" for k, v in used.items())
                 + f": the phonetic-class fallbacks of {source} (--strict refuses instead)")


def _corpus_label(row: dict[str, Any], i: int, role_map: Any) -> str:
    """The label as the corpus writes it of segment ``i`` of ``row``'s recording (read again, unmapped)."""
    from coartic.io import load_trial
    from coartic.io.labelmap import LabelMap

    try:
        trial = load_trial(Path(str(row["file"])), labels=row["labels"], label_map=LabelMap({}, keep_unmapped=True),
                           role_map=role_map)
        return trial.segments.labels[i] if trial.segments is not None else "?"
    except (ValueError, OSError, IndexError):
        return "?"


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
