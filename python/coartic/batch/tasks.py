"""The units of a batch, as plain functions a Dask worker (or this process) runs.

Two kinds of task:

``load_group(group)``
    reads one speaker's or session's trials through ``coartic.fit.data`` and returns the
    ``Utterance`` list: NumPy arrays and strings, which pickle. A ``coartic._core.Corpus`` (a PyO3
    class) does not pickle, and need not: the fit below builds it on the worker from these arrays.
``fit_unit(spec, utterance_lists, key, ...)``
    fits one channel with ``coartic.jobs.fit.fit_job`` (the whole least-squares job, as
    ``coartic fit`` runs it) into a temporary folder on the worker, and returns the files it wrote
    as bytes. The client lands them in the output folder: workers need no write access to it, only
    read access to the recordings.
``posterior_unit(spec, config, table, utterance_lists, key, ...)``
    samples the channel's posteriors (``coartic.mcmc``: per phoneme or joint, as the fit spec's
    ``[mcmc]`` says) around the group's fitted table, the same way, and returns the chains,
    summaries, plots and the table with the posterior quantiles.

The Rust core runs each evaluation on rayon's global thread pool, whose size it reads once, from
``RAYON_NUM_THREADS`` (default: every core), at the first parallel call in a process.
``cap_threads`` sets it before that call, so that workers × threads stays within the cores.
"""

from __future__ import annotations

import math
import os
import socket
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from coartic.errors import CoarticError
from coartic.model import Utterance
from coartic.fit.spec import FitSpec

RAYON_ENV = "RAYON_NUM_THREADS"
# Statuses of coartic.fit whose point is not a finished fit: such a unit fails (and is not landed).
FAILED_STATUSES = frozenset({"failed", "non-finite start", "interrupted"})


class UnitFailed(CoarticError, RuntimeError):
    """A unit whose fit did not finish; the message names the unit and the engine's reason."""


KINDS = ("fit", "posterior")


@dataclass(frozen=True)
class UnitKey:
    """One unit: the fit of a group's (or the pooled corpus's, ``group`` None) channel, or the
    posteriors (``kind`` "posterior", coartic.mcmc) of a group's channel around its fit."""

    group: str | None
    channel: str
    kind: str = "fit"

    @property
    def label(self) -> str:
        base = f"{self.group if self.group is not None else 'pooled'} {self.channel}"
        return base if self.kind == "fit" else f"{base} {self.kind}"

    @property
    def fit(self) -> UnitKey:
        """The fit unit this unit starts from (itself for a fit)."""
        return UnitKey(self.group, self.channel)


@dataclass
class UnitOutput:
    """What a unit sends back: the files the fit job wrote, and where and how long it ran."""

    key: UnitKey
    files: dict[str, bytes]
    compute_s: float  # the fit itself (coartic.jobs.fit.fit_job), on the worker
    load_s: float  # unpacking the data (the Corpus is built inside the fit)
    host: str
    pid: int
    rayon_threads: str  # RAYON_NUM_THREADS as the worker saw it ('' = unset: every core)
    status: str
    rmse: float
    cpu_s: float = math.nan  # CPU time of the worker process during the fit (every thread)


def cap_threads(threads: int | None) -> None:
    """Cap the core's rayon pool in this process, unless the environment already caps it.

    Effective only before the first parallel call of the core in this process (a fresh worker); a
    worker started with ``RAYON_NUM_THREADS`` set keeps its own value.
    """
    if threads is not None and threads >= 1 and not os.environ.get(RAYON_ENV):
        os.environ[RAYON_ENV] = str(int(threads))


def load_group(spec: FitSpec, group: str | None, threads: int | None = None) -> list[Utterance]:
    """Every trial of one group, read with ``coartic.fit.data`` (errors name the trial and spec)."""
    cap_threads(threads)
    from coartic.fit.data import load_utterances, manifest_rows

    manifest = spec.corpus_spec.manifest
    if manifest is not None and not manifest.is_file():
        # the usual cause on a cluster: the recordings are not where the client read them
        raise UnitFailed(f"group {group}: {manifest} is not readable on the worker at {socket.gethostname()} "
                         f"(working directory {os.getcwd()}); every worker must read the recordings at the "
                         f"paths the client gives (spec {spec.path})")
    utts = load_utterances(spec, manifest_rows(spec))
    if group is not None:
        for u in utts:  # the pooled fit and the report tell the groups apart by this
            u.meta["group"] = group
    return utts


def fit_unit(spec: FitSpec, utterance_lists: Sequence[Sequence[Utterance]], key: UnitKey,
             threads: int | None = None, before: Callable[[UnitKey], None] | None = None) -> UnitOutput:
    """Fit ``key.channel`` on the concatenated utterance lists with the fit job (``coartic.jobs.fit``).

    ``before`` is called first, on the worker, with the unit's key (fault injection in tests).
    Raises UnitFailed when the engine did not finish (nothing of it is landed).
    """
    cap_threads(threads)
    if before is not None:
        before(key)
    t0 = time.perf_counter()
    utts = [u for lst in utterance_lists for u in lst]
    from coartic.jobs.fit import fit_job  # (a worker's first unit imports it: not part of the fit's time)

    t1 = time.perf_counter()
    c1 = time.process_time()

    with tempfile.TemporaryDirectory(prefix="coartic-unit-") as tmp:
        result = fit_job(spec.with_options(channels=(key.channel,)), tmp, utterances=utts, quiet=True, report=False)
        t2 = time.perf_counter()
        c2 = time.process_time()
        fit = result.channels.get(key.channel)
        if fit is None or result.interrupted or fit.status in FAILED_STATUSES:
            why = "nothing was fitted" if fit is None else f"{fit.status}: {fit.message}"
            raise UnitFailed(f"unit {key.label}: the fit did not finish ({why}; spec {spec.path})")
        files = {p.name: p.read_bytes() for p in sorted(Path(tmp).iterdir()) if p.is_file()}
    return UnitOutput(key=key, files=files, compute_s=t2 - t1, load_s=t1 - t0, host=socket.gethostname(),
                      pid=os.getpid(), rayon_threads=os.environ.get(RAYON_ENV, ""), status=fit.status,
                      rmse=fit.rmse, cpu_s=c2 - c1)


def _files(root: Path, skip: frozenset[str] = frozenset()) -> dict[str, bytes]:
    """Every file under ``root`` by its relative path (POSIX)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.relative_to(root).as_posix() not in skip}


def posterior_unit(spec: FitSpec, config: Any, table: dict[str, Any], utterance_lists: Sequence[Sequence[Utterance]],
                   key: UnitKey, threads: int | None = None,
                   before: Callable[[UnitKey], None] | None = None) -> UnitOutput:
    """Sample ``key.channel``'s posteriors around the fitted ``table`` (its JSON document) with
    ``coartic.mcmc`` and return what it wrote, plus ``table.json`` with the posterior quantiles."""
    import json
    from dataclasses import replace

    from coartic.mcmc.job import record_posterior, sample_table
    from coartic.table import ParameterTable

    cap_threads(threads)
    if before is not None:
        before(key)
    t0 = time.perf_counter()
    utts = [u for lst in utterance_lists for u in lst]
    with tempfile.TemporaryDirectory(prefix="coartic-posterior-") as tmp_:
        tmp = Path(tmp_)
        fitted = tmp / "fit_table.json"
        tab = ParameterTable.from_json_dict(table, source=f"the fit of unit {key.fit.label}")
        tab.save(fitted)
        t1 = time.perf_counter()
        c1 = time.process_time()
        runs, interrupted = sample_table(spec, replace(config, channels=(key.channel,)), tab, fitted, utts,
                                         tmp / "mcmc", progress=False)
        t2 = time.perf_counter()
        c2 = time.process_time()
        if interrupted:
            raise UnitFailed(f"unit {key.label}: sampling was interrupted")
        for r in runs:
            record_posterior(tab, r)
        not_converged = [r.label for r in runs if not r.result.converged]
        tab.save(tmp / "table.json")
        index = [{"label": r.label, "phoneme": r.phoneme, "converged": bool(r.result.converged),
                  "directory": r.directory.relative_to(tmp).as_posix()} for r in runs]
        (tmp / "posteriors.json").write_text(json.dumps(index, indent=1) + "\n", encoding="utf-8")
        files = _files(tmp, skip=frozenset({"fit_table.json"}))
    return UnitOutput(key=key, files=files, compute_s=t2 - t1, load_s=t1 - t0, host=socket.gethostname(),
                      pid=os.getpid(), rayon_threads=os.environ.get(RAYON_ENV, ""),
                      status=f"{len(runs) - len(not_converged)} of {len(runs)} converged", rmse=math.nan,
                      cpu_s=c2 - c1)
