"""``coartic mcmc SPEC --fit DIR --out DIR``: posteriors for the least-squares table (docs/MCMC.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.panel import Panel
from rich.table import Table

from coartic.mcmc.run import PosteriorRun, phoneme_dir, verdict_lines
from coartic.console import print_error
from coartic.outputs import OutputDir, OutputError, atomic_write_text

console = Console(stderr=True)


def find_table(fit: Path) -> Path:
    """The least-squares table: ``fit`` itself if a file, else the table JSON inside the fit directory."""
    if fit.is_file():
        return fit
    if not fit.is_dir():
        raise FileNotFoundError(f"{fit}: no such fit directory or table file")
    for name in ("table.json", "parameters.json", "fitted_table.json"):
        if (fit / name).is_file():
            return fit / name
    found = []
    for p in sorted(fit.glob("*.json")):
        try:
            if json.loads(p.read_text()).get("schema") == "coartic.table/1":
                found.append(p)
        except (OSError, ValueError, AttributeError):
            continue
    if len(found) != 1:
        what = "no" if not found else f"{len(found)} ({', '.join(p.name for p in found)})"
        raise FileNotFoundError(f"{fit}: expected one parameter table (coartic.table/1 JSON), found {what}; pass the file itself with --fit")
    return found[0]


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
    strict: bool = typer.Option(False, help="Exit with status 2 if any posterior has not converged."),
    allow_stale_fit: bool = typer.Option(False, help="Sample even if the table's recorded RMSE does not match the data loaded now."),
    quiet: bool = typer.Option(False, help="No progress bars."),
    force: bool = typer.Option(False, "--force", help="Start over in --out even if it holds another run's chains "
                               "(they are deleted); a rerun of the same spec and fit resumes without it."),
) -> None:
    """Sample the posterior of the fitted parameters with emcee, check convergence, write intervals.

    Rerun the same command after an interruption (Ctrl-C, kill) to resume where it stopped.
    """
    from coartic.mcmc import run as mcmc_run

    try:
        fit_spec, cfg = mcmc_run.read_spec(spec)
        if channels:
            cfg.channels = tuple(c.strip() for c in channels.split(",") if c.strip())
        if phonemes:
            cfg.phonemes = tuple(p.strip() for p in phonemes.split(",") if p.strip())
        if scope:
            if scope not in mcmc_run.SCOPES:
                raise mcmc_run.McmcConfigError(f"--scope {scope!r}: expected one of {', '.join(mcmc_run.SCOPES)}")
            cfg.scope = scope
        if max_steps is not None:
            cfg.settings.max_steps = max_steps
            cfg.settings.min_steps = min(cfg.settings.min_steps, max_steps)
        table_path = find_table(fit)
        with mcmc_output(spec, fit, table_path, out, force) as directory:
            outcome = run_job(fit_spec, cfg, table_path, directory, progress=not quiet, allow_stale=allow_stale_fit)
    except (ValueError, OSError) as e:
        print_error(console, e)
        raise typer.Exit(1) from None
    runs, interrupted = outcome
    console.print(_status_table(runs))
    bad = verdict_lines(runs)
    if interrupted:
        console.print(Panel(f"Interrupted; every finished step is saved in {out}.\nRun the same command again to resume.", style="yellow"))
        raise typer.Exit(130)
    if bad:
        console.print(Panel(escape("\n".join(bad)), title=f"{len(bad)} of {len(runs)} posteriors have NOT CONVERGED: their intervals are not trustworthy", style="bold red"))
        if strict:
            raise typer.Exit(2)
    else:
        console.print(f"[green]All {len(runs)} posteriors converged.[/] Table with uncertainty: {out / 'table.json'}")


def mcmc_output(spec: Path, fit: Path, table_path: Path, out: Path, force: bool = False) -> OutputDir:
    """``out`` claimed for this job, in place (its chains are resumed). Refused if it is, or is
    inside, the fit directory (a new fit replaces that directory whole, and the fit's table.json
    must not be overwritten by the table with uncertainty), if its table.json would be the table
    sampled from, or if it holds another spec's or fit's chains."""
    import os

    from coartic.outputs import read_marker

    here = Path(os.path.abspath(out))
    table_abs = Path(os.path.abspath(table_path))
    fit_dir = Path(os.path.abspath(fit)) if fit.is_dir() else table_abs.parent
    is_fit_output = fit.is_dir() or (read_marker(fit_dir) or {}).get("command") == "fit"
    if here / "table.json" == table_abs or (is_fit_output and (here == fit_dir or fit_dir in here.parents)):
        where = "the" if here == fit_dir else "inside the"
        raise OutputError(f"--out {out}: is {where} fit directory {fit_dir}; the MCMC table would overwrite the "
                          "least-squares one, and a new fit replaces that directory whole. Choose an output "
                          f"directory beside it, e.g. --out {fit_dir.with_name(fit_dir.name + '_mcmc')}")
    def legacy(d: Path) -> bool:
        # chains written before coartic_run.json: resumed as before (each posterior's chains/meta.json
        # still refuses chains of another posterior), not deleted by a --force the user had to give
        return (d / "mcmc.json").is_file() or any(d.glob("*/*/chains/meta.json"))

    return OutputDir(out, "mcmc", {"spec": str(spec.resolve()), "fit": str(table_abs.resolve())},
                     force=force, staged=False, protect=[spec, table_path], recognise=legacy)


STALE_TOLERANCE = 0.01


def check_fit_matches_data(table: Any, table_path: Path, channel: str, data: Any, packing: Any, options: Any,
                           allow_stale: bool = False, speakers: Any = None) -> None:
    """Refuse a table fitted to other data: the RMSE at its values on the data loaded now must be
    the RMSE the fit recorded (metadata.rmse), to 1 %. Otherwise the walkers would not start at the
    optimum and every per-phoneme posterior would be conditioned on values that no longer fit."""
    from coartic.mcmc.run import fixed_noise

    recorded = (table.metadata or {}).get("rmse", {}).get(channel)
    if recorded is None or allow_stale:
        return
    now = fixed_noise(data, packing, options, speakers=speakers)
    if abs(now - recorded) > STALE_TOLERANCE * recorded:
        raise ValueError(
            f"{table_path}: fitted to other data than the spec gives now: on {channel} the RMSE at the table's "
            f"values is {now:.4f} mm, the fit recorded {recorded:.4f} mm (metadata.rmse). Refit with coartic fit, "
            "or pass --allow-stale-fit to sample anyway"
        )


def run_job(fit_spec: Any, cfg: Any, table_path: Path, out: Path, progress: bool = True,
            allow_stale: bool = False) -> tuple[list[PosteriorRun], bool]:
    """Load the data and the table, sample every posterior, write table, summaries and report fragment."""
    from coartic.fit.data import load_utterances
    from coartic.mcmc import plots, summary
    from coartic.mcmc.run import channel_runs, spec_priors, spec_shrinkage, table_problem, table_speakers
    from coartic.table import ParameterTable

    table = ParameterTable.load(table_path)
    utterances = load_utterances(fit_spec)
    out.mkdir(parents=True, exist_ok=True)
    runs: list[PosteriorRun] = []
    sections: list[str] = []

    def save(r: PosteriorRun) -> None:
        # after every posterior, so an interrupted job keeps what is finished
        runs.append(r)
        if r.result.interrupted:
            return  # chains saved for resuming; no intervals from a partial chain
        summary.write_uncertainty(table, r.channel, r.summaries)
        table.metadata.setdefault("mcmc", {})
        meta = table.metadata["mcmc"]
        meta.setdefault("not_converged", [])
        if not r.result.converged and r.label not in meta["not_converged"]:
            meta["not_converged"].append(r.label)
        if r.result.converged and r.label in meta["not_converged"]:
            meta["not_converged"].remove(r.label)
        table.save(out / "table.json")
        table.save(out / "table.csv")
        verdict = r.result.report.summary() if r.result.report else "no convergence check"
        sections.append(plots.html_fragment(r.label, r.images, r.summaries, verdict.splitlines()[0], r.result.converged, out))
        body = "".join(sections)
        atomic_write_text(out / "mcmc.html", _wrap(body))
        add_to_fit_report(table_path.parent, out, runs)
        index = [
            {"label": x.label, "channel": x.channel, "phoneme": x.phoneme, "converged": x.result.converged,
             "directory": str(x.directory.relative_to(out)), "images": [str(p.relative_to(out)) for p in x.images]}
            for x in runs
        ]
        atomic_write_text(out / "mcmc.json", json.dumps(index, indent=1))

    interrupted = False
    for channel in cfg.channels or fit_spec.channels:
        data, packing, options = table_problem(fit_spec, table, table_path, channel, utterances)
        speakers = table_speakers(fit_spec, table, table_path, channel)
        check_fit_matches_data(table, table_path, channel, data, packing, options, allow_stale, speakers)
        _, interrupted = channel_runs(channel, data, packing, options, cfg, out, progress, on_done=save,
                                      spec_priors=spec_priors(fit_spec, packing, channel),
                                      spec_shrinkage=spec_shrinkage(fit_spec, table, packing, channel),
                                      speakers=speakers)
        if interrupted:
            break
    return runs, interrupted


def _wrap(body: str) -> str:
    return f'<div class="coartic-mcmc">\n<h2>Posteriors (emcee)</h2>\n{body}</div>\n'


BEGIN, END = "<!-- coartic-mcmc begin -->", "<!-- coartic-mcmc end -->"


def add_to_fit_report(fit_dir: Path, out: Path, runs: list[PosteriorRun]) -> Path:
    """Put the posteriors into the least-squares report: ``report_mcmc.html`` in the fit directory
    (the report includes every ``report_*.html`` when it is written) and, if ``report.html`` is
    already there, the same block inserted (or replaced) before its ``</body>``."""
    import os

    from coartic.mcmc import plots

    sections = []
    for r in runs:
        verdict = r.result.report.summary().splitlines()[0] if r.result.report else "no convergence check"
        section = plots.html_fragment(r.label, r.images, r.summaries, verdict, r.result.converged, out)
        # image paths as seen from the fit directory
        for p in r.images:
            rel_out = str(p.relative_to(out))
            section = section.replace(f'src="{rel_out}"', f'src="{os.path.relpath(p, fit_dir)}"')
        sections.append(section)
    block = f"{BEGIN}\n{_wrap(''.join(sections))}{END}\n"
    frag = fit_dir / "report_mcmc.html"
    atomic_write_text(frag, block)
    report = fit_dir / "report.html"
    if report.is_file():
        text = report.read_text(encoding="utf-8")
        if BEGIN in text and END in text:
            text = text[: text.index(BEGIN)] + block + text[text.index(END) + len(END) + 1 :]
        elif "</body>" in text:
            text = text.replace("</body>", block + "</body>", 1)
        atomic_write_text(report, text)
    return frag


__all__ = ["mcmc_command", "find_table", "run_job", "add_to_fit_report", "phoneme_dir"]
