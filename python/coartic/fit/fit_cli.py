"""``coartic fit SPEC --out DIR``: fit, print the RMSE table, write the table, CSVs and the HTML report."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.fit.result import BAR_MM, FitResult
from coartic.fit.spec import ENGINES, SpecError, load_spec
from coartic.console import print_error
from coartic.table import ALL_CHANNELS


def rmse_table(result: FitResult, title: str = "RMSE (mm)") -> Table:
    """Channels as rows; overall, worst vowel context, worst consonant, worst repetition, worst rate."""
    t = Table(title=f"{title} — the paper's bar is {BAR_MM} mm")
    # only the groupings the corpus has (a manifest without 'rate' has no worst rate)
    groups = [g for g in ("vowel", "consonant", "repetition", "rate") if result.worst(g)]
    for col in ("channel", "all", *(f"worst {g}" for g in groups), "status"):
        t.add_column(col, justify="left" if col in ("channel", "status") else "right")
    worst = {g: result.worst(g) for g in groups}

    def cell(v: float, label: str = "") -> str:
        colour = "green" if v < BAR_MM else "red"
        return f"[{colour}]{v:.3f}[/{colour}]" + (f" ({label})" if label else "")

    for ch, fit in result.channels.items():
        row = [ch, cell(fit.rmse)]
        for g in groups:
            w = worst[g].get(ch)
            row.append(cell(w[1], w[0]) if w else "–")
        row.append(fit.status)
        t.add_row(*row)
    return t


def fit_command(
    spec: Path = typer.Argument(..., help="fit spec (TOML), e.g. fit/synthetic.toml"),
    out: Path = typer.Option(Path("results/fit"), "--out", "-o", help="output directory"),
    engine: Optional[str] = typer.Option(None, help=f"override the spec's engine ({', '.join(ENGINES)})"),
    channels: Optional[str] = typer.Option(None, help="comma-separated channels (default: the spec's)"),
    no_staging: bool = typer.Option(False, "--no-staging", help="one joint fit instead of stages"),
    validate: bool = typer.Option(False, "--validate", help="also fit on repetitions 1-4 / the normal rate "
                                  "and report RMSE on the held-out repetition / the fast rate"),
    report: bool = typer.Option(True, "--report/--no-report", help="write the HTML report with plots"),
) -> None:
    """Fit the coarticulation model to a corpus by least squares (MODEL.md §5)."""
    console = Console()
    try:
        s = load_spec(spec)
        changes: dict[str, object] = {}
        if engine is not None:
            if engine not in ENGINES:
                raise SpecError(f"--engine {engine!r}: unknown engine ({', '.join(ENGINES)})")
            changes["engine"] = engine
            if engine != s.engine:
                changes["engine_options"] = {}
        if channels is not None:
            chs = tuple(c.strip() for c in channels.split(",") if c.strip())
            # any channel the data can give, LA like the others (the spec's list is the default)
            bad = [c for c in chs if c not in ALL_CHANNELS]
            if bad or not chs:
                raise SpecError(f"--channels: {bad or channels!r}: not channels; known: {', '.join(ALL_CHANNELS)}")
            changes["channels"] = chs
        if no_staging:
            changes["staging"] = False
        s = s.with_options(**changes)
        from coartic.fit.runner import run

        result = run(s, out)
    except (ValueError, OSError) as e:  # SpecError, DataError, ModelInputError: messages name the culprit
        print_error(console, e)
        raise typer.Exit(2) from None
    if not result.channels:
        console.print("[yellow]nothing was fitted[/yellow]" + (" (interrupted)" if result.interrupted else ""))
        raise typer.Exit(130 if result.interrupted else 1)
    console.print(rmse_table(result))
    for ch, fit in result.channels.items():
        st = fit.stats
        if st and st.at_bound:
            console.print(f"[yellow]{ch}: {len(st.at_bound)} parameter(s) at a bound[/yellow] (see fit_report.txt)")
        if st and st.unidentified:
            console.print(f"[yellow]{ch}: {len(st.unidentified)} parameter(s) not identified[/yellow] "
                          "(see fit_report.txt)")
    if validate:
        from coartic.fit.validate import validate_all

        try:
            val = validate_all(s, out / "validation", console=console)
        except KeyboardInterrupt:
            console.print("[yellow]validation interrupted[/yellow]")
            val = None
        except ValueError as e:  # e.g. no repetition or rate to hold out: said, not raised
            console.print(f"[yellow]no validation:[/yellow] {escape(str(e))}", soft_wrap=True)
            val = None
        if val is not None:
            from coartic.fit.validate import validation_table

            console.print(validation_table(val))
    if report:
        from coartic.report.html import write_report

        html = write_report(result, out, console=console)
        console.print(f"report: {html}")
    console.print(f"table: {out / 'table.json'} (and table.csv); RMSE: {out / 'rmse.csv'}; "
                  f"fit report: {out / 'fit_report.txt'}")
    if result.interrupted:
        console.print("[yellow]interrupted: the partial result above was written[/yellow]")
        raise typer.Exit(130)
