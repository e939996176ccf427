"""MCMC intervals of the emotions' deviations (``[model] emotions = "targets"``, docs/EMOTIONS.md).

A deviation d = T(p|e) − T(p|neutral) is a difference of two targets, so its interval needs their
joint posterior: ``deviation_posterior`` samples the targets of every row of one phoneme (its
neutral row and each emotion's) together, with the fit's deviation prior (the shrinkage pairs with
the data-estimated τ) and the noise level sampled, every other entry (the dynamics, the other
phonemes) held at the least-squares optimum, on the utterances that contain the phoneme. The
intervals are therefore conditional on the dynamics, like a per-phoneme posterior's (docs/MCMC.md).

``session_intervals`` samples every channel and phoneme of a fitted session (each posterior
resumable in its own folder), ``credible_report`` says which deviations are credible, per channel and
emotion, with their intervals (and, given the truth, how many of its non-zero ones are caught, how
many of its zero ones are called credible, how often the interval holds it), ``write_intervals``
writes the CSV and the report (``fit/emotion_intervals.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from coartic.estimation.problem import ChannelProblem
from coartic.mcmc.errors import McmcError
from coartic.mcmc.posterior import LogPosterior
from coartic.mcmc.run import sample_posterior
from coartic.mcmc.sampler import SamplerSettings
from coartic.table import PARAMETERS

QUANTILES = (2.5, 50.0, 97.5)


@dataclass(frozen=True)
class DeviationInterval:
    channel: str
    emotion: str
    phoneme: str
    fitted: float  # the least-squares (MAP) deviation, mm
    q2_5: float
    q50: float
    q97_5: float
    converged: bool

    @property
    def credible(self) -> bool:
        """The 95 % interval excludes 0."""
        return self.q2_5 > 0.0 or self.q97_5 < 0.0

    def row(self) -> dict[str, Any]:
        return {"channel": self.channel, "emotion": self.emotion, "phoneme": self.phoneme, "fitted": self.fitted,
                "q2.5": self.q2_5, "q50": self.q50, "q97.5": self.q97_5, "credible": self.credible,
                "converged": self.converged}


def _rows_of(problem: ChannelProblem, phoneme: str) -> list[int]:
    rows = problem.speaker_rows
    if rows is None or rows.factor != "emotions":
        raise McmcError(f"channel {problem.data.channel}: the problem has no emotion rows ([model] emotions = \"targets\")")
    if phoneme not in rows.base:
        raise McmcError(f"channel {problem.data.channel}: phoneme {phoneme!r} does not occur "
                        f"(phonemes: {' '.join(rows.base)})")
    p = rows.base.index(phoneme)
    return [r for r, (q, _) in enumerate(rows.rows) if q == p]


def deviation_posterior(problem: ChannelProblem, phoneme: str) -> LogPosterior:
    """The joint posterior of the targets of ``phoneme``'s rows (neutral and every emotion)."""
    idx = _rows_of(problem, phoneme)
    pk = problem.packing
    k = PARAMETERS.index("target")
    free = np.zeros_like(pk.free)
    free[idx, k] = pk.free[idx, k]
    if not free.any():
        raise McmcError(f"channel {problem.data.channel}: the targets of {phoneme!r} are fixed by the spec")
    assert problem.speaker_rows is not None
    labels = {problem.speaker_rows.labels[r] for r in idx}
    return LogPosterior(problem.data.subset(labels), pk.with_free(free, False), problem.options, None,
                        shrinkage=problem.shrink_groups)


def deviation_intervals(problem: ChannelProblem, phoneme: str, directory: Path,
                        settings: SamplerSettings | None = None) -> list[DeviationInterval]:
    """Sample ``deviation_posterior`` into ``directory`` (resumable, as every posterior) and return
    each emotion's deviation of ``phoneme``: the least-squares value and the posterior quantiles."""
    rows = problem.speaker_rows
    assert rows is not None
    post = deviation_posterior(problem, phoneme)
    run = sample_posterior(post, directory, settings or SamplerSettings(), f"{problem.data.channel} /{phoneme}/ "
                           "emotions", phoneme, make_plots=False, progress=False)
    if run.result.interrupted:
        # Ctrl-C or kill while sampling: the chains are saved (a rerun resumes them); no interval
        # from a partial chain, and no next posterior either (the user asked the whole run to stop)
        raise KeyboardInterrupt(f"{problem.data.channel} /{phoneme}/: interrupted; its chains are kept in {directory}")
    draws = run.result.draws()
    names = run.result.names
    params, _ = problem.packing.unpack(problem.packing.pack())
    k = PARAMETERS.index("target")
    idx = _rows_of(problem, phoneme)
    neutral = next(r for r in idx if rows.rows[r][1] == 0)
    col = {r: names.index(f"{rows.labels[r]}.target") for r in idx if f"{rows.labels[r]}.target" in names}
    out = []
    for r in idx:
        if r == neutral or r not in col or neutral not in col:
            continue
        d = draws[:, col[r]] - draws[:, col[neutral]]
        q = np.percentile(d, QUANTILES)
        out.append(DeviationInterval(problem.data.channel, rows.names[rows.rows[r][1]], phoneme,
                                     float(params[r, k] - params[neutral, k]), float(q[0]), float(q[1]), float(q[2]),
                                     run.result.converged))
    return out


def session_intervals(spec: Any, utterances: Sequence[Any], table: Any, directory: Path,
                      settings: SamplerSettings | None = None, channels: Sequence[str] | None = None,
                      phonemes: Sequence[str] | None = None,
                      on_done: Callable[[str, str, int, int], None] | None = None) -> list[DeviationInterval]:
    """Every deviation of a fit with ``[model] emotions = "targets"``: for each channel (default the
    table's) and each phoneme of its emotion rows (default all, pauses included), the joint posterior
    of the phoneme's targets (``deviation_intervals``) sampled into ``directory/<channel>/<phoneme>``.
    ``on_done(channel, phoneme, done, total)`` after each posterior. An interrupted posterior (Ctrl-C,
    SIGTERM) raises KeyboardInterrupt: the posteriors done and the interrupted one's chains are kept,
    and the same call resumes."""
    from coartic.estimation.problem import build_problem

    chans = list(channels) if channels else list(table.channels)
    problems = []
    for ch in chans:
        problem = build_problem(spec.estimation_settings(), utterances, ch, table)
        rows = problem.speaker_rows
        if rows is None or rows.factor != "emotions":
            raise McmcError(f"{spec.path}: channel {ch}: no emotion rows ([model] emotions = \"targets\")")
        unknown = [p for p in (phonemes or ()) if p not in rows.base]
        if unknown:
            raise McmcError(f"channel {ch}: phoneme(s) {unknown} do not occur (phonemes: {' '.join(rows.base)})")
        problems.append((ch, problem, [p for p in rows.base if not phonemes or p in phonemes]))
    total = sum(len(ps) for _, _, ps in problems)
    out: list[DeviationInterval] = []
    done = 0
    for ch, problem, phs in problems:
        for ph in phs:
            out.extend(deviation_intervals(problem, ph, directory / ch / _folder(ph), settings))
            done += 1
            if on_done is not None:
                on_done(ch, ph, done, total)
    return out


def _folder(phoneme: str) -> str:
    """A phoneme's folder name: pause rows ('#', '#end') spelt out."""
    return phoneme.replace("#", "pause") if phoneme.startswith("#") else phoneme


def credible_report(intervals: Sequence[DeviationInterval],
                    truth: Mapping[str, Any] | None = None) -> str:
    """Which deviations are credible (the 95 % interval excludes 0), per channel and emotion, each with
    its fitted value and interval; with ``truth`` (a table's ``metadata.emotions.channels``: the
    synthetic session's ground truth), per channel how many of the truth's non-zero deviations are
    credible, how many of its zero ones are called credible, and how often the interval holds it."""
    lines = ["[[Emotion deviations]] d = T(p|emotion) - T(p|neutral), mm: 95 % MCMC intervals "
             "(coartic.mcmc.emotions); credible when the interval excludes 0"]
    chans = list(dict.fromkeys(d.channel for d in intervals))
    for ch in chans:
        rows = [d for d in intervals if d.channel == ch]
        head = f"{ch}: {sum(d.credible for d in rows)} of {len(rows)} credible"
        if truth is not None and ch in truth:
            true = truth[ch]["deviations"]
            nz = [d for d in rows if abs(float(true[d.emotion][d.phoneme])) > 0]
            z = [d for d in rows if float(true[d.emotion][d.phoneme]) == 0]
            held = sum(d.q2_5 <= float(true[d.emotion][d.phoneme]) <= d.q97_5 for d in rows)
            head += (f"; truth: {sum(d.credible for d in nz)} of its {len(nz)} non-zero credible, "
                     f"{sum(d.credible for d in z)} of its {len(z)} zero ones called credible, "
                     f"the interval holds it for {held} of {len(rows)}")
        if not all(d.converged for d in rows):
            head += " (NOT every posterior converged: sample longer)"
        lines.append(head)
        for e in dict.fromkeys(d.emotion for d in rows):
            cred = [d for d in rows if d.emotion == e and d.credible]
            shown = ", ".join(f"{d.phoneme} {d.fitted:+.2f} [{d.q2_5:+.2f}, {d.q97_5:+.2f}]" for d in cred)
            lines.append(f"    {e}: {shown if cred else 'none credible'}")
    return "\n".join(lines) + "\n"


def write_intervals(intervals: Sequence[DeviationInterval], directory: Path,
                    truth: Mapping[str, Any] | None = None) -> dict[str, Path]:
    """``emotion_intervals.csv`` (one row per deviation) and ``emotion_intervals.txt``
    (``credible_report``) in ``directory``, each written to a temporary name then renamed."""
    import csv
    import io

    from coartic.outputs import atomic_write_text

    if not intervals:
        raise McmcError("no deviation to write (no emotion rows sampled)")
    directory.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(intervals[0].row()), lineterminator="\n")
    w.writeheader()
    w.writerows(d.row() for d in intervals)
    paths = {"csv": directory / "emotion_intervals.csv", "text": directory / "emotion_intervals.txt"}
    atomic_write_text(paths["csv"], buf.getvalue())
    atomic_write_text(paths["text"], credible_report(intervals, truth))
    return paths
