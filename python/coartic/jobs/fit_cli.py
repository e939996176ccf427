"""``coartic fit SPEC --out DIR``: fit, print the RMSE table, write the table, CSVs and the HTML report."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.evaluation.heldout import flags, held_out
from coartic.estimation.bounds import summary_counts
from coartic.fit.result import BAR_MM, UNIDENTIFIED_ADVICE, FitResult
from coartic.errors import SpecError
from coartic.fit.spec import ENGINES, MAX_STARTS, VALIDATE_GROUPS, FitSpec, load_spec
from coartic.fit.staged import UNCONFIRMED_STATUSES
from coartic.console import EXIT_UNCONFIRMED, print_table
from coartic.table import ALL_CHANNELS
from coartic.outputs import OutputDir


def rmse_table(result: FitResult, title: str = "RMSE (mm)") -> Table:
    """Channels as rows; overall, speech alone (where the data hold pauses), worst vowel context,
    worst consonant, worst repetition, worst rate."""
    t = Table(title=f"{title} — the paper's bar is {BAR_MM} mm")
    # only the groupings the corpus has (a manifest without 'rate' has no worst rate)
    groups = [g for g in ("vowel", "consonant", "repetition", "rate") if result.worst(g)]
    speech = result.speech_rmse()
    for col in ("channel", "all", *(["speech"] if speech else []), *(f"worst {g}" for g in groups), "status"):
        t.add_column(col, justify="left" if col in ("channel", "status") else "right")
    worst = {g: result.worst(g) for g in groups}

    def cell(v: float, label: str = "") -> str:
        colour = "green" if v < BAR_MM else "red"
        return f"[{colour}]{v:.3f}[/{colour}]" + (f" ({label})" if label else "")

    for ch, fit in result.channels.items():
        row = [ch, cell(fit.rmse)] + ([cell(speech[ch]) if ch in speech else "–"] if speech else [])
        for g in groups:
            w = worst[g].get(ch)
            row.append(cell(w[1], w[0]) if w else "–")
        colour = "green" if fit.status == "converged" else "red" if fit.status in UNCONFIRMED_STATUSES else "yellow"
        row.append(f"[{colour}]{escape(fit.status)}[/{colour}]" + (" (polished by scipy)" if fit.polished else ""))
        t.add_row(*row)
    return t


def status_lines(result: FitResult) -> list[str]:
    """Per channel (rich markup, printed soft-wrapped: never cut): the multi-start's optima, and
    every status other than "converged" with the reason, the exit status it gives, and what to do."""
    lines = []
    for ch, fit in result.channels.items():
        if fit.multistart is not None:
            colour = "yellow" if fit.multistart.best_found_once else "green"
            lines.append(f"[{colour}]{escape(ch)}[/{colour}]: {escape(fit.multistart_line())}")
        for line in fit.polished:  # another local method finished the engine's fit: say so
            lines.append(f"[yellow]{escape(ch)}: polished[/yellow]: {escape(line)}")
        if fit.status != "converged":
            colour = "red" if fit.status in UNCONFIRMED_STATUSES else "yellow"
            lines.append(f"[{colour}]{escape(ch)}: {escape(fit.status)}[/{colour}]: {escape(fit.message)}"
                         + (f" ({escape(STATUS_ADVICE[fit.status])})" if fit.status in STATUS_ADVICE else ""))
    return lines


STATUS_ADVICE = {
    "max-evaluations": "the fit stopped at its limit: raise [engine.options] max_nfev (scipy), local_maxeval "
                       "(nlopt) or max_iter (casadi); exit status 3",
    "stage-failed": "a stage failed and the next one went on from its best point: try another engine or more "
                    "[fit] starts; exit status 3",
    "best-found-once": "no other start reached a fit as good (within the noise): raise [fit] starts or keep, "
                       "or fix or tie what the data leave free (fit_report.txt); exit status 3",
}

def fit_command(
    spec: Path = typer.Argument(..., help="fit spec (TOML), e.g. fit/synthetic.toml"),
    out: Path = typer.Option(Path("results/fit"), "--out", "-o", help="output directory"),
    engine: Optional[str] = typer.Option(None, help=f"override the spec's engine ({', '.join(ENGINES)})"),
    channels: Optional[str] = typer.Option(None, help="comma-separated channels (default: the spec's)"),
    no_staging: bool = typer.Option(False, "--no-staging", help="one joint fit instead of stages"),
    validate: bool = typer.Option(False, "--validate", help="also fit on part of the data and report RMSE on "
                                  "the rest: k-fold by \\[validate] group (utterance, sentence, rate, speaker, "
                                  "repetition), else the held-out repetition and the fast rate"),
    validate_by: Optional[str] = typer.Option(None, "--validate-by", help="validate (implies --validate) by this "
                                              "split instead of the spec's \\[validate] group: time (each utterance "
                                              "cut at its middle segment, one half fitted, the other held out, both "
                                              "ways), utterance, sentence, rate, speaker or repetition"),
    report: bool = typer.Option(True, "--report/--no-report", help="write the HTML report with plots"),
    choose: Optional[str] = typer.Option(None, "--choose", help="KEY=V1,V2,...: choose a setting by k-fold "
                                         "cross-validation on the training data, then fit with it (e.g. "
                                         "shrink.sd=0.03,0.1,0.3,1; replaces the spec's \\[choose] grid; "
                                         "docs/FITTING.md)"),
    starts: Optional[int] = typer.Option(None, "--starts", min=1, max=MAX_STARTS, help="multi-start: local fits from this many "
                                         "quasi-random starts (default the spec's \\[fit] starts, 32; 1: one fit from "
                                         "\\[parameters.start])"),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="seed of the starts (default \\[fit] seed, 0)"),
    force: bool = typer.Option(False, "--force", help="replace --out even if it holds another run's output "
                               "(a rerun of the same spec and channels replaces its own output without it)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress (bars in a terminal, lines elsewhere, on "
                               "stderr); the result tables, warnings and errors are still printed"),
) -> None:
    """Fit the coarticulation model to a corpus by least squares (MODEL.md §5).

    By default from 32 quasi-random starts (\\[fit] starts; docs/FITTING.md). The outputs are
    written beside --out and swapped in whole when the fit ends (docs/OUTPUTS.md).
    Progress goes to stderr (live in a terminal, a line per stage, channel and 15 s elsewhere).

    Exit status: 0 every channel converged; 3 written, but a channel reached its evaluation or
    iteration limit (max-evaluations), had a failed stage (stage-failed) or a best optimum that one
    start only reached (best-found-once); 2 an error (spec, data, output) or an engine that failed
    outright (nothing written); 1 nothing fitted; 130 interrupted (Ctrl-C).
    """
    console = Console()
    err = Console(stderr=True)
    try:
        s = load_spec(spec)
        changes: dict[str, object] = {}
        if engine is not None:
            if engine not in ENGINES:
                raise SpecError(f"--engine {engine!r}: unknown engine ({', '.join(ENGINES)})")
            # another engine starts from its own default options
            changes["engine"] = {"name": engine, **({} if engine == s.engine.name else {"options": {}})}
        if channels is not None:
            chs = tuple(c.strip() for c in channels.split(",") if c.strip())
            # any channel the data can give, LA like the others (the spec's list is the default)
            bad = [c for c in chs if c not in ALL_CHANNELS]
            if bad or not chs:
                raise SpecError(f"--channels: {bad or channels!r}: not channels; known: {', '.join(ALL_CHANNELS)}")
            changes["channels"] = chs
        if no_staging:
            changes["staging"] = {"enabled": False}
        if starts is not None:
            changes["starts"] = starts
            if s.fit.keep is not None and s.fit.keep > starts:
                changes["keep"] = starts
        if seed is not None:
            changes["seed"] = seed
        if validate_by is not None:
            if validate_by not in VALIDATE_GROUPS:
                raise SpecError(f"--validate-by {validate_by!r}: unknown split ({', '.join(VALIDATE_GROUPS)})")
            changes["validate"] = {"group": validate_by}
            validate = True
        s = s.with_options(**changes)
        if choose is not None:
            from coartic.fit.choose import parse_choose

            s = parse_choose(s, choose)
        output = fit_output(s, out, force)
        with output as staging:
            result = _fit_into(s, staging, console, err, validate, report, quiet)
            if not result.channels:  # nothing to show for it: the previous output stays
                output.abandon()
            elif result.interrupted:
                output.status = "interrupted"
    except KeyboardInterrupt:  # outside the fit itself (report, swap): what was written is in --out
        console.print(f"[yellow]interrupted[/yellow]; what was finished is in {escape(str(out))}", soft_wrap=True)
        raise typer.Exit(130) from None
    if not result.channels:
        console.print("[yellow]nothing was fitted[/yellow]" + (" (interrupted)" if result.interrupted else ""))
        raise typer.Exit(130 if result.interrupted else 1)
    console.print(escape(f"table: {out / 'table.json'} (and table.csv); RMSE: {out / 'rmse.csv'}; "
                         f"fit report: {out / 'fit_report.txt'}" + (f"; report: {out / 'report.html'}" if report else "")),
                  soft_wrap=True, highlight=False)
    if result.interrupted:
        console.print("[yellow]interrupted: the partial result above was written[/yellow]")
        raise typer.Exit(130)
    if any(f.status in UNCONFIRMED_STATUSES for f in result.channels.values()):
        raise typer.Exit(EXIT_UNCONFIRMED)


def warning_lines(result: FitResult) -> list[str]:
    """The console's warnings per channel (rich markup): parameters at a bound with the count of each
    category of their explanation (red when one is unexplained), and parameters not identified."""
    lines = []
    for ch, fit in result.channels.items():
        st = fit.stats
        if st and st.at_bound:
            colour = "red" if any(b.category == "unexplained" for b in st.bounds.values()) else "yellow"
            lines.append(f"[{colour}]{escape(ch)}: {len(st.at_bound)} parameter(s) at a bound[/{colour}]: "
                         f"{escape(summary_counts(st.bounds))} (why: fit_report.txt, report.html)")
        if st and st.unidentified:
            lines.append(f"[yellow]{escape(ch)}: {len(st.unidentified)} parameter(s) not identified[/yellow] "
                         "(why and what to do: fit_report.txt, summary.json)")
            why = [(nm, st.unidentified_why[nm].partition(": ")[0]) for nm in st.unidentified if nm in st.unidentified_why]
            lines += [f"    {escape(nm)}: {escape(w)}" for nm, w in why[:5]]
            if why:
                lines.append(f"    {escape(UNIDENTIFIED_ADVICE)}" + (f" ({len(why) - 5} more in fit_report.txt)"
                                                                   if len(why) > 5 else ""))
    return lines


def fit_output(spec: FitSpec, out: Path, force: bool = False) -> OutputDir:
    """The output directory of a fit: the same spec file and channels replace their own output."""
    spec_path = spec.path.resolve()

    def legacy(d: Path) -> bool:  # written before coartic_run.json: its summary names the spec
        import json

        try:
            doc = json.loads((d / "summary.json").read_text(encoding="utf-8"))
            return Path(doc["spec"]).resolve() == spec_path and sorted(doc["channels"]) == sorted(spec.channels)
        except (OSError, ValueError, KeyError, TypeError):
            return False

    c = spec.corpus_spec
    inputs = [spec.path, *(p for p in (c.manifest, spec.start_table) if p is not None), *c.files, *c.labels]
    return OutputDir(out, "fit", {"spec": str(spec_path), "channels": ",".join(spec.channels)},
                     force=force, protect=inputs, recognise=legacy)


def _fit_into(s: FitSpec, out: Path, console: Console, err: Console, validate: bool, report: bool,
              quiet: bool) -> FitResult:
    """The fit, its validation and report, written into ``out`` (the staging directory) by
    ``coartic.jobs.fit.fit_job`` (progress on ``err``); the results printed on ``console``."""
    from coartic.evaluation.choose import Choice
    from coartic.jobs.fit import fit_job

    result = fit_job(s, out, console=err, quiet=quiet, validate=validate, report=report)
    if not result.channels:
        return result
    print_table(console, rmse_table(result))
    if isinstance(result.choice, Choice):
        c = result.choice
        console.print(escape(f"{c.choose.key} chosen by cross-validation on the training data (rule {c.choose.rule}): "
                             + ", ".join(f"{ch} {v:g}" for ch, v in c.chosen.items())
                             + " (curve: choose.csv, choose.png, fit_report.txt)"), soft_wrap=True, highlight=False)
    for line in status_lines(result):
        console.print(line, soft_wrap=True, highlight=False)
    for line in warning_lines(result):
        console.print(line, soft_wrap=True)
    for note in result.notes:
        console.print(f"[yellow]note:[/yellow] {escape(note)}", soft_wrap=True)
    scores = held_out(result)
    if scores:
        from coartic.evaluation.validate import validation_table

        print_table(console, validation_table(scores), keys=2)
        for f in flags(scores):
            console.print(f"[bold red]WORSE THAN THE STEP MODEL[/bold red] {escape(f)}", soft_wrap=True, highlight=False)
    return result
