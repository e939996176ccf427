"""Baselines for every held-out figure: what a table must beat for the model to have helped (issue 19).

Fitted on the training utterances, evaluated on exactly the samples the table is scored on:

- ``constant``: the training mean of the channel (every valid training sample);
- ``step``: each phoneme's training mean over the samples inside its segments, no coarticulation (a
  phoneme the training never saw, and samples outside every segment, take the constant);
- ``warped``: another token of the same sentence in the training data (same label sequence, another
  file: another rate or repetition) warped onto the test labels by the piecewise-linear time map
  through the segments' starts and centres (and the last end); with several such tokens, the mean of
  their warped trajectories. Only where such a token exists.

``Baselines.fit(train, channels)`` keeps what they need; ``predict(test, channel)`` gives each
baseline's predictions, one array per test utterance, which ``coartic.evaluation.score`` scores like the
table's (as measured, each utterance's offset removed, speaker-calibrated). ``beats_step`` is the
flag the score, the validation and the comparison raise when the table does not beat the step model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.errors import UsageError
from coartic.estimation.target_prior import segment_means
from coartic.model import Utterance

F64 = NDArray[np.float64]

BASELINES = ("constant", "step", "warped")
TITLES = {"constant": "constant (training mean)", "step": "step (phoneme means)",
          "warped": "same sentence, warped"}


def _token_key(u: Utterance) -> tuple[str, ...]:
    return tuple(u.labels)


def _file(u: Utterance) -> str:
    """Which recording ``u`` is: its file resolved (a spec's "fit/../x.csv" and the command line's
    "x.csv" are one file, or a recording scored in sample is its own "other token"), else its name."""
    f = u.meta.get("file")
    return str(Path(f).resolve()) if f else u.name


def warp_times(test: Utterance, token: Utterance) -> F64:
    """The test utterance's sample times mapped into ``token``'s time: piecewise linear through
    every segment's start and centre and the last segment's end (the two have the same labels);
    outside the first and last knot, shifted by the nearest knot's offset (slope 1)."""
    k_test = np.concatenate([np.column_stack([test.starts, 0.5 * (test.starts + test.ends)]).ravel(), test.ends[-1:]])
    k_tok = np.concatenate([np.column_stack([token.starts, 0.5 * (token.starts + token.ends)]).ravel(), token.ends[-1:]])
    t = test.times
    tau = np.interp(t, k_test, k_tok)
    tau = np.where(t < k_test[0], t - k_test[0] + k_tok[0], tau)
    return np.asarray(np.where(t > k_test[-1], t - k_test[-1] + k_tok[-1], tau), dtype=np.float64)


@dataclass
class Baselines:
    """The training data's constant and step model per channel, and its tokens for warping."""

    channels: tuple[str, ...]
    constant: dict[str, float]
    step: dict[str, dict[str, float]]
    tokens: list[Utterance] = field(default_factory=list)

    @classmethod
    def fit(cls, train: Sequence[Utterance], channels: Sequence[str]) -> Baselines:
        chans = tuple(channels)
        constant: dict[str, float] = {}
        step: dict[str, dict[str, float]] = {}
        for ch in chans:
            tot, n = 0.0, 0
            for u in train:
                y = u.observed[ch]
                ok = u.valid[ch] & np.isfinite(y)
                tot += float(y[ok].sum())
                n += int(ok.sum())
            constant[ch] = tot / n if n else float("nan")
            step[ch] = segment_means(train, ch)
        return cls(chans, constant, step, list(train))

    def same_sentence(self, test: Utterance) -> list[Utterance]:
        """The training tokens of ``test``'s sentence: same label sequence, another file."""
        return [u for u in self.tokens if _token_key(u) == _token_key(test) and _file(u) != _file(test)]

    def predict_one(self, name: str, test: Utterance, channel: str) -> F64 | None:
        """Baseline ``name``'s prediction of ``channel`` at ``test``'s samples (None: the warped
        baseline of an utterance whose sentence has no other token in the training data)."""
        c = self.constant[channel]
        if name == "constant":
            return np.full(test.times.size, c)
        if name == "step":
            means = self.step[channel]
            per_segment = np.array([means.get(lab, c) for lab in test.labels] + [c])
            return per_segment[test.sample_segments()]  # −1 (outside every segment) picks the constant
        if name == "warped":
            tokens = self.same_sentence(test)
            if not tokens:
                return None
            out = np.zeros(test.times.size)
            for tok in tokens:
                y, ok = tok.observed[channel], tok.valid[channel] & np.isfinite(tok.observed[channel])
                if not ok.any():
                    return None
                out += np.interp(warp_times(test, tok), tok.times[ok], y[ok])
            return out / len(tokens)
        raise UsageError(f"unknown baseline {name!r} (known: {', '.join(BASELINES)})")

    def predict(self, test: Sequence[Utterance], channel: str) -> dict[str, list[F64]]:
        """Each baseline's predictions of ``channel``, one array per test utterance; the warped
        baseline only if every test utterance has another token of its sentence in the training."""
        out: dict[str, list[F64]] = {}
        for name in BASELINES:
            preds = [self.predict_one(name, u, channel) for u in test]
            if all(p is not None for p in preds):
                out[name] = [p for p in preds if p is not None]
        return out


    def absent(self, test: Sequence[Utterance], channel: str) -> dict[str, str]:
        """Each baseline ``predict`` leaves out for ``channel``, with the reason in words (the
        warped one: the test utterances whose sentence has no other token in the training data)."""
        out: dict[str, str] = {}
        lone = [u.name for u in test if self.predict_one("warped", u, channel) is None]
        if lone:
            more = f" and {len(lone) - 3} more" if len(lone) > 3 else ""
            out["warped"] = (f"no other token of the sentence of {', '.join(lone[:3])}{more} in the training data "
                             f"(a warped token needs the same label sequence from another file)")
        return out


def caption(shown: Sequence[str], absent: dict[str, str]) -> str:
    """The words under a table of baselines: what each one shown is, and why each other is not."""
    parts = [f"{b} = {WHAT[b]}" for b in BASELINES if b in shown]
    said = ("baselines on the same samples: " + "; ".join(parts)) if parts else "no baselines"
    gone = [f"{b} not shown: {why}" for b, why in absent.items() if b not in shown]
    return said + "".join(f"; {g}" for g in gone)


WHAT = {"constant": "training mean", "step": "each phoneme's training mean",
        "warped": "another token of the sentence, time-warped"}


def other_session(test: Sequence[Utterance], train: Sequence[Utterance]) -> str | None:
    """Why ``test`` was recorded in another session or by another speaker than ``train`` (their raw
    positions then have another origin), or None: a test speaker (meta ``speaker``) or session
    (meta ``session``) the training lacks, else a test file in a directory none of the training
    files is in (a session's files sit together: an EMU session, a speaker's directory). Utterances
    without files (made in memory) count as one session."""
    for key in ("speaker", "session"):
        seen = {u.meta.get(key) for u in train}
        new = sorted({str(u.meta[key]) for u in test if key in u.meta and u.meta[key] not in seen})
        if new and None not in seen:
            return f"{key} {', '.join(new)} is not in the training data"
    dirs = {Path(str(u.meta["file"])).resolve().parent for u in train if u.meta.get("file")}
    away = sorted({Path(str(u.meta["file"])).name for u in test
                   if u.meta.get("file") and Path(str(u.meta["file"])).resolve().parent not in dirs})
    if dirs and away:
        return f"{', '.join(away[:3])}{' and more' if len(away) > 3 else ''} is in no directory of the training files"
    return None


def beats_step(table_rmse: tuple[float, float], step_rmse: tuple[float, float], offset_only: bool = False) -> bool:
    """Whether the table beats the step model both as measured and with the offsets removed
    ((raw, offset removed) RMSE of each on the same samples); ``offset_only`` (recordings from another
    session or speaker, whose raw positions have another origin): with the offsets removed only."""
    pairs = list(zip(table_rmse, step_rmse))[1:] if offset_only else zip(table_rmse, step_rmse)
    return all(t < s for t, s in pairs if np.isfinite(s))


def flag_text(channel: str, table_rmse: tuple[float, float], step_rmse: tuple[float, float],
              other: str | None = None,
              speech: tuple[tuple[float, float], tuple[float, float]] | None = None) -> str:
    """The console's and report's words for a table that does not beat the step model (``other``:
    why the test recordings are from another session or speaker: compared with the offsets removed).
    ``speech``: the table's and the step model's (as measured, offset removed) RMSE on the speech
    samples alone; where the table beats the step model there, the words say so: the pauses decide."""
    if other:
        text = (f"{channel}: the table does not beat the step model (phoneme means, no coarticulation) with the "
                f"offsets removed: {table_rmse[1]:.3f} vs {step_rmse[1]:.3f} mm (as measured {table_rmse[0]:.3f} vs "
                f"{step_rmse[0]:.3f} mm, not compared: {other}, so its positions have another origin)")
    else:
        text = (f"{channel}: the table does not beat the step model (phoneme means, no coarticulation): "
                f"{table_rmse[0]:.3f} vs {step_rmse[0]:.3f} mm as measured, {table_rmse[1]:.3f} vs "
                f"{step_rmse[1]:.3f} mm offset removed")
    if speech is not None and np.isfinite(speech).all() and beats_step(*speech, offset_only=other is not None):
        (t, to), (s, so) = speech
        text += (f"; on speech alone (pauses left out) it does: {t:.3f} vs {s:.3f} mm as measured, {to:.3f} vs "
                 f"{so:.3f} mm offset removed, so the pauses decide")
    return text
