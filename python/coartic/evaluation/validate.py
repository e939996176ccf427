"""Validation beyond the training data: k-fold by a grouping, held-out repetition, the other rate.

With ``[validate] group`` ("utterance", "sentence", "rate", "speaker" or "repetition") and
optionally ``folds``: the groups are dealt into k folds and each fold is held out once (default
one fold per group; "utterance" needs no manifest). ``group = "time"`` (``coartic fit --validate-by
time``) splits in time instead: every utterance cut at its middle segment (``halves``), the first
halves fitted and the second held out, then the reverse. Otherwise: fit on repetitions other than
``holdout_repetition`` and report RMSE on it; fit on ``train_rate`` and report RMSE on
``test_rate`` (the model's claim is that the same parameters hold at a faster rate). Each split is
a full fit of every channel (the fit job with the split's utterances), scored by
``coartic.evaluation.score`` (as measured and with each utterance's offset removed).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Protocol, Sequence

import numpy as np
from numpy.typing import NDArray
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.errors import CoarticError
from coartic.evaluation.baselines import BASELINES
from coartic.fit.data import group_of, load_utterances
from coartic.model import Utterance, utterances_for_table
from coartic.evaluation.heldout import BASELINE_COLUMNS, BaselineFigures, SplitScore, pooled
from coartic.fit.result import BAR_MM, FitResult
from coartic.evaluation.score import score_utterances, with_fallbacks
from coartic.io.labelmap import LabelMap
from coartic.errors import SpecError
from coartic.fit.spec import FitSpec
from coartic.outputs import atomic_write_text


# SplitScore.worst_vowel of test utterances without a vowel context (shown as "–")
NO_VOWEL = ("", float("nan"))


def score(result: FitResult, test: Sequence[Utterance], split: str,
          train: Sequence[Utterance] | None = None, notes: list[str] | None = None) -> list[SplitScore]:
    """RMSE of the fitted table on utterances the fit did not see (``coartic.evaluation.score``); with
    ``train`` (the split's training utterances), the baselines' on the same samples too. A held-out
    phoneme the training lacks is scored as its phonetic class's fallback the table has (the label
    map's, as ``coartic score`` does; said in ``notes``); one with none is ``UnseenPhonemes``."""
    table = result.table()
    out = []
    for ch, fit in result.channels.items():
        # pauses as the table reads them (a pause row the split's training lacks: its nearest one)
        test_ch, note = with_fallbacks(utterances_for_table(table, test), table, [ch], LabelMap.recorded(table))
        unknown = sorted({lab for u in test_ch for lab in u.labels} - set(fit.problem.phonemes))
        if unknown:
            raise UnseenPhonemes(f"{split}: the test utterances contain phonemes the training fit never saw, "
                                 f"with no phonetic-class fallback it saw: {unknown}")
        if note is not None and notes is not None:
            notes.append(f"validation, {split}, {ch}: {note.replace(' (--strict refuses instead)', '')}")
        sc = score_utterances(table, test_ch, [ch], train=train)
        by_vowel: dict[str, list[float]] = {}
        per_utterance: dict[str, tuple[float, int]] = {}
        for u, utt in enumerate(sc.utterances):
            r = sc.residuals(ch, u)
            a = by_vowel.setdefault(utt.meta.get("vowel", "?"), [0.0, 0.0])
            a[0] += float(np.nansum(r**2))
            a[1] += float(np.isfinite(r).sum())
            per_utterance[utt.name] = (float(np.nansum(r**2)), int(np.isfinite(r).sum()))
        vowel_rmse = {v: float(np.sqrt(s / n)) for v, (s, n) in by_vowel.items() if n}
        # recordings without a vowel context (real speech: no VCV manifest) have no worst vowel to name;
        # "?" there read as the glottal stop's label
        worst = (max(vowel_rmse.items(), key=lambda kv: kv[1]) if any("vowel" in u.meta for u in sc.utterances)
                 else NO_VOWEL)
        row = sc.channel_rows()[0]
        n = fit.problem.data.n_valid
        base = {r["model"]: (r["rmse_mm"], r["rmse_offset_removed_mm"], r["rmse_calibrated_mm"], r["rmse_speech_mm"],
                             r["rmse_speech_offset_removed_mm"])
                for r in sc.baseline_rows() if r["model"] != "table"}
        out.append(SplitScore(split, ch, fit.rmse, row["rmse_mm"], row["samples"], worst, row["rmse_offset_removed_mm"],
                              fit.rmse**2 * n, n, fit.packing.n_free, row["rmse_calibrated_mm"], base,
                              test_rmse_speech=row["rmse_speech_mm"],
                              test_rmse_speech_offset_removed=row["rmse_speech_offset_removed_mm"],
                              test_speech_samples=row["speech_samples"], other_session=sc.other_session,
                              utterance_sse=per_utterance))
        if fit.multistart is not None:  # how much the held-out error differs between the optima found
            for o in fit.multistart.optima:
                params, beta = fit.packing.unpack(o.x)
                t = result.table()
                t.set_from_matrix(ch, list(fit.problem.phonemes), fit.problem.table_matrix(params), beta)
                o.heldout_rmse[split] = float(score_utterances(t, test_ch, [ch]).channel_rows()[0]["rmse_mm"])
            out[-1].optima_test_rmse = tuple(o.heldout_rmse[split] for o in fit.multistart.optima)
    return out


class UnseenPhonemes(CoarticError, ValueError):
    """A held-out utterance has a phoneme its training split lacks: the table cannot predict it."""


def halves(u: Utterance) -> tuple[Utterance, Utterance]:
    """``u`` cut at the start of its middle segment: the segments and samples before, and after."""
    k = len(u.labels) // 2
    cut = u.starts[k]
    a, b = u.times < cut, u.times >= cut

    def part(sl: slice, m: NDArray[np.bool_], tag: str) -> Utterance:
        return Utterance(u.labels[sl], u.starts[sl], u.ends[sl], u.times[m], f"{u.name} ({tag})",
                         {c: v[m] for c, v in u.observed.items()}, {c: v[m] for c, v in u.valid.items()},
                         {**u.meta, "file": f"{u.meta.get('file', u.name)}#{tag}"})

    return part(slice(0, k), a, "first half"), part(slice(k, None), b, "second half")


def time_splits(utterances: Sequence[Utterance]) -> list[tuple[str, list[Utterance], list[Utterance]]]:
    """Every utterance of two segments or more cut in time (``halves``): the first halves fitted,
    the second held out, and the reverse."""
    cut = [halves(u) for u in utterances if len(u.labels) >= 2]
    first, second = [a for a, _ in cut], [b for _, b in cut]
    return [("time split: first halves fitted, second halves held out", first, second),
            ("time split: second halves fitted, first halves held out", second, first)]


def kfold_splits(spec: FitSpec, utterances: Sequence[Utterance]) -> list[tuple[str, list[Utterance], list[Utterance]]]:
    """k-fold splits by ``[validate] group``: the groups (sorted) dealt round-robin into
    ``folds`` folds (default one per group: leave one group out); each fold is held out once.
    ``group = "time"``: the two halves of every utterance in time (``time_splits``)."""
    group = spec.validate.group
    assert group is not None
    if group == "time":
        if not any(len(u.labels) >= 2 for u in utterances):
            raise SpecError.at(spec.path, "validate.group", "'time': no utterance has two segments to split")
        return time_splits(utterances)
    values = [group_of(u, group, spec) for u in utterances]
    groups = sorted(set(values), key=_natural)
    if len(groups) < 2:
        raise SpecError.at(spec.path, "validate.group", f"{group!r}: the corpus has only one {group} "
                           f"({groups[0] if groups else 'none'}), nothing to hold out")
    k = min(spec.validate.folds or len(groups), len(groups))
    out = []
    for j in range(k):
        held = set(groups[j::k])
        test = [u for u, v in zip(utterances, values) if v in held]
        train = [u for u, v in zip(utterances, values) if v not in held]
        shown = ", ".join(Path(g).name if group == "utterance" else g for g in groups[j::k])
        out.append((f"fold {j + 1}/{k} ({group} {shown} held out)", train, test))
    return out


def splits(spec: FitSpec, utterances: Sequence[Utterance],
           notes: list[str] | None = None) -> list[tuple[str, list[Utterance], list[Utterance]]]:
    """(name, train, test) for each validation the spec asks for and the corpus allows: the
    k-fold splits of ``[validate] group`` if given, else the held-out repetition and the rate.
    A held-out repetition the corpus's repetitions do not include is said in ``notes``."""
    if spec.validate.group is not None:
        return kfold_splits(spec, utterances)
    out = []
    if spec.validate.holdout_repetition is not None:
        rep = str(spec.validate.holdout_repetition)
        test = [u for u in utterances if _rep(u) == rep]
        train = [u for u in utterances if _rep(u) not in (rep, None)]
        if test and train:
            out.append((f"repetition {rep} held out", train, test))
        else:
            have = sorted({r for u in utterances if (r := _rep(u)) is not None}, key=_natural)
            if have and notes is not None:
                why = (f"the corpus has only repetition {have[0]}, none left to fit" if have == [rep]
                       else f"the corpus's repetitions are {', '.join(have)}")
                notes.append(f"{spec.path}: [validate] holdout_repetition = {rep}: {why}; that split is skipped "
                             "(hold out one of them, or give [validate] group = \"repetition\" for k-fold)")
    if spec.validate.train_rate and spec.validate.test_rate:
        train = [u for u in utterances if u.meta.get("rate") == spec.validate.train_rate]
        test = [u for u in utterances if u.meta.get("rate") == spec.validate.test_rate]
        if test and train:
            out.append((f"fit {spec.validate.train_rate} rate, test {spec.validate.test_rate} rate", train, test))
    if not out:
        raise SpecError.at(spec.path, "validate", f"the corpus has no repetition {spec.validate.holdout_repetition} / "
                           f"rates {spec.validate.train_rate!r}, {spec.validate.test_rate!r} to hold out (manifest columns "
                           "'repetition' and 'rate'); or give group = \"utterance\" (k-fold by any grouping)")
    return out


def _natural(v: str) -> tuple[int, float | str]:
    try:
        return (0, float(v))
    except ValueError:
        return (1, v)


def _rep(u: Utterance) -> str | None:
    r = u.meta.get("repetition")
    if r is None:
        return None
    try:
        return str(int(r))
    except ValueError:
        return str(r)


class FitFunction(Protocol):
    """What validation fits each split with, writing it into ``out``: ``coartic.jobs.fit.fit_job``
    (passed in by the job, so that evaluation does not import the application above it)."""

    def __call__(self, spec: FitSpec, out: str | Path | None = None, *, utterances: Sequence[Utterance] | None = ...,
                 console: Console | None = ..., quiet: bool = ..., report: bool = ...) -> FitResult: ...


def validate_all(spec: FitSpec, out: str | Path | None = None, utterances: Sequence[Utterance] | None = None,
                 console: Console | None = None, quiet: bool = False,
                 notes: list[str] | None = None, *, fit: FitFunction) -> list[SplitScore]:
    """Fit each split's training utterances with ``fit`` (``coartic.jobs.fit.fit_job``) and score its
    held-out ones; ``out`` receives one directory per split and ``validation.csv``. A fold whose
    held-out utterances have a phoneme its training lacks cannot be scored: it is skipped with a
    note (in ``notes``)."""
    if utterances is None:
        utterances = load_utterances(spec)
    scores: list[SplitScore] = []
    for name, train, test in splits(spec, utterances, notes):
        if console is not None and not quiet:
            console.print(f"[bold]validation[/bold]: {escape(name)} ({len(train)} trials to fit, {len(test)} to test)")
        sub = Path(out) / _dirname(name) if out is not None else None
        res = fit(spec, sub, utterances=train, console=console, quiet=quiet, report=False)
        try:
            scores += score(res, test, name, train, notes)
        except UnseenPhonemes as e:
            if notes is None:
                raise
            notes.append(f"validation: {e}; not scored")
        else:
            if sub is not None and any(f.multistart is not None for f in res.channels.values()):
                res.save(sub)  # its fit_report.txt and summary.json now give each optimum's held-out RMSE
        if res.interrupted:
            break
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["split", "channel", "train_rmse_mm", "test_rmse_mm", "test_rmse_offset_removed_mm", "test_samples",
                    "worst_vowel", "worst_vowel_rmse_mm", "test_rmse_speaker_calibrated_mm",
                    *(f"{b}_{k}" for b in BASELINES for k in BASELINE_COLUMNS), "beats_step_model",
                    "optima_test_rmse_mm", "test_rmse_speech_mm", "test_rmse_speech_offset_removed_mm"])
        nan = (float("nan"),) * len(BASELINE_COLUMNS)
        for sc in scores:
            w.writerow([sc.split, sc.channel, repr(sc.train_rmse), repr(sc.test_rmse), repr(sc.test_rmse_offset_removed),
                        sc.test_samples, sc.worst_vowel[0], repr(sc.worst_vowel[1]), repr(sc.test_rmse_calibrated),
                        *(repr(v) for b in BASELINES for v in sc.baselines.get(b, nan)), sc.beats_step,
                        # each multi-start optimum's held-out RMSE, best (in-sample) first
                        ";".join(f"{v:.6g}" for v in sc.optima_test_rmse), repr(sc.test_rmse_speech),
                        repr(sc.test_rmse_speech_offset_removed)])
        atomic_write_text(Path(out) / "validation.csv", buf.getvalue())
    return scores


def _dirname(split: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in split).strip("_")


def validation_table(scores: Sequence[SplitScore]) -> Table:
    from coartic.evaluation.baselines import caption

    have = [b for b in ("step", "constant", "warped") if any(b in sc.baselines for sc in scores)]
    absent = {b: ("no split's test sentence has another token in its training data" if b == "warped" else
                  "not computed") for b in ("step", "constant", "warped") if b not in have}
    t = Table(title=f"Validation RMSE (mm) on data the fit did not see — bar {BAR_MM} mm",
              caption=caption(have, absent) + " (as measured / offset removed; speech only: pauses left out); ✗ = "
                      "the table does not beat the step model")
    for c in ("split", "channel", "train", "test", "test, offset removed", "test, speech only", *have,
              "worst vowel (test)"):
        t.add_column(c, justify="left" if c in ("split", "channel") else "right")

    def pair(v: tuple[float, ...] | None) -> str:
        return "–" if v is None else f"{v[0]:.3f} / {v[1]:.3f} (speech only {v[3]:.3f} / {v[4]:.3f})"

    def cell(v: float) -> str:
        col = "green" if v < BAR_MM else "red"
        return f"[{col}]{v:.3f}[/{col}]"

    for sc in scores:
        mark = "" if sc.beats_step else " [bold red]✗[/bold red]"
        t.add_row(escape(sc.split), sc.channel + mark, f"{sc.train_rmse:.3f}", cell(sc.test_rmse),
                  cell(sc.test_rmse_offset_removed),
                  f"{sc.test_rmse_speech:.3f} / {sc.test_rmse_speech_offset_removed:.3f}",
                  *(pair(sc.baselines.get(b)) for b in have),
                  f"{sc.worst_vowel[1]:.3f} ({escape(sc.worst_vowel[0])})" if sc.worst_vowel[0] else "–")
    if len({sc.split for sc in scores}) > 1:
        def both(b: str, ch: str) -> BaselineFigures | None:
            a, s = pooled(scores, b).get(ch), pooled(scores, b, speech=True).get(ch)
            return None if a is None else (a[0], a[1], float("nan"), *(s[:2] if s else (float("nan"),) * 2))

        speech = pooled(scores, speech=True)
        for ch, (rm, ro, _) in pooled(scores).items():
            rs, rso = speech[ch][:2] if ch in speech else (float("nan"), float("nan"))
            t.add_row("[bold]all splits pooled[/bold]", ch, "", cell(rm), cell(ro), f"{rs:.3f} / {rso:.3f}",
                      *(pair(both(b, ch)) for b in have), "")
    return t
