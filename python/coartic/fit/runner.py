"""The whole least-squares job: load the corpus, fit every channel, collect and save the result.

``run(spec)`` is what ``coartic fit`` calls. Channels are fitted one after the other (the Rust core
already uses both cores inside each evaluation). When ``out`` is given, the result is written after
every channel, so an interrupted run keeps what it finished; Ctrl-C during a channel keeps that
channel's best point, marks the result interrupted, writes it and stops.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

import numpy as np
from rich.console import Console
from threadpoolctl import threadpool_limits
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from coartic.fit.problem import ChannelProblem, Utterance, build_problem
from coartic.fit.result import ChannelFit, FitResult, finish_channel, now
from coartic.fit.spec import FitSpec, SpecError, load_spec
from coartic.fit.staged import fit_staged
from coartic.table import ParameterTable


def start_values(spec: FitSpec, channel: str, phonemes: Sequence[str]) -> tuple[np.ndarray, float] | None:
    """Start values from ``parameters.start_table`` ("from table"), or None (defaults and data)."""
    if spec.start_table is None:
        return None
    try:
        table = ParameterTable.load(spec.start_table)
        return table.to_matrix(channel, phonemes)
    except ValueError as e:
        raise SpecError(f"{spec.path}: [parameters.start_table] {e}") from None


def fit_channel(spec: FitSpec, utterances: Sequence[Utterance], channel: str,
                progress: Progress | None = None) -> ChannelFit:
    """Fit one channel (staged if the spec says so); never raises on a bad start or Ctrl-C."""
    problem: ChannelProblem = build_problem(spec, utterances, channel)
    start = start_values(spec, channel, problem.data.phonemes)
    if start is not None:
        problem = build_problem(spec, utterances, channel, start=start)
    task = None
    if progress is not None:
        task = progress.add_task(f"{channel}", total=None, info="")

        def monitor(nfev: int, best: float) -> None:
            rmse = np.sqrt(best / max(problem.data.n_valid, 1))
            progress.update(task, advance=1, info=f"RMSE {rmse:.3f} mm")

        problem.monitor = monitor
    t0 = time.perf_counter()

    def on_stage(i: int, n: int, p: ChannelProblem) -> None:
        if progress is not None and task is not None:
            progress.update(task, description=f"{channel} stage {i + 1}/{n} ({p.packing.n_free} free)")

    # One BLAS thread: the dense solves are small, and the machine's cores are better spent in the
    # Rust core; a multi-threaded BLAS on busy cores made them 10-30x slower.
    with threadpool_limits(limits=1, user_api="blas"):
        final, res, stages = fit_staged(problem, spec.engine, spec.engine_options,
                                        spec.stages if spec.staging else None, on_stage)
    try:
        fit = finish_channel(final, res.x, res.status, res.message, time.perf_counter() - t0, stages)
    except KeyboardInterrupt:  # Ctrl-C while the statistics were computed: keep the fitted point
        fit = finish_channel(final, res.x, "interrupted", "stopped by the user (Ctrl-C) after the fit",
                             time.perf_counter() - t0, stages)
    if progress is not None and task is not None:
        progress.update(task, description=f"{channel} done", info=f"RMSE {fit.rmse:.3f} mm [{fit.status}]")
        progress.stop_task(task)
    return fit


def run(spec: FitSpec | str | Path, out: str | Path | None = None, *, utterances: Sequence[Utterance] | None = None,
        console: Console | None = None, quiet: bool = False) -> FitResult:
    """Fit every channel of ``spec`` and return the FitResult (also saved to ``out`` if given).

    ``utterances`` skips loading (e.g. a validation split of already loaded data).
    """
    if not isinstance(spec, FitSpec):
        spec = load_spec(spec)
    console = console or Console(stderr=True, quiet=quiet)
    result = FitResult(spec, {}, now())
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[info]}"), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=False, disable=quiet) as progress:
        if utterances is None:
            from coartic.fit.data import load_utterances, manifest_rows

            rows = manifest_rows(spec)
            task = progress.add_task("loading trials", total=len(rows), info="")
            try:
                utterances = load_utterances(spec, rows, lambda i, n: progress.update(task, completed=i))
            except KeyboardInterrupt:
                result.interrupted = True
                result.notes.append("interrupted while loading the trials: nothing was fitted")
                return result
        for ch in spec.channels:
            try:
                fit = fit_channel(spec, utterances, ch, progress)
            except KeyboardInterrupt:  # between engine calls: nothing of this channel to keep
                result.interrupted = True
                break
            result.channels[ch] = fit
            if fit.status == "interrupted":
                result.interrupted = True
            if out is not None:
                result.save(out)
            if result.interrupted:
                break
    if result.interrupted:
        done = ", ".join(result.channels) or "none"
        result.notes.append(f"interrupted by the user; channels finished or partly fitted: {done}")
        if out is not None:
            result.save(out)
    return result
