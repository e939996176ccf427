"""`coartic perceive prepare | serve | simulate | export | analyse`: thin shells over coartic.perceive."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.markup import escape

from coartic.console import LineProgress

app = typer.Typer(help="Perceptual tests of the animation: prepare a study, serve it to participants' browsers, "
                  "export and analyse the answers (docs/PERCEIVE.md).", no_args_is_help=True)
_err = Console(stderr=True)
_out = Console()

StudyDir = Annotated[Path, typer.Argument(help="The prepared study's directory (coartic perceive prepare --out).")]
DbOpt = Annotated[str | None, typer.Option("--db", help="Results database URL: sqlite:///PATH or "
                                           "postgresql://USER@HOST/DB. Default: sqlite:///STUDY_DIR/results.sqlite.")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Replace an output that another run wrote.")]


def _fail(err: BaseException) -> NoReturn:
    raise err  # reported by the one handler of every command (coartic.console.handled): exit status 2


@app.command("prepare")
def prepare_command(
    spec: Annotated[Path, typer.Argument(help="The study spec (TOML; docs/PERCEIVE.md).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The study's directory (created).")],
    force: ForceOpt = False,
) -> None:
    """Render a study's stimuli (coartic's face with Festival's voice, noise at the spec's SNRs) into OUT."""
    from coartic.errors import CoarticError
    from coartic.outputs import OutputDir, OutputError
    from coartic.perceive.spec import read_study
    from coartic.perceive.stimuli import prepare_stimuli

    try:
        study = read_study(spec)
        if (out / "results.sqlite").exists():
            raise OutputError(f"{out} holds a results database (results.sqlite): preparing the study again "
                                  "would delete the answers; move it away or choose another --out")
        with OutputDir(out, "perceive prepare", {"spec": spec.resolve()}, force=force, protect=[spec]) as staging, \
                LineProgress(console=_err) as progress:
            manifest = prepare_stimuli(study, staging, progress)
    except (CoarticError, OSError) as err:
        _fail(err)
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
    from coartic.errors import CoarticError
    from coartic.perceive.server import serve

    def ready(url: str) -> None:
        print(f"serving {study} at {url} (Ctrl-C to stop)", flush=True)

    try:
        serve(study, db, host=host, port=port, ready=ready)
    except KeyboardInterrupt:
        _err.print("stopped: every acknowledged answer is in the database")
    except (CoarticError, OSError) as err:
        _fail(err)
    sys.stdout.flush()
