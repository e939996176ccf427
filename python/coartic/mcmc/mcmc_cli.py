"""``coartic mcmc SPEC --fit DIR --out DIR``: posteriors for the least-squares table (docs/MCMC.md).

The job is ``coartic.mcmc.job.sample``; this module only prints what it returns."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.mcmc.run import PosteriorRun, phoneme_dir, verdict_lines
from coartic.console import EXIT_UNCONFIRMED, print_table

console = Console(stderr=True)


def _status_table(runs: list[PosteriorRun]) -> Table:
    t = Table(title="MCMC posteriors")
    for col in ("posterior", "dim", "steps", "tau", "N/tau", "max R-hat", "min ESS", "acceptance", "identified", "verdict"):
        t.add_column(col, justify="right" if col not in ("posterior", "verdict") else "left")
    for r in runs:
        rep = r.result.report
        ok = r.result.converged
        ident = sum(s.identified for s in r.summaries)
        rhat = max((x for x in rep.rhat if x == x), default=float("nan")) if rep else float("nan")
        t.add_row(
            r.label,
            str(r.posterior.dim),
            str(rep.n_steps) if rep else "0",
            f"{rep.tau_max:.0f}" if rep else "-",
            f"{rep.n_steps / max(rep.tau_max, 1e-9):.0f}" if rep else "-",
            f"{rhat:.3f}",
            f"{min(rep.ess_bulk):.0f}" if rep else "-",
            " ".join(f"{a:.2f}" for a in r.result.acceptance),
            f"{ident}/{len(r.summaries)}",
            "[green]converged" if ok else ("[yellow]interrupted" if r.result.interrupted else "[bold red]NOT CONVERGED"),
        )
    return t


def mcmc_command(
    spec: Path = typer.Argument(..., help="The fit spec (TOML) used for the least-squares fit; its \\[mcmc] section configures sampling."),
    fit: Path = typer.Option(..., "--fit", help="The least-squares output directory (or its table JSON): the walkers start at its optimum."),
    out: Path = typer.Option(..., "--out", help="Output directory: chains (resumable), plots, summaries, table with uncertainty."),
    channels: Optional[str] = typer.Option(None, help="Comma-separated channels (default: \\[mcmc] channels, else the spec's)."),
    phonemes: Optional[str] = typer.Option(None, help="Comma-separated phonemes (default: \\[mcmc] phonemes, else every non-pause phoneme)."),
    scope: Optional[str] = typer.Option(None, help="'phonemes' (one posterior per phoneme) or 'channel' (joint, slow)."),
    max_steps: Optional[int] = typer.Option(None, help="Override \\[mcmc] max_steps."),
    strict: bool = typer.Option(False, help="Exit with status 3 (written, not confirmed) if any posterior has not converged."),
    allow_stale_fit: bool = typer.Option(False, help="Sample even if the table's recorded RMSE does not match the data loaded now."),
    quiet: bool = typer.Option(False, help="No progress bars."),
    force: bool = typer.Option(False, "--force", help="Start over in --out even if it holds another run's chains "
                               "(they are deleted); a rerun of the same spec and fit resumes without it."),
) -> None:
    """Sample the posterior of the fitted parameters with emcee, check convergence, write intervals.

    Rerun the same command after an interruption (Ctrl-C, kill) to resume where it stopped.
    """
    from coartic.mcmc.job import sample

    result = sample(spec, fit, out, channels=_names(channels), phonemes=_names(phonemes), scope=scope,
                    max_steps=max_steps, progress=not quiet, allow_stale=allow_stale_fit, force=force)
    runs, interrupted = result.runs, result.interrupted
    print_table(console, _status_table(runs))
    for ch, held in {r.channel: r.held_fixed for r in runs}.items():
        if held:  # estimated by the fit, sampled by no posterior here: their intervals are not given
            console.print(escape(f"{ch}: held at the least-squares values (sampled in no posterior): {', '.join(held)}"),
                          soft_wrap=True, highlight=False)
    bad = verdict_lines(runs)
    # Verdicts as soft-wrapped lines (not a panel, whose title is cut at a narrow width).
    if interrupted:
        console.print(escape(f"Interrupted; every finished step is saved in {out}. Run the same command again to "
                             "resume."), style="yellow", soft_wrap=True, highlight=False)
        raise typer.Exit(130)
    if bad:
        console.print(f"{len(bad)} of {len(runs)} posteriors have NOT CONVERGED: their intervals are not trustworthy",
                      style="bold red", soft_wrap=True, highlight=False)
        for line in bad:
            console.print(escape(f"  {line}"), style="red", soft_wrap=True, highlight=False)
        if strict:
            raise typer.Exit(EXIT_UNCONFIRMED)
    else:
        console.print(f"[green]All {len(runs)} posteriors converged.[/] Table with uncertainty: "
                      f"{escape(str(out / 'table.json'))}", soft_wrap=True, highlight=False)


def _names(csv: str | None) -> tuple[str, ...] | None:
    return tuple(x.strip() for x in csv.split(",") if x.strip()) if csv else None


__all__ = ["mcmc_command", "phoneme_dir"]
