"""The least-squares fit of a spec: load the corpus, fit every channel, return the result.

``run(spec)`` returns the ``FitResult`` and writes nothing: the job that also validates, writes the
files and the report is ``coartic.jobs.fit`` (what ``coartic fit`` calls), which saves the result
after every channel through ``run``'s ``on_channel``, so an interrupted run keeps what it finished.
Channels are fitted one after the other (the Rust core already uses both cores inside each
evaluation); Ctrl-C during a channel keeps that channel's best point, marks the result interrupted
and stops.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from rich.console import Console
from rich.markup import escape
from threadpoolctl import threadpool_limits
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from coartic.console import LineProgress
from coartic.errors import CoarticError
from coartic.fit.engines import EngineResult, OptionError, check_options
from coartic.estimation.emotions import estimate_prior
from coartic.estimation.problem import ChannelProblem, build_problem
from coartic.model import Utterance
from coartic.fit.result import ChannelFit, Chosen, FitResult, finish_channel, now
from coartic.errors import SpecError, UsageError
from coartic.fit.spec import FitSpec, load_spec
from coartic.fit.multistart import MultiStart, fit_multistart
from coartic.fit.staged import EB_CANDIDATES, channel_status, fit_pooled, fit_pooled_best, fit_staged
from coartic.pauses import STAND_INS
from coartic.table import ParameterTable


# Starts one after the other, each using both cores through the core's rayon: on the 2-core
# machine, two starts at once in threads were slower (bench/multistart.py, docs/FITTING.md).
MULTISTART_WORKERS = 1


def start_values(spec: FitSpec, channel: str, phonemes: Sequence[str]) -> tuple[np.ndarray, float] | None:
    """Start values from ``parameters.start_table`` ("from table"), or None (defaults and data)."""
    if spec.start_table is None:
        return None
    try:
        table = ParameterTable.load(spec.start_table)
        # a table fitted with one pause label starts each pause posture from that pause's row
        have = set(table.phonemes_for(channel))
        rows = [ph if ph in have else next((s for s in STAND_INS.get(ph, ()) if s in have), ph) for ph in phonemes]
        return table.to_matrix(channel, rows)
    except ValueError as e:
        raise SpecError.at(spec.path, "parameters.start_table", str(e)) from None


def fit_channel(spec: FitSpec, utterances: Sequence[Utterance], channel: str,
                progress: Progress | None = None) -> ChannelFit:
    """Fit one channel (staged if the spec says so); never raises on a bad start or Ctrl-C."""
    settings = spec.estimation_settings()
    problem: ChannelProblem = build_problem(settings, utterances, channel)
    start = start_values(spec, channel, problem.phonemes)
    if start is not None:
        problem = build_problem(settings, utterances, channel, start=start)
    if problem.packing.n_free == 0:  # no start, stage or engine has anything to move: say so, not "converged"
        raise SpecError.at(spec.path, "parameters.free", f"{channel}: no parameter is free (free = "
                           f"{list(spec.parameters.free)!r}, and no [[override]] or fit_beta frees one): nothing to fit; free "
                           "at least one (e.g. free = [\"target\"]), or predict with a fixed table by coartic score")
    task = None
    if progress is not None:
        task = progress.add_task(f"{channel}", total=None, info="", unit="evaluations")

        # the best objective so far as an RMS (mm): the data RMSE only when nothing is added to the SSE
        what = "penalised RMS" if problem.penalised else "RMSE"

        def monitor(nfev: int, best: float) -> None:
            rms = np.sqrt(best / max(problem.data.n_valid, 1))
            progress.update(task, advance=1, info=f"{what} {rms:.3f} mm")

        problem.monitor = monitor
    t0 = time.perf_counter()

    def on_stage(i: int, n: int, p: ChannelProblem) -> None:
        if progress is not None and task is not None:
            progress.update(task, description=f"{channel} stage {i + 1}/{n} ({p.packing.n_free} free)")

    # One BLAS thread: the dense solves are small, and the machine's cores are better spent in the
    # Rust core; a multi-threaded BLAS on busy cores made them 10-30x slower.
    stage_names = spec.staging.stages if spec.staging.enabled else None
    multi: MultiStart | None = None
    with threadpool_limits(limits=1, user_api="blas"):
        if spec.fit.starts > 1:
            def on_start(done: int, total: int, what: str) -> None:
                if progress is not None and task is not None:
                    progress.update(task, description=f"{channel} multi-start: {what} done")

            final, res, stages, multi = fit_multistart(problem, spec.engine.name, spec.engine.options, stage_names,
                                                       spec.fit.starts, spec.fit.seed, spec.fit.probe, spec.fit.keep,
                                                       workers=MULTISTART_WORKERS, on_start=on_start,
                                                       include_start=spec.fit.include_start)
        else:
            final, res, stages = fit_staged(problem, spec.engine.name, spec.engine.options, stage_names, on_stage)
        if spec.groups.emotions != "none" and res.status not in ("interrupted", "failed", "non-finite start"):
            # the deviations' scale τ from the fit without their prior, then the fit with it from there
            # (coartic.estimation.emotions)
            prior = estimate_prior(final, res.x)
            final, res, more = fit_staged(final.with_emotion_prior(prior), spec.engine.name, spec.engine.options, None,
                                          on_stage)
            stages = [*stages, *more]
        pooling = None
        if final.pool is not None and res.status in ("converged", "max-evaluations"):
            # partial pooling: the pool's sd estimated from the data, the fit re-solved at it
            if progress is not None and task is not None:
                progress.update(task, description=f"{channel} pooling (sd estimated)")
            if multi is not None and len(multi.optima) > 1:
                # every distinct optimum's empirical Bayes, the highest evidence kept (fit_pooled_best)
                others = sorted(multi.optima[1:], key=lambda o: o.objective)
                picked = others[:EB_CANDIDATES - 1]
                zero = next((o for o in others if 0 in o.starts), None)
                if zero is not None and zero not in picked:  # start 0's (the single fit's) always
                    picked.append(zero)
                # the data weight from start 0's optimum (the single fit's, whatever the seed), else the best's
                at = next((k + 1 for k, o in enumerate(picked) if 0 in o.starts), 0)
                final, pooled_res, pooling = fit_pooled_best(
                    final, [res.x] + [o.x for o in picked], spec.engine.name, spec.engine.options,
                    [multi.best.objective] + [o.objective for o in picked], weigh_at=at)
            else:
                final, pooled_res, pooling = fit_pooled(final, res.x, spec.engine.name, spec.engine.options)
            if pooled_res is not None:
                keep = res.status == "converged" and pooled_res.status == "converged"
                status = res.status if keep else pooled_res.status
                message = res.message if keep else f"re-solving at the estimated pooling sd: {pooled_res.message}"
                if pooled_res.status in ("failed", "non-finite start"):
                    # the fit itself converged; a re-solve at a later pooling sd did not, and the
                    # optimum of the last round that did is kept (fit_pooled): unconfirmed, not lost
                    status = "stage-failed"
                    message += "; the optimum at the last pooling sd that converged is kept (the sd not settled)"
                res = EngineResult(pooled_res.x, status, message,
                                   res.nfev + pooled_res.nfev, res.njev + pooled_res.njev)
    status, message = channel_status(res, stages, multi is not None and multi.best_found_once)
    try:
        fit = finish_channel(final, res.x, status, message, time.perf_counter() - t0, stages)
    except KeyboardInterrupt:  # Ctrl-C while the statistics were computed: keep the fitted point
        fit = finish_channel(final, res.x, "interrupted", "stopped by the user (Ctrl-C) after the fit",
                             time.perf_counter() - t0, stages)
    fit.multistart = multi
    fit.pooling = pooling
    if progress is not None and task is not None:
        progress.update(task, description=f"{channel} done", info=escape(f"RMSE {fit.rmse:.3f} mm [{fit.status}]"))
        progress.stop_task(task)
    return fit


class FitFailed(CoarticError, ValueError):
    """An engine failed on a channel (its result would be the unfitted start values): the message
    names the channel, the engine and the engine's own words; ``channel`` is the channel."""

    def __init__(self, message: str, channel: str = "") -> None:
        super().__init__(message)
        self.channel = channel


# Engine outcomes that leave no fitted values: the run stops and says so, instead of writing the
# start values as if they were a fit. ("max-evaluations" is a fit, reported in the status column.)
FAILED_STATUSES = ("failed", "non-finite start")


# What the caller is told after each channel (the job saves the result then, so that an interrupted
# run keeps what it finished); and what chooses a ``[choose]`` setting on the (training) utterances
# before the fit (``coartic.evaluation.choose.cross_validate``: an evaluation, above the fit).
ChannelDone = Callable[[FitResult], None]
Chooser = Callable[[FitSpec, Sequence[Utterance], Progress], Chosen]


def run(spec: FitSpec | str | Path, *, utterances: Sequence[Utterance] | None = None,
        console: Console | None = None, quiet: bool = False, on_channel: ChannelDone | None = None,
        choose: Chooser | None = None) -> FitResult:
    """Fit every channel of ``spec`` and return the FitResult; nothing is written.

    ``on_channel(result)`` is called after every channel is added to the result (and when a
    channel is interrupted), so that a caller can save what is finished: ``coartic.jobs.fit``
    writes the result there, and the validation and the report at the end. ``choose`` makes the
    ``[choose]`` setting's choice on the utterances before the fit (a spec with ``[choose]``
    needs it: ``coartic.evaluation.choose.cross_validate``, which ``coartic.jobs.fit.fit_job`` passes).
    Ctrl-C during a channel keeps that channel's best point, marks the result interrupted and
    stops.

    ``utterances`` skips loading (e.g. a validation split of already loaded data).

    Raises
    ------
    FitFailed
        An engine failed on a channel (it is not in the result); names the channel.
    SpecError, DataError
        A spec or data problem, naming the file and key.
    """
    if not isinstance(spec, FitSpec):
        spec = load_spec(spec)
    check_engine_options(spec)
    console = console or Console(stderr=True, quiet=quiet)
    result = FitResult(spec, {}, now())
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[info]}"), TimeElapsedColumn())
    with LineProgress(*columns, console=console, quiet=quiet) as progress:
        if utterances is None:
            from coartic.fit.data import load_utterances, manifest_rows

            rows = manifest_rows(spec)
            task = progress.add_task("loading trials", total=len(rows), info="")
            try:
                utterances = load_utterances(spec, rows, lambda i, n: progress.update(task, completed=i),
                                             notes=result.notes)
                progress.stop_task(task)
            except KeyboardInterrupt:
                result.interrupted = True
                result.notes.append("interrupted while loading the trials: nothing was fitted")
                return result
            result.notes += check_overrides(spec, utterances)
        else:  # given utterances (a validation split, a script's): pauses as the spec fits them
            from coartic.fit.data import with_spec_pauses

            utterances = with_spec_pauses(spec, utterances, result.notes)
        from coartic.fit.guards import small_data_notes

        result.notes += small_data_notes(spec, utterances)  # settings the data cannot support: refused or warned
        result.utterances = list(utterances)
        if spec.choose is not None:  # the setting first, on these (training) utterances
            if choose is None:
                raise UsageError(f"{spec.path}: [choose] {spec.choose.key} is chosen by cross-validation, an "
                                 "evaluation above the fit: fit it with coartic.jobs.fit.fit_job (what coartic fit "
                                 "runs), or pass choose=coartic.evaluation.choose.cross_validate")
            try:
                result.choice = choose(spec, utterances, progress)
            except KeyboardInterrupt:
                result.interrupted = True
                result.notes.append(f"interrupted while choosing {spec.choose.key} by cross-validation: nothing was fitted")
                return result
            result.notes += result.choice.notes
        for ch in spec.channels:
            try:
                fit = fit_channel(spec if result.choice is None else result.choice.spec_for(spec, ch),
                                  utterances, ch, progress)
            except KeyboardInterrupt:  # between engine calls: nothing of this channel to keep
                result.interrupted = True
                break
            if fit.status in FAILED_STATUSES:
                raise FitFailed(f"channel {ch}: the {spec.engine.name} engine failed ({fit.status}): {fit.message}",
                                channel=ch)
            result.channels[ch] = fit
            if fit.status == "interrupted":
                result.interrupted = True
            if on_channel is not None:
                on_channel(result)
            if result.interrupted:
                break
    if result.interrupted:
        done = ", ".join(result.channels) or "none"
        result.notes.append(f"interrupted by the user; channels finished or partly fitted: {done}")
    return result


def check_engine_options(spec: FitSpec) -> None:
    """``[engine.options]`` checked before anything is loaded: errors name the spec and the key."""
    try:
        check_options(spec.engine.name, spec.engine.options)
    except OptionError as e:
        raise SpecError.at(spec.path, f"engine.options.{e.key}", f"({spec.engine.name} engine) {e.message}",
                           parameter=e.key) from None


def check_overrides(spec: FitSpec, utterances: Sequence[Utterance]) -> list[str]:
    """Every ``[[override]]``, ``[[tie]]`` and ``[[shrink]]`` against the phonemes of the corpus: one
    that could change nothing is refused (an override none of whose phonemes occurs; a tie or shrink
    with fewer than two members present, which would have nothing to share or pull together); one
    naming some absent phonemes (e.g. /b/ of "p b m" in a corpus cut by ``select`` or ``limit``)
    applies to the others, and the returned notes say which were absent. Checked on the whole
    corpus, not on a validation split, which may lack a phoneme legitimately."""
    present = {lab for u in utterances for lab in u.labels}
    inventory = f"(phonemes: {' '.join(sorted(present))})"
    notes = []
    groups = ([(f"override #{i + 1}", o.phonemes, 1) for i, o in enumerate(spec.parameters.overrides)]
              + [(f"tie #{i + 1}", t.phonemes, 2) for i, t in enumerate(spec.parameters.ties)]
              + [(s.key, s.phonemes, 2) for s in spec.priors.shrinks])
    for key, phonemes, needed in groups:
        missing = [p for p in phonemes if p not in present]
        if len(phonemes) - len(missing) < needed:
            what = "none occurs" if needed == 1 else "fewer than two occur"
            raise SpecError.at(spec.path, key, f"phonemes {list(phonemes)}: {what} in the corpus, so it would change "
                               f"nothing {inventory}", ", ".join(missing))
        if missing:
            notes.append(f"[{key}] phonemes {missing} do not occur in the corpus: not applied to them")
    return notes
