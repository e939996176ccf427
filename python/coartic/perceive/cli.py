"""`coartic perceive prepare | serve | simulate | export | analyse`: thin shells over coartic.perceive.

Errors are reported by the one handler of every command (coartic.console.handled: exit status 2)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from coartic.console import LineProgress
from coartic.extras import require

if TYPE_CHECKING:
    from coartic.perceive.storage import Store

app = typer.Typer(help="Perceptual tests of the animation: prepare a study, serve it to participants' browsers, "
                  "export and analyse the answers (docs/PERCEIVE.md).", no_args_is_help=True)
_err = Console(stderr=True)
_out = Console()

StudyDir = Annotated[Path, typer.Argument(help="The prepared study's directory (coartic perceive prepare --out).")]
DbOpt = Annotated[str | None, typer.Option("--db", help="Results database URL: sqlite:///PATH or "
                                           "postgresql://USER@HOST/DB. Default: sqlite:///STUDY_DIR/results.sqlite.")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Replace an output that another run wrote.")]


@app.command("prepare")
def prepare_command(
    spec: Annotated[Path, typer.Argument(help="The study spec (TOML; docs/PERCEIVE.md).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The study's directory (created).")],
    force: ForceOpt = False,
) -> None:
    """Render a study's stimuli (coartic's face with Festival's voice, noise at the spec's SNRs) into OUT."""
    require("perceive", "coartic perceive")
    from coartic.outputs import OutputDir, OutputError
    from coartic.perceive.spec import read_study
    from coartic.perceive.stimuli import prepare_stimuli

    study = read_study(spec)
    if (out / "results.sqlite").exists():
        raise OutputError(f"{out} holds a results database (results.sqlite): preparing the study again "
                          "would delete the answers; move it away or choose another --out")
    with OutputDir(out, "perceive prepare", {"spec": spec.resolve()}, force=force, protect=[spec]) as staging, \
            LineProgress(console=_err) as progress:
        manifest = prepare_stimuli(study, staging, progress)
    _out.print(f"{len(manifest['stimuli'])} stimuli of study {escape(study.name)} ({study.design}) in "
               f"{escape(str(out))}; serve it with: coartic perceive serve {escape(str(out))}", highlight=False,
               soft_wrap=True)


@app.command("serve")
def serve_command(
    study: StudyDir,
    db: DbOpt = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on: 127.0.0.1 (this machine only) unless "
                                      "participants must reach it from elsewhere (0.0.0.0: every interface).")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="Port (0: any free one, printed).")] = 8080,
) -> None:
    """Serve a prepared study to participants' browsers (consent, trials, resumable sessions) until Ctrl-C."""
    require("perceive", "coartic perceive")
    from coartic.perceive.server import serve

    def ready(url: str) -> None:
        print(f"serving {study} at {url} (Ctrl-C to stop)", flush=True)

    try:
        serve(study, db, host=host, port=port, ready=ready)
    except KeyboardInterrupt:
        _err.print("stopped: every acknowledged answer is in the database")
    sys.stdout.flush()


def _open(study: Path, db: str | None, durable: bool = True) -> tuple[dict[str, Any], Store]:
    from coartic.perceive.server import default_db_url, load_study
    from coartic.perceive.storage import Store

    manifest, secret = load_study(study)
    return manifest, Store(db or default_db_url(study), manifest, secret, durable=durable)


@app.command("simulate")
def simulate_command(
    study: StudyDir,
    participants: Annotated[int, typer.Option("--participants", "-n", min=1, max=100000,
                                              help="How many simulated participants answer every trial.")],
    effect: Annotated[list[str] | None, typer.Option("--effect", help="CONDITION=NUMBER: the planted effect of a "
                                                     "condition (logit; rating points for MUSHRA); repeat per condition.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the simulated answers.")] = 1,
    db: DbOpt = None,
) -> None:
    """Add simulated participants' answers (planted effects) to a study's database, to check its power and analysis."""
    require("perceive", "coartic perceive")
    from coartic.perceive.simulate import Plant, parse_effects, simulate

    manifest, store = _open(study, db, durable=False)
    conditions = [str(c["name"]) for c in manifest["conditions"]]
    n = simulate(store, participants, Plant(effects=parse_effects(effect or [], conditions)), seed)
    store.close()
    _out.print(f"{participants} simulated participants, {n} answers stored (marked simulated in the export)")


@app.command("export")
def export_command(
    study: StudyDir,
    out: Annotated[Path, typer.Option("--out", "-o", help="The CSV to write.")],
    db: DbOpt = None,
    force: ForceOpt = False,
) -> None:
    """Write the answers as a tidy CSV: one row per answer (per rated face for MUSHRA)."""
    require("perceive", "coartic perceive")
    from coartic.outputs import OutputError
    from coartic.perceive.tidy import tidy_answers, write_csv

    if out.exists() and not force:
        raise OutputError(f"{out} exists: give --force to replace it")
    _, store = _open(study, db)
    frame = tidy_answers(store.manifest, store.answer_rows())
    store.close()
    write_csv(frame, out)
    _out.print(f"{len(frame)} rows, {frame['participant'].nunique()} participants: {escape(str(out))}", highlight=False)


@app.command("analyse")
def analyse_command(
    study: StudyDir,
    out: Annotated[Path, typer.Option("--out", "-o", help="The report's directory (report.html, answers.csv, "
                                      "summary.json, plots).")],
    db: DbOpt = None,
    force: ForceOpt = False,
) -> None:
    """Analyse the answers (mixed models, confusion matrices, bootstrap intervals) into an HTML report with plots."""
    require("perceive", "coartic perceive")
    from coartic.outputs import OutputDir
    from coartic.perceive.analysis import analyse
    from coartic.perceive.report import write_report
    from coartic.perceive.tidy import tidy_answers

    _, store = _open(study, db)
    tidy = tidy_answers(store.manifest, store.answer_rows())
    counts = store.counts()
    store.close()
    result = analyse(store.manifest, tidy)
    with OutputDir(out, "perceive analyse", {"study": study.resolve()}, force=force, protect=[study]) as staging:
        write_report(result, store.manifest, tidy, staging, f"coartic perceive analyse {study} --out {out}")
    _out.print(f"{result.n_participants} participants analysed ({len(result.excluded)} excluded; "
               f"{counts['completed']} of {counts['participants']} finished): {escape(str(out / 'report.html'))}",
               highlight=False)
    for e in result.effects:
        if e.name != "intercept":
            word = "credible" if e.credible else "interval includes 0"
            _out.print(f"  {escape(e.name)}: {e.estimate:+.3f} [{e.low:+.3f}, {e.high:+.3f}] ({word})", highlight=False)
    for note in result.notes:
        _err.print(f"[yellow]note:[/] {escape(note)}", highlight=False)
