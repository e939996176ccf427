"""Run a batch: every unit as a Dask task (or one after another), results landed as they finish.

``run_batch(spec, out)`` is what ``coartic batch`` calls. Units are the fits of one group's channel
(``units/<group>/<channel>/``) and of the pooled corpus's channel (``units/_pooled/<channel>/``);
each unit's files arrive whole, under a temporary name that is renamed once everything is written,
so a folder that exists is a finished unit. A rerun into the same ``out`` skips those; Ctrl-C,
a lost worker or a failed unit loses none of them. The folder is claimed with ``coartic.outputs``
(its marker records the spec and a fingerprint of the spec files and manifests): another batch's
folder is refused rather than mixed in, and two runs never write one folder at once.

Schedulers:

- ``serial=True``: this process, one unit after the other (the reference the tests compare with);
- no ``scheduler``: a ``distributed.LocalCluster`` of worker processes on this machine, one task at
  a time each, the core's rayon threads capped at cores // workers;
- ``scheduler="tcp://host:8786"``: a running Dask scheduler (``dask scheduler`` and ``dask worker``,
  or dask-jobqueue on SLURM; docs/BATCH.md). Workers must read the recordings at the same paths:
  the batch spec gives them absolute (``load_batch_spec``), whatever the workers' directory.
  ``tls://host:8786`` with Dask's own TLS (``Tls``, ``cluster_security``).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from coartic.batch.layout import UNIT_FILE, is_done, land_dir, unit_dir
from coartic.batch.outcome import BatchOutcome
from coartic.batch.spec import BatchSpec
from coartic.batch.tasks import UnitFailed, UnitKey, UnitOutput, fit_unit, load_group, posterior_unit
from coartic.console import LineProgress
from coartic.errors import CoarticError, UsageError
from coartic.extras import require
from coartic.model import Utterance
from coartic.outputs import DeferredSignals, OutputDir


class ClusterError(CoarticError, ValueError):
    """The Dask cluster could not be started or reached; the message names the address."""


def plan_units(spec: BatchSpec) -> list[UnitKey]:
    """Every unit: each group's channels, the pooled corpus's, then each group's posteriors."""
    keys = [UnitKey(g.name, ch) for g in spec.groups for ch in spec.channels]
    if spec.pooled:
        keys += [UnitKey(None, ch) for ch in spec.channels]
    keys += [UnitKey(g.name, ch, "posterior") for g in spec.groups for ch in spec.posterior_channels]
    return keys


def output_dir(spec: BatchSpec, out: Path, force: bool = False) -> OutputDir:
    """The batch's output folder, claimed in place (coartic.outputs): a rerun of the same batch
    continues in it; another batch's folder (other spec files or manifests) is refused unless
    ``force``; two runs never write it at once."""
    identity = {"spec": str(spec.path.resolve()), "fingerprint": spec.fingerprint}
    return OutputDir(out, "batch", identity, force=force, staged=False,
                     protect=[spec.path, spec.fit.path, *(g.spec.corpus_spec.manifest for g in spec.groups
                                                          if g.spec.corpus_spec.manifest is not None)])


def land_unit(out: Path, spec: BatchSpec, result: UnitOutput) -> None:
    info = {"unit": result.key.label, "group": result.key.group, "channel": result.key.channel,
            "status": result.status, "rmse_mm": result.rmse, "compute_s": result.compute_s, "cpu_s": result.cpu_s, "load_s": result.load_s,
            "host": result.host, "pid": result.pid, "rayon_threads": result.rayon_threads,
            "fingerprint": spec.fingerprint}
    files = dict(result.files)
    files[UNIT_FILE] = (json.dumps(info, indent=2) + "\n").encode()
    land_dir(unit_dir(out, result.key), files)


# ----------------------------------------------------------------------------- schedulers


# Worker processes of a local cluster: each is a Python process with the core loaded (~150 MB), so
# a typo (10**6) would exhaust the machine's memory before any unit ran.
MAX_WORKERS = 1024


def local_threads(workers: int) -> int:
    """Rayon threads per worker so that workers × threads ≤ cores."""
    return max(1, (os.cpu_count() or 1) // max(workers, 1))


def cluster_threads(client: Any) -> int | None:
    """Rayon threads per Dask thread on the tightest host of a running cluster (None: no worker)."""
    try:
        workers = client.scheduler_info(n_workers=-1)["workers"]
    except TypeError:  # distributed before n_workers
        workers = client.scheduler_info()["workers"]
    if not workers:
        return None
    cores = client.run(os.cpu_count)
    used: dict[str, int] = defaultdict(int)
    have: dict[str, int] = {}
    for addr, w in workers.items():
        host = w.get("host", addr)
        used[host] += int(w.get("nthreads", 1))
        have[host] = int(cores.get(addr) or 1)
    return min(max(1, have[h] // used[h]) for h in used)


@dataclass(frozen=True)
class Tls:
    """Certificates for a ``tls://`` scheduler (``--tls-ca-file``, ``--tls-cert``, ``--tls-key``).
    Any left out comes from the Dask configuration (``distributed.comm.tls.ca-file``,
    ``distributed.comm.tls.client.cert`` and ``.key``), as ``dask worker`` reads them."""

    ca_file: Path | None = None
    cert: Path | None = None
    key: Path | None = None


def cluster_security(scheduler: str, tls: Tls | None) -> Any:
    """The ``distributed.Security`` for reaching ``scheduler``: Dask's own TLS (encryption
    required) for a ``tls://`` address, certificates from ``tls`` or else the Dask configuration;
    None (Dask's default) for other protocols, which take no certificates."""
    require("batch", "a Dask cluster")
    import dask.config
    from distributed.security import Security

    given = tls is not None and any(v is not None for v in (tls.ca_file, tls.cert, tls.key))
    if not scheduler.startswith("tls://"):
        if given:
            raise ClusterError(f"--scheduler {scheduler}: TLS certificates were given, but the address is not tls://; "
                               "start the scheduler with --protocol tls and pass its tls:// address")
        return None
    t = tls or Tls()
    conf = {k: dask.config.get(f"distributed.comm.tls.{k}", None) for k in ("ca-file", "client.cert", "client.key")}
    ca = str(t.ca_file) if t.ca_file is not None else conf["ca-file"]
    cert = str(t.cert) if t.cert is not None else conf["client.cert"]
    key = str(t.key) if t.key is not None else conf["client.key"]
    if not ca or not cert:
        missing = " and ".join(n for n, v in (("--tls-ca-file", ca), ("--tls-cert", cert)) if not v)
        raise ClusterError(f"--scheduler {scheduler}: a tls:// scheduler needs the CA certificate and this client's "
                           f"certificate: give {missing}, or set distributed.comm.tls.ca-file and "
                           "distributed.comm.tls.client.cert (and .key) in the Dask configuration")
    for what, f in (("CA certificate", ca), ("certificate", cert), ("key", key)):
        if f and not Path(f).is_file():
            raise ClusterError(f"--scheduler {scheduler}: the TLS {what} {f} does not exist")
    return Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key or None, require_encryption=True)


# The local cluster's dashboard (and the scheduler's HTTP server under it) listens on loopback only,
# on a free port: it shows task names and file paths, which are nobody else's business.
LOCAL_DASHBOARD = "127.0.0.1:0"


def require_packages(spec: BatchSpec | None, serial: bool) -> None:
    """Dask (the [batch] extra) unless `serial`; emcee and ArviZ (the [mcmc] extra) when the spec
    asks for posteriors; checked before anything is read or written."""
    if not serial:
        require("batch", "coartic batch on a Dask cluster (--serial runs without Dask)")
    if spec is not None and spec.posterior_channels:
        require("mcmc", "the batch spec's [posteriors]")


def run_batch(spec: BatchSpec, out: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              serial: bool = False, force: bool = False, report: bool = True, console: Console | None = None,
              quiet: bool = False, before: Callable[[UnitKey], None] | None = None,
              tls: Tls | None = None) -> BatchOutcome:
    """Run every unfinished unit of ``spec`` into ``out``, then write the tables and the report.

    ``before`` is called on the worker before each fit unit (fault injection in tests). Ctrl-C and
    SIGTERM (a job's time limit) stop the run after the units that have finished; a unit being
    landed is landed first. ``tls``: certificates for a ``tls://`` scheduler (``cluster_security``).
    """
    out = Path(out)
    if workers is not None and not 1 <= workers <= MAX_WORKERS:
        raise UsageError(f"workers = {workers}: between 1 and {MAX_WORKERS} worker processes")
    require_packages(spec, serial)
    console = console or Console(stderr=True, quiet=quiet)
    keys = plan_units(spec)
    t0 = time.perf_counter()
    security = cluster_security(scheduler, tls) if scheduler is not None and not serial else None  # refused before any output
    od = output_dir(spec, out, force)
    with DeferredSignals() as signals, od:
        # Temporary folders of a run killed mid-landing: never a finished unit.
        for stale in [*out.glob("units/*/.*.tmp-*"), *out.glob("posteriors/*/.*.tmp-*")]:
            shutil.rmtree(stale, ignore_errors=True)
        todo = [k for k in keys if not is_done(out, k)]
        outcome = BatchOutcome(out, len(keys), len(keys) - len(todo))
        columns = (TextColumn("[bold]units"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                   TextColumn("{task.description}"))
        with LineProgress(*columns, console=console, quiet=quiet) as progress:
            task = progress.add_task("", total=len(keys), completed=outcome.skipped)

            def landed(result: UnitOutput) -> None:
                with signals.saving():
                    land_unit(out, spec, result)
                outcome.landed.append(result.key)
                what = f"RMSE {result.rmse:.3f} mm" if result.key.kind == "fit" else result.status
                progress.update(task, advance=1, description=f"{result.key.label}: {what}")

            def failed(key: UnitKey, err: BaseException) -> None:
                outcome.failed[key.label] = f"{type(err).__name__}: {err}"
                progress.update(task, description=f"[red]{key.label} failed[/red]")

            try:
                if todo and serial:
                    _run_serial(spec, out, todo, landed, failed, before)
                elif todo:
                    _run_dask(spec, out, todo, landed, failed, before, scheduler, workers, outcome, console, security)
            except KeyboardInterrupt:
                outcome.interrupted = True
        from coartic.batch.report import write_outputs

        with signals.saving():
            write_outputs(spec, out, outcome, report)
        od.status = "interrupted" if outcome.interrupted else "incomplete" if outcome.failed else "complete"
    outcome.wall_s = time.perf_counter() - t0
    return outcome


def _run_serial(spec: BatchSpec, out: Path, todo: list[UnitKey], landed: Callable[[UnitOutput], None],
                failed: Callable[[UnitKey, BaseException], None],
                before: Callable[[UnitKey], None] | None) -> None:
    loaded: dict[str, list[Utterance] | BaseException] = {}
    groups = {g.name: g for g in spec.groups}

    def load(name: str) -> list[Utterance]:
        if name not in loaded:
            try:
                loaded[name] = load_group(groups[name].spec, name)
            except Exception as e:  # a bad trial fails that group's units, not the batch
                loaded[name] = e
        got = loaded[name]
        if isinstance(got, BaseException):
            raise got
        return got

    for key in todo:
        try:
            if key.kind == "posterior":
                assert key.group is not None
                table = fitted_table(out, key)
                result = posterior_unit(groups[key.group].spec, spec.mcmc, table, [load(key.group)], key, None, before)
            elif key.group is None:
                lists = [load(g.name) for g in spec.groups]
                result = fit_unit(spec.pooled_spec, lists, key, None, before)
            else:
                result = fit_unit(groups[key.group].spec, [load(key.group)], key, None, before)
        except Exception as e:
            failed(key, e)
            continue
        landed(result)


def fitted_table(out: Path, key: UnitKey) -> dict[str, Any]:
    """The landed table of the fit a posterior unit starts from (its JSON document)."""
    path = unit_dir(out, key.fit) / "table.json"
    if not is_done(out, key.fit):
        raise UnitFailed(f"unit {key.label}: its fit (unit {key.fit.label}) did not finish")
    doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return doc


def _run_dask(spec: BatchSpec, out: Path, todo: list[UnitKey], landed: Callable[[UnitOutput], None],
              failed: Callable[[UnitKey, BaseException], None], before: Callable[[UnitKey], None] | None,
              scheduler: str | None, workers: int | None, outcome: BatchOutcome, console: Console,
              security: Any = None) -> None:
    require("batch", "a Dask cluster (coartic batch without --serial)")
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    try:
        if scheduler is None:
            n = workers if workers is not None else min(os.cpu_count() or 1, len(todo))
            threads: int | None = local_threads(n)
            # One task per worker process; the core's threads capped in each (the nanny sets the
            # variable before the worker process starts, and again when it restarts a lost one).
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=LOCAL_DASHBOARD,
                                   env={"RAYON_NUM_THREADS": str(threads)},
                                   # units report their errors through their futures; the workers' own
                                   # messages at shutdown (heartbeats to a closed scheduler) are noise
                                   silence_logs=logging.CRITICAL)
            client = Client(cluster)
            outcome.workers = n
        else:
            client = Client(scheduler, timeout="30s", security=security)
            threads = cluster_threads(client)
            outcome.workers = len(client.scheduler_info().get("workers", {}))
    except KeyboardInterrupt:
        raise
    except Exception as e:  # Dask raises OSError, TimeoutError, RuntimeError... with its own words
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close()
        where = f"the Dask scheduler at {scheduler}" if scheduler else f"a local Dask cluster of {workers or 'default'} workers"
        raise ClusterError(f"cannot start or reach {where}: {type(e).__name__}: {e}") from None
    outcome.threads = threads
    by_future: dict[Any, UnitKey] = {}
    try:
        groups = {g.name: g for g in spec.groups}
        needed = {k.group for k in todo if k.group is not None}
        if any(k.group is None for k in todo):
            needed |= set(groups)
        # Loads first (every fit waits for one), pooled fits next (the longest), then the groups'.
        loads = {name: client.submit(load_group, groups[name].spec, name, threads, pure=False, priority=20)
                 for name in groups if name in needed}
        # A posterior starts from its fit's landed table: submitted once that fit is on disk.
        waiting = {k.fit: k for k in todo if k.kind == "posterior"}

        def submit_posterior(key: UnitKey) -> Any:
            assert key.group is not None
            fut = client.submit(posterior_unit, groups[key.group].spec, spec.mcmc, fitted_table(out, key),
                                [loads[key.group]], key, threads, before, pure=False, priority=5)
            by_future[fut] = key
            return fut

        for key in todo:
            if key.kind == "posterior":
                if is_done(out, key.fit):
                    submit_posterior(waiting.pop(key.fit))
                continue
            if key.group is None:
                fut = client.submit(fit_unit, spec.pooled_spec, [loads[g] for g in groups], key, threads, before,
                                    pure=False, priority=10)
            else:
                fut = client.submit(fit_unit, groups[key.group].spec, [loads[key.group]], key, threads, before,
                                    pure=False, priority=0)
            by_future[fut] = key
        if not waiting:
            del loads  # held by the units only: each group's data is freed once its units are done
        running = as_completed(list(by_future))
        for fut in running:
            key = by_future.pop(fut)
            try:
                result = fut.result()
            except Exception as e:  # the unit's error, or KilledWorker after repeated worker losses
                failed(key, e)
                if key in waiting:
                    failed(waiting.pop(key), UnitFailed(f"its fit (unit {key.label}) did not finish"))
            else:
                landed(result)
                if key in waiting:
                    running.add(submit_posterior(waiting.pop(key)))
            fut.release()
    finally:
        with contextlib.suppress(Exception):
            client.cancel(list(by_future))
        client.close()
        if cluster is not None:
            cluster.close()
