"""A setting chosen by k-fold cross-validation on the training data (``[choose]``, ``coartic fit --choose``).

For each value of the grid, the training utterances are split by ``group`` into ``folds`` folds
(``coartic.evaluation.validate.kfold_splits``, as ``[validate] group`` does), each fold is held out once
and scored by ``coartic.evaluation.validate.score``; the value is then chosen per channel and the fit
(``coartic.fit.run``, given the choice) is made on all training data with it. Nothing outside the utterances given
takes part: inside ``--validate`` every split chooses on its own training utterances (nested
cross-validation), so the held-out data never tune the strength.

Rules: ``"min"`` takes the value with the lowest mean held-out RMSE over the folds; ``"1se"`` (the
default for a regularisation strength) the strongest regularisation whose mean is within one
standard error of that minimum (Breiman et al. 1984; Hastie, Tibshirani & Friedman §7.10). Why
1-SE: near its minimum the curve is flat within the noise of k folds, so the minimum itself is
partly chance; the one-SE rule picks, among values the folds cannot tell apart, the one with the
fewest effective parameters, and a table is meant to carry over to speech that no fold resembles
(another rate, another sentence), where the simpler table is the safer bet.

Output (``Choice.save``): ``choose.csv`` (value, channel, mean and SE of the fold RMSEs, pooled
RMSE, per-fold RMSEs, chosen), ``choose.png`` (the curve per channel), lines in ``fit_report.txt``
and ``"choice"`` in the table's metadata.

The grid and the spec of one value are the spec's (``coartic.fit.choose``).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from coartic.console import LineProgress
from coartic.errors import SpecError, UsageError
from coartic.evaluation.validate import UnseenPhonemes, kfold_splits, score
from coartic.fit.choose import set_value
from coartic.fit.spec import CHOOSABLE, Choose, FitSpec, choose_base
from coartic.model import Utterance


@dataclass
class CurvePoint:
    value: float
    channel: str
    fold_rmse: list[float]
    fold_samples: list[int]

    @property
    def mean(self) -> float:
        return float(np.mean(self.fold_rmse)) if self.fold_rmse else math.nan

    @property
    def se(self) -> float:
        k = len(self.fold_rmse)
        return float(np.std(self.fold_rmse, ddof=1) / math.sqrt(k)) if k > 1 else math.nan

    @property
    def pooled(self) -> float:
        n = sum(self.fold_samples)
        return float(math.sqrt(sum(r * r * m for r, m in zip(self.fold_rmse, self.fold_samples)) / n)) if n else math.nan


@dataclass
class Choice:
    """The cross-validation curve of one ``[choose]`` and the value chosen per channel."""

    choose: Choose
    points: list[CurvePoint]
    folds: list[str]  # the folds scored
    n_folds: int = 0  # the folds made (some may not be scorable)
    chosen: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def curve(self, channel: str) -> list[CurvePoint]:
        return [p for p in self.points if p.channel == channel]

    def pick(self) -> None:
        """Apply the rule per channel (fills ``chosen``)."""
        c = self.choose
        direction = CHOOSABLE[choose_base(c.key) or c.key]
        for ch in dict.fromkeys(p.channel for p in self.points):
            pts = [p for p in self.curve(ch) if math.isfinite(p.mean)]
            if not pts:
                continue
            best = min(pts, key=lambda p: p.mean)
            pick = best
            if c.rule == "1se":
                limit = best.mean + (best.se if math.isfinite(best.se) else 0.0)
                ok = [p for p in pts if p.mean <= limit]
                pick = min(ok, key=lambda p: p.value) if direction < 0 else max(ok, key=lambda p: p.value)
            self.chosen[ch] = pick.value

    def spec_for(self, spec: FitSpec, channel: str) -> FitSpec:
        """The spec the final fit of ``channel`` uses: the chosen value, no ``[choose]``."""
        return set_value(spec, self.choose.key, self.chosen[channel])

    def rows(self) -> list[dict[str, Any]]:
        out = []
        for p in self.points:
            out.append({"key": self.choose.key, "value": p.value, "channel": p.channel, "folds": len(p.fold_rmse),
                        "mean_heldout_rmse_mm": p.mean, "se_mm": p.se, "pooled_heldout_rmse_mm": p.pooled,
                        "fold_rmse_mm": " ".join(f"{r:.6g}" for r in p.fold_rmse),
                        "chosen": self.chosen.get(p.channel) == p.value})
        return out

    def metadata(self) -> dict[str, Any]:
        c = self.choose
        return {"key": c.key, "rule": c.rule, "group": c.group, "folds": max(self.n_folds, len(self.folds)),
                "folds_scored": len(self.folds), "values": list(c.values),
                "chosen": dict(self.chosen),
                "curve": {ch: {repr(p.value): {"mean_rmse_mm": p.mean, "se_mm": p.se} for p in self.curve(ch)}
                          for ch in dict.fromkeys(p.channel for p in self.points)}}

    def text_lines(self) -> list[str]:
        c = self.choose
        made = max(self.n_folds, len(self.folds))
        scored = "" if made == len(self.folds) else f", {len(self.folds)} scored"
        lines = [f"[[Choice]] {c.key} by {made}-fold cross-validation on the training data "
                 f"(group {c.group}{scored}, rule {c.rule}): " + ", ".join(f"{ch} {v:g}" for ch, v in self.chosen.items())]
        lines += [f"    note: {n}" for n in self.notes]
        for ch in dict.fromkeys(p.channel for p in self.points):
            for p in self.curve(ch):
                mark = "  <- chosen" if self.chosen.get(ch) == p.value else ""
                lines.append(f"    {ch} {c.key} = {p.value:<8g} held-out RMSE {p.mean:.4f} +/- {p.se:.4f} mm "
                             f"(pooled {p.pooled:.4f}){mark}")
        return lines

    def save(self, out: str | Path) -> dict[str, Path]:
        from coartic.outputs import atomic_write_text

        out = Path(out)
        paths = {"choose_csv": out / "choose.csv", "choose_figure": out / "choose.png"}
        buf = io.StringIO()
        rows = self.rows()
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
        atomic_write_text(paths["choose_csv"], buf.getvalue())
        curve_figure(self, paths["choose_figure"])
        return paths


def curve_figure(choice: Choice, path: Path) -> Path:
    """Mean held-out RMSE ± one SE against the value, per channel; the chosen value marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from coartic.outputs import save_figure

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for ch in dict.fromkeys(p.channel for p in choice.points):
        pts = choice.curve(ch)
        line = ax.errorbar([p.value for p in pts], [p.mean for p in pts], yerr=[p.se for p in pts], marker="o",
                           capsize=3, label=ch)
        if ch in choice.chosen:
            v = choice.chosen[ch]
            ax.plot([v], [next(p.mean for p in pts if p.value == v)], "*", ms=14, color=line[0].get_color())
    vals = choice.choose.values
    if min(vals) > 0 and max(vals) / min(vals) >= 10:
        ax.set_xscale("log")
    ax.set_xlabel(f"{choice.choose.key} (star: chosen, rule {choice.choose.rule})")
    ax.set_ylabel("held-out RMSE (mm), mean ± SE over folds")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def cross_validate(spec: FitSpec, utterances: Sequence[Utterance], progress: Progress | None = None,
                   console: Console | None = None) -> Choice:
    """Fit (``coartic.fit.run``: nothing is written) and score every (value, fold) of ``spec.choose`` on
    ``utterances`` and pick the values.

    A fold whose held-out utterances have a phoneme its training lacks cannot be scored: it is
    left out (said in ``notes``); none scorable is an error naming ``[choose]``. Ctrl-C propagates
    (KeyboardInterrupt): the caller writes nothing of a half-made choice.
    """
    from coartic.fit.runner import run  # the least-squares job: engines and all, loaded when a choice is made

    c = spec.choose
    if c is None:
        raise UsageError("cross_validate needs a spec with [choose]")
    try:
        folds = kfold_splits(spec.with_options(validate={"group": c.group, "folds": c.folds}), utterances)
    except SpecError as e:  # named by [choose], where the grouping came from
        why = str(e).partition("] ")[2] or str(e)
        raise SpecError.at(spec.path, "choose", f"group = {c.group!r}, in {len(utterances)} training utterances: "
                           f"{why}") from None
    points = {(v, ch): CurvePoint(v, ch, [], []) for v in c.values for ch in spec.channels}
    scored: list[str] = []
    notes: list[str] = []
    own = progress is None
    if progress is None:
        columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("{task.fields[info]}"), TimeElapsedColumn())
        progress = LineProgress(*columns, console=console or Console(stderr=True), quiet=console is None)
        progress.start()
    try:
        task = progress.add_task(f"choosing {c.key}", total=len(c.values) * len(folds), info="")
        for name, train, test in folds:
            unseen = sorted({lab for u in test for lab in u.labels} - {lab for u in train for lab in u.labels})
            if unseen:  # nothing to fit: the table could not predict the held-out utterances
                notes.append(f"{name}: the held-out utterances contain phonemes its training lacks: {unseen}; "
                             "fold left out of the choice")
                progress.advance(task, len(c.values))
                continue
            ok = True
            for v in c.values:
                progress.update(task, info=f"{c.key} = {v:g}, {name}")
                res = run(set_value(spec, c.key, v), utterances=train, quiet=True)
                if res.interrupted:
                    raise KeyboardInterrupt
                try:
                    for sc in score(res, test, name):
                        p = points[v, sc.channel]
                        p.fold_rmse.append(sc.test_rmse)
                        p.fold_samples.append(sc.test_samples)
                except UnseenPhonemes as e:
                    notes.append(f"{e}; fold left out of the choice")
                    ok = False
                    progress.advance(task, len(c.values) - c.values.index(v))
                    break
                progress.advance(task)
            if ok:
                scored.append(name)
        progress.update(task, info="done")
        progress.stop_task(task)
    finally:
        if own:
            progress.stop()
    if not scored:
        raise SpecError.at(spec.path, "choose", f"no {c.group} fold can be scored (each holds out phonemes its "
                           f"training lacks: {'; '.join(notes)}); group by something else or give more utterances")
    choice = Choice(c, [p for p in points.values() if p.fold_rmse], scored, len(folds), notes=notes)
    choice.pick()
    return choice
