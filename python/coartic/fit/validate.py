"""Validation beyond the training data: held-out repetition, and the other speaking rate.

Fit on repetitions other than ``holdout_repetition`` and report RMSE on it; fit on ``train_rate``
and report RMSE on ``test_rate`` (the model's claim is that the same parameters hold at a faster
rate). Each split is a full fit of every channel (``run`` with the split's utterances).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from rich.console import Console
from rich.table import Table

from coartic.fit.problem import ChannelData, Utterance
from coartic.fit.result import BAR_MM, FitResult
from coartic.fit.spec import FitSpec, SpecError


@dataclass
class SplitScore:
    split: str  # e.g. "repetition 5 held out"
    channel: str
    train_rmse: float
    test_rmse: float
    test_samples: int
    worst_vowel: tuple[str, float]


def score(result: FitResult, test: Sequence[Utterance], split: str) -> list[SplitScore]:
    """RMSE of the fitted parameters on utterances the fit did not see."""
    out = []
    for ch, fit in result.channels.items():
        known = set(fit.phonemes)
        unknown = sorted({lab for u in test for lab in u.labels} - known)
        if unknown:
            raise ValueError(f"{split}: the test utterances contain phonemes the training fit never saw: {unknown}")
        data = ChannelData.build(test, ch, fit.phonemes)
        f = fit.problem.__class__(data, fit.packing, fit.problem.options).evaluate(fit.params, fit.beta)
        r2 = np.where(data.weights > 0, (f - data.observed) ** 2, 0.0)
        per_utt = np.add.reduceat(r2, data.sample_offsets[:-1])
        cnt = np.add.reduceat(data.weights, data.sample_offsets[:-1])
        by_vowel: dict[str, list[float]] = {}
        for u, utt in enumerate(data.utterances):
            a = by_vowel.setdefault(utt.meta.get("vowel", "?"), [0.0, 0.0])
            a[0] += per_utt[u]
            a[1] += cnt[u]
        vowel_rmse = {v: float(np.sqrt(s / n)) for v, (s, n) in by_vowel.items() if n}
        worst = max(vowel_rmse.items(), key=lambda kv: kv[1])
        out.append(SplitScore(split, ch, fit.rmse, float(np.sqrt(r2.sum() / data.weights.sum())),
                              int(data.weights.sum()), worst))
    return out


def splits(spec: FitSpec, utterances: Sequence[Utterance]) -> list[tuple[str, list[Utterance], list[Utterance]]]:
    """(name, train, test) for each validation the spec asks for and the corpus allows."""
    out = []
    if spec.holdout_repetition is not None:
        rep = str(spec.holdout_repetition)
        test = [u for u in utterances if _rep(u) == rep]
        train = [u for u in utterances if _rep(u) not in (rep, None)]
        if test and train:
            out.append((f"repetition {rep} held out", train, test))
    if spec.train_rate and spec.test_rate:
        train = [u for u in utterances if u.meta.get("rate") == spec.train_rate]
        test = [u for u in utterances if u.meta.get("rate") == spec.test_rate]
        if test and train:
            out.append((f"fit {spec.train_rate} rate, test {spec.test_rate} rate", train, test))
    if not out:
        raise SpecError(f"{spec.path}: [validate] the corpus has no repetition {spec.holdout_repetition} / "
                        f"rates {spec.train_rate!r}, {spec.test_rate!r} to hold out (manifest columns "
                        "'repetition' and 'rate')")
    return out


def _rep(u: Utterance) -> str | None:
    r = u.meta.get("repetition")
    if r is None:
        return None
    try:
        return str(int(r))
    except ValueError:
        return str(r)


def validate_all(spec: FitSpec, out: str | Path | None = None, utterances: Sequence[Utterance] | None = None,
                 console: Console | None = None, quiet: bool = False) -> list[SplitScore]:
    from coartic.fit.runner import run

    if utterances is None:
        from coartic.fit.data import load_utterances

        utterances = load_utterances(spec)
    scores: list[SplitScore] = []
    for name, train, test in splits(spec, utterances):
        if console is not None and not quiet:
            console.print(f"[bold]validation[/bold]: {name} ({len(train)} trials to fit, {len(test)} to test)")
        sub = Path(out) / name.replace(" ", "_").replace(",", "") if out is not None else None
        res = run(spec, sub, utterances=train, console=console, quiet=quiet, report=False)
        scores += score(res, test, name)
        if res.interrupted:
            break
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        with (Path(out) / "validation.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["split", "channel", "train_rmse_mm", "test_rmse_mm", "test_samples", "worst_vowel",
                        "worst_vowel_rmse_mm"])
            for s in scores:
                w.writerow([s.split, s.channel, repr(s.train_rmse), repr(s.test_rmse), s.test_samples,
                            s.worst_vowel[0], repr(s.worst_vowel[1])])
    return scores


def validation_table(scores: Sequence[SplitScore]) -> Table:
    t = Table(title=f"Validation RMSE (mm) on data the fit did not see — bar {BAR_MM} mm")
    for c in ("split", "channel", "train", "test", "worst vowel (test)"):
        t.add_column(c, justify="left" if c in ("split", "channel") else "right")
    for s in scores:
        col = "green" if s.test_rmse < BAR_MM else "red"
        t.add_row(s.split, s.channel, f"{s.train_rmse:.3f}", f"[{col}]{s.test_rmse:.3f}[/{col}]",
                  f"{s.worst_vowel[1]:.3f} ({s.worst_vowel[0]})")
    return t
