"""``coartic compare SPEC... --out DIR``: fit several specs and compare them by held-out RMSE and AIC/BIC."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.console import print_table
from coartic.fit.result import BAR_MM


def compare_command(
    specs: list[Path] = typer.Argument(..., help="fit specs (TOML) to compare, e.g. original vs modified"),
    out: Path = typer.Option(Path("results/compare"), "--out", "-o", help="output directory"),
    validate: bool = typer.Option(True, "--validate/--no-validate",
                                  help="held-out RMSE from each spec's \\[validate] splits (AIC/BIC either way)"),
    force: bool = typer.Option(False, "--force", help="replace --out even if it holds another run's output"),
    vary: Optional[str] = typer.Option(None, "--vary", help="KEY=V1,V2,...: one model per value of a setting of "
                                       "each spec (e.g. prior_noise=0.1,0.3,1 to choose a prior strength by "
                                       "held-out RMSE)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress on stderr; the comparison is still printed"),
) -> None:
    """Fit every spec on its data and compare: free parameters, RMSE, held-out RMSE, AIC, BIC.

    Exit status: 0 every fit converged; 3 written, but a fit reached its evaluation or iteration limit
    (max-evaluations), had a failed stage (stage-failed) or a best optimum that one start only
    reached (best-found-once), as `coartic fit`; 2 an error (spec, data, output); 130 interrupted.
    """
    from coartic.jobs.compare import compare
    from coartic.evaluation.compare import vary as vary_spec
    from coartic.fit.spec import FitSpec, load_spec, parse_grid
    from coartic.outputs import OutputDir

    console = Console()
    err = Console(stderr=True)
    models: list[FitSpec | Path] = list(specs)
    if vary is not None:
        key, values = parse_grid("--vary", vary)
        models = [m for s in specs for m in vary_spec(load_spec(s), key, values)]
    identity = {"specs": ",".join(str(s.resolve()) for s in specs), "validate": validate, "vary": vary or ""}
    with OutputDir(out, "compare", identity, force=force, protect=specs) as d:
        cmp = compare(models, d, validate=validate, console=err, quiet=quiet)
    print_table(console, comparison_table(cmp), keys=2)
    for n in cmp.factor_lines():
        console.print(escape(n), soft_wrap=True, highlight=False)
    for n in cmp.notes:
        console.print(f"note: {escape(n)}", soft_wrap=True, highlight=False)
    console.print(escape(f"written: {out / 'compare.html'} (table and figure), compare.csv, one fit per spec"),
                  soft_wrap=True, highlight=False)
    if any(res.interrupted for res in cmp.results):
        raise typer.Exit(130)
    from coartic.console import EXIT_UNCONFIRMED
    from coartic.jobs.fit_cli import STATUS_ADVICE
    from coartic.fit.staged import UNCONFIRMED_STATUSES

    unconfirmed = [r for r in cmp.rows if r.status in UNCONFIRMED_STATUSES]
    for r in unconfirmed:  # the comparison of a fit that did not converge is not to be trusted as it stands
        console.print(f"[bold red]{escape(r.model)} {escape(r.channel)}: {escape(r.status)}[/bold red]: "
                      f"{escape(STATUS_ADVICE.get(r.status, ''))}", soft_wrap=True, highlight=False)
    if unconfirmed:
        raise typer.Exit(EXIT_UNCONFIRMED)


def comparison_table(cmp: object) -> Table:
    from coartic.evaluation.compare import Comparison

    assert isinstance(cmp, Comparison)
    t = Table(title=f"Model comparison (RMSE in mm, bar {BAR_MM} mm; lower AIC/BIC is better)",
              caption="step model: each phoneme's training mean on the same held-out samples (as measured / no "
                      "offsets); ✗ = the table does not beat it. effective: the trace of the hat matrix. chosen (✓): "
                      "within one SE of the lowest held-out RMSE, the fewest effective parameters")
    for c in ("model", "channel", "free", "effective", "RMSE", "held-out ± SE", "held-out, no offsets", "step model",
              "AIC", "BIC", "chosen", "status"):
        t.add_column(c, justify="left" if c in ("model", "channel", "status") else "right")

    def f(v: float, fmt: str, best: bool = False) -> str:
        s = "–" if not math.isfinite(v) else format(v, fmt)
        return f"[bold green]{s}[/bold green]" if best else s

    def step(r: object) -> str:
        from coartic.evaluation.compare import Row

        assert isinstance(r, Row)
        if "step" not in r.baselines:
            return "–"
        s = f"{r.baselines['step'][0]:.3f} / {r.baselines['step'][1]:.3f}"
        return s if r.beats_step else f"{s} [bold red]✗[/bold red]"

    for r in cmp.rows:
        held = f(r.heldout_rmse, ".3f", cmp.best(r.channel, "heldout_rmse") == r.model)
        if math.isfinite(r.heldout_rmse_se):
            held += f" ± {r.heldout_rmse_se:.3f}"
        t.add_row(escape(r.model), r.channel, str(r.n_free), f(r.n_effective, ".1f"), f(r.rmse, ".3f"), held,
                  f(r.heldout_rmse_offset_removed, ".3f"), step(r), f(r.aic, ".1f"),
                  f(r.bic, ".1f", cmp.best(r.channel, "bic") == r.model),
                  "✓" if cmp.chosen(r.channel) == r.model else "", escape(r.status))
    return t
