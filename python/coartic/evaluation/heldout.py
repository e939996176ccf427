"""Held-out scores and what is said of them: one split's scores (``SplitScore``), the RMSE pooled
over splits, the flags where the table does not beat the step model, and summary.json's part.

Below ``coartic.evaluation.validate`` (which makes the scores by fitting and scoring splits) and the
report, which read them; above the fit, whose result carries them as ``Validation`` (the fit's
``HeldOut``: the fit writes their lines without importing this module).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Sequence

import numpy as np

from coartic.evaluation.baselines import beats_step, flag_text

if TYPE_CHECKING:
    from coartic.fit.result import FitResult

# the baselines' columns of validation.csv, each prefixed by the baseline's name
BASELINE_COLUMNS = ("rmse_mm", "rmse_offset_removed_mm", "rmse_speaker_calibrated_mm", "rmse_speech_mm",
                    "rmse_speech_offset_removed_mm")
BaselineFigures = tuple[float, float, float, float, float]  # a baseline's BASELINE_COLUMNS


@dataclass
class SplitScore:
    split: str  # e.g. "repetition 5 held out"
    channel: str
    train_rmse: float
    test_rmse: float
    test_samples: int
    worst_vowel: tuple[str, float]
    test_rmse_offset_removed: float = float("nan")  # after removing each test utterance's offset
    train_sse: float = float("nan")
    train_samples: int = 0
    n_free: int = 0
    # after calibrating the test speaker's offset and scale on the test data (coartic.evaluation.score)
    test_rmse_calibrated: float = float("nan")
    # baseline -> (as measured, offset removed, speaker-calibrated, speech only as measured and offset
    # removed) test RMSE on the same samples (BASELINE_COLUMNS)
    baselines: dict[str, BaselineFigures] = field(default_factory=dict)
    # a multi-start's distinct optima ([fit] starts > 1): each one's test RMSE, best in-sample first
    optima_test_rmse: tuple[float, ...] = ()
    # the test samples inside speech segments only (every pause posture left out): as measured,
    # offset removed (coartic.evaluation.score: "rmse_speech_mm")
    test_rmse_speech: float = float("nan")
    test_rmse_speech_offset_removed: float = float("nan")
    test_speech_samples: int = 0
    # why the test utterances are from another session or speaker than the training (None: the same):
    # the step model is then compared with the offsets removed only (coartic.evaluation.baselines.other_session)
    other_session: str | None = None
    # each test utterance's (SSE, valid samples) as measured, by name: the units `coartic compare`
    # takes a held-out RMSE's standard error over (coartic.evaluation.compare.heldout_se)
    utterance_sse: dict[str, tuple[float, int]] = field(default_factory=dict)

    @property
    def beats_step(self) -> bool:
        """The table beats the step model (as measured and offset removed; offset removed only for
        another session or speaker), or there is none."""
        step = self.baselines.get("step")
        return step is None or beats_step((self.test_rmse, self.test_rmse_offset_removed), step[:2],
                                          offset_only=self.other_session is not None)

    def flag(self) -> str | None:
        if self.beats_step:
            return None
        step = self.baselines["step"]
        speech = ((self.test_rmse_speech, self.test_rmse_speech_offset_removed), (step[3], step[4])) \
            if len(step) > 4 else None
        return f"{self.split}: " + flag_text(self.channel, (self.test_rmse, self.test_rmse_offset_removed),
                                             step[:2], self.other_session, speech)


def pooled(scores: Sequence[SplitScore], model: str = "table", speech: bool = False) -> dict[str, tuple[float, float, int]]:
    """Per channel, the held-out RMSE over every split's test samples together (as measured,
    offset removed, samples): the one number a k-fold validation gives. ``model``: the table, or
    a baseline (``coartic.evaluation.baselines``; a channel some split lacks it on is left out).
    ``speech``: over the speech samples only (pauses left out)."""
    acc: dict[str, list[float]] = {}
    lacking: set[str] = set()
    for sc in scores:
        if model == "table":
            rm, ro = ((sc.test_rmse_speech, sc.test_rmse_speech_offset_removed) if speech
                      else (sc.test_rmse, sc.test_rmse_offset_removed))
        elif model in sc.baselines and (not speech or len(sc.baselines[model]) > 4):
            rm, ro = sc.baselines[model][3:5] if speech else sc.baselines[model][:2]
        else:
            lacking.add(sc.channel)
            continue
        n = sc.test_speech_samples if speech else sc.test_samples
        if n == 0:
            continue
        a = acc.setdefault(sc.channel, [0.0, 0.0, 0.0])
        a[0] += rm**2 * n
        a[1] += ro**2 * n
        a[2] += n
    return {ch: (float(np.sqrt(s / n)), float(np.sqrt(so / n)), int(n)) for ch, (s, so, n) in acc.items()
            if n and ch not in lacking}


def flags(scores: Sequence[SplitScore]) -> list[str]:
    """The lines that say where the table does not beat the step model: each split, and pooled."""
    out = [f for f in (sc.flag() for sc in scores) if f is not None]
    if len({sc.split for sc in scores}) > 1:
        table, step = pooled(scores), pooled(scores, "step")
        table_speech, step_speech = pooled(scores, speech=True), pooled(scores, "step", speech=True)
        # a channel any of whose splits is from another session is compared with the offsets removed
        other = {sc.channel: sc.other_session for sc in scores if sc.other_session}
        out += [f"all splits pooled: "
                + flag_text(ch, table[ch][:2], step[ch][:2], other.get(ch),
                            (table_speech[ch][:2], step_speech[ch][:2]) if ch in table_speech and ch in step_speech
                            else None)
                for ch in table if ch in step and not beats_step(table[ch][:2], step[ch][:2], offset_only=ch in other)]
    return out


def baseline_summary(scores: Sequence[SplitScore]) -> dict[str, object]:
    """summary.json's validation: per split and channel the table's and baselines' held-out RMSE, the flags."""
    return {"splits": [{"split": sc.split, "channel": sc.channel, "samples": sc.test_samples,
                        "table": {"rmse_mm": sc.test_rmse, "rmse_offset_removed_mm": sc.test_rmse_offset_removed,
                                  "rmse_speaker_calibrated_mm": sc.test_rmse_calibrated,
                                  "rmse_speech_mm": sc.test_rmse_speech,
                                  "rmse_speech_offset_removed_mm": sc.test_rmse_speech_offset_removed},
                        **{b: dict(zip(BASELINE_COLUMNS, v)) for b, v in sc.baselines.items()},
                        "beats_step_model": sc.beats_step, "other_session": sc.other_session} for sc in scores],
            "flags": flags(scores)}


@dataclass
class Validation:
    """A fit's held-out scores as its result carries them (``FitResult.validation``, the fit's
    ``HeldOut``): the last section of fit_report.txt and summary.json's ``"validation"``."""

    scores: list[SplitScore]

    def text_lines(self) -> list[str]:
        if not self.scores:
            return []
        lines = ["", "[[Validation]] (held-out RMSE in mm as measured / offset removed; baselines on the same "
                 "samples: constant = training mean, step = each phoneme's training mean, warped = another "
                 "token of the sentence)"]
        for sc in self.scores:
            base = "".join(f", {b} {v[0]:.4f} / {v[1]:.4f}" for b, v in sc.baselines.items())
            lines.append(f"    {sc.split}, {sc.channel}: table {sc.test_rmse:.4f} / "
                         f"{sc.test_rmse_offset_removed:.4f}{base}")
        return lines + [f"    WARNING: {f}" for f in flags(self.scores)]

    def summary(self) -> dict[str, object] | None:
        return baseline_summary(self.scores) if self.scores else None


def held_out(result: FitResult) -> list[SplitScore]:
    """The split scores a fit's result carries (none when it was not validated)."""
    v = result.validation
    return v.scores if isinstance(v, Validation) else []
