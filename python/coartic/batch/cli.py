"""``coartic batch SPEC --out DIR``: one fit spec over many speakers or sessions, on Dask."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.batch.run import MAX_WORKERS
from coartic.console import print_error, print_table
from coartic.fit.result import BAR_MM

if TYPE_CHECKING:
    from coartic.batch.spec import BatchSpec


def batch_command(
    spec: Path = typer.Argument(..., help="batch spec (TOML), e.g. fit/batch_synthetic.toml"),
    out: Path = typer.Option(..., "--out", "-o", help="output folder (new, or this batch's: finished units are kept)"),
    scheduler: Optional[str] = typer.Option(None, help="address of a running Dask scheduler, e.g. tcp://host:8786 "
                                            "(default: a local cluster of worker processes)"),
    workers: Optional[int] = typer.Option(None, min=1, max=MAX_WORKERS, help="worker processes of the local cluster "
                                          f"(default: one per core, at most one per unit; at most {MAX_WORKERS})"),
    serial: bool = typer.Option(False, "--serial", help="no Dask: every unit in this process, one after another"),
    force: bool = typer.Option(False, "--force", help="replace an output folder that holds another run's results"),
    report: bool = typer.Option(True, "--report/--no-report", help="write the figures and report.html"),
    tls_ca_file: Optional[Path] = typer.Option(None, "--tls-ca-file", help="for a tls:// scheduler: the CA certificate "
                                               "(default: the Dask configuration's distributed.comm.tls.ca-file)"),
    tls_cert: Optional[Path] = typer.Option(None, "--tls-cert", help="for a tls:// scheduler: this client's certificate "
                                            "(default: distributed.comm.tls.client.cert)"),
    tls_key: Optional[Path] = typer.Option(None, "--tls-key", help="for a tls:// scheduler: its private key, unless in "
                                           "the certificate file (default: distributed.comm.tls.client.key)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress on stderr; the RMSE table, the outcome and "
                               "errors are still printed"),
) -> None:
    """Fit every speaker/session (and all of them pooled), with \\[posteriors] sample each one's posteriors: one Dask task
    per speaker and channel; rerun the same command to continue after an interruption."""
    console = Console()
    err = Console(stderr=True)
    from coartic.errors import UsageError

    if scheduler is not None and (workers is not None or serial):
        raise UsageError("--scheduler runs on the cluster's workers: --workers and --serial do not apply")
    tls_given = [f"{name} {path}" for name, path in (("--tls-ca-file", tls_ca_file), ("--tls-cert", tls_cert),
                                                     ("--tls-key", tls_key)) if path is not None]
    if scheduler is None and tls_given:  # the local cluster takes no certificates: not a silent no-op
        raise UsageError(f"{', '.join(tls_given)}: TLS certificates are for a tls:// scheduler; give its address "
                         "with --scheduler tls://HOST:PORT, or leave them out to run on a local cluster")
    from coartic.batch.run import Tls, require_packages, run_batch
    from coartic.batch.spec import load_batch_spec

    require_packages(None, serial)
    s = load_batch_spec(spec)
    outcome = run_batch(s, out, scheduler=scheduler, workers=workers, serial=serial, force=force, report=report,
                        console=err, quiet=quiet, tls=Tls(tls_ca_file, tls_cert, tls_key))
    from coartic.batch.report import rmse_rows

    print_table(console, rmse_table(s, rmse_rows(s, out)))
    where = f"report: {out / 'report.html'}" if report else f"tables: {out / 'groups'}"
    console.print(escape(f"{len(outcome.landed)} unit(s) done now, {outcome.skipped} already done, of {outcome.total}; "
                         f"{where}"), soft_wrap=True, highlight=False)
    for label, why in outcome.failed.items():
        print_error(err, f"unit {label}: {why}")
    if outcome.interrupted:
        err.print("[yellow]interrupted: every finished unit is kept; run the same command again to continue[/]")
        raise typer.Exit(130)
    if outcome.failed:
        raise typer.Exit(1)


def rmse_table(spec: BatchSpec, rows: list[dict[str, Any]]) -> Table:
    """Groups as rows, channels as columns (rows as ``batch.report.rmse_rows`` gives them)."""
    t = Table(title=f"RMSE (mm) per group and channel — the paper's bar is {BAR_MM} mm")
    t.add_column("group")
    for ch in spec.channels:
        t.add_column(ch, justify="right")
    by = {(r["group"], r["channel"]): r["rmse_mm"] for r in rows}
    for g in [*spec.group_names, *(["pooled"] if spec.pooled else [])]:
        cells = [by.get((g, ch)) for ch in spec.channels]
        t.add_row(escape(g), *[("–" if v is None else f"[{'green' if v < BAR_MM else 'red'}]{v:.3f}[/]") for v in cells])
    return t
