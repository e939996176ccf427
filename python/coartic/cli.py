"""The `coartic` command. Each sub-command lives beside the code it drives and is registered here.

Sub-commands are loaded when they run (or when their own --help is asked for), not when `coartic`
starts: `coartic --help` and `coartic --version` import none of SciPy, matplotlib, the MCMC stack,
Dask, CasADi, nlopt or ezc3d, which the commands that use them import themselves
(tests/python/test_cli_startup.py; measured by bench/startup.py). The listing shown by
`coartic --help` comes from `COMMANDS` below, checked equal to each command's own first help line.
"""

from __future__ import annotations

import atexit
import gc
import importlib
from typing import Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from coartic._version import __version__
from coartic.console import handled, show_data_warnings

YOUNG_GENERATION = 10_000  # objects between two collections of the youngest generation (main)

# name -> (module, attribute, the help's first paragraph, shown by `coartic --help`). The attribute is a command
# function or a typer sub-app (`corpus`).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "inspect": ("coartic.io.inspect_cli", "inspect_command",
                "Summarise a recording: markers, rate, frames, gaps per marker, labels, channels."),
    "fit": ("coartic.jobs.fit_cli", "fit_command",
            "Fit the coarticulation model to a corpus by least squares (MODEL.md §5)."),
    "score": ("coartic.evaluation.score_cli", "score_command",
              "Predict recordings the fit did not see and report the RMSE (also after removing a per-utterance "
              "offset, and after calibrating the speaker's offset and scale on these recordings)."),
    "compare": ("coartic.jobs.compare_cli", "compare_command",
                "Fit every spec on its data and compare: free parameters, RMSE, held-out RMSE, AIC, BIC."),
    "mcmc": ("coartic.mcmc.mcmc_cli", "mcmc_command",
             "Sample the posterior of the fitted parameters with emcee, check convergence, write intervals."),
    "animate": ("coartic.runtime.runtime_cli", "animate_command",
                "Animate a label file, or a recording and its transcript: channel trajectories (CSV), an MPEG-4 "
                "FAP file and a preview."),
    "align": ("coartic.align.align_cli", "align_command",
              "Align a recording to its transcript: NAME.TextGrid (tiers words, phones and the model's phonemes, "
              "which `coartic animate` reads) and NAME.align.txt (method, confidence, warnings)."),
    "speak": ("coartic.runtime.runtime_cli", "speak_command",
              "Say Italian (or English, --lang en) text with Festival: WAV, channel trajectories, FAP file and preview, all as long as "
              "the WAV."),
    "demo": ("coartic.demo", "demo_command",
             "Plot the model on /a p a/, /a f a/, /a t a/ at a normal and a 3x faster rate (illustrative table)."),
    "view": ("coartic.face.view_cli", "view_command",
             "Write OUT_DIR/view.html: the face (glTF) playing with its WAV in sync, the channels and a cursor."),
    "batch": ("coartic.batch.cli", "batch_command",
              "Fit every speaker/session (and all of them pooled), with \\[posteriors] sample each one's posteriors: "
              "one Dask task per speaker and channel; rerun the same command to continue after an interruption."),
    "corpus": ("coartic.synthetic_cli", "app", "The synthetic ELITE-style session (corpus-synthetic/)."),
    "perceive": ("coartic.perceive.cli", "app", "Perceptual tests of the animation: prepare a study, serve it to "
                 "participants' browsers, export and analyse the answers (docs/PERCEIVE.md)."),
}


def load_command(name: str) -> Any:
    """The (click) command `name`, its module imported now, its errors reported by the one handler
    of every command (`coartic.console.handled`: exception -> exit status -> message)."""
    module, attr, _ = COMMANDS[name]
    obj: Any = getattr(importlib.import_module(module), attr)
    if isinstance(obj, typer.Typer):
        for info in obj.registered_commands:
            info.callback = handled(info.callback) if info.callback is not None else None
        cmd: Any = typer.main.get_group(obj)
    else:
        single = typer.Typer(add_completion=False)
        single.command(name)(handled(obj))
        cmd = typer.main.get_command(single)
    cmd.name = name
    return cmd


class LazyGroup(TyperGroup):
    """A typer group whose sub-commands are imported on first use. While the group's own help is
    formatted, each sub-command is a placeholder carrying the one-line help of `COMMANDS`."""

    _listing = False

    # (typer's click types are its private vendored copy: the overrides take them as Any)
    def list_commands(self, ctx: Any) -> list[str]:
        return [*super().list_commands(ctx), *(n for n in COMMANDS if n not in self.commands)]

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name in self.commands or cmd_name not in COMMANDS:
            return super().get_command(ctx, cmd_name)
        if self._listing:
            return TyperCommand(cmd_name, short_help=COMMANDS[cmd_name][2])
        self.commands[cmd_name] = load_command(cmd_name)
        return self.commands[cmd_name]

    def format_help(self, ctx: Any, formatter: Any) -> None:
        self._listing = True
        try:
            super().format_help(ctx, formatter)
        finally:
            self._listing = False


app = typer.Typer(
    name="coartic",
    cls=LazyGroup,
    help="Fit, sample and animate the Cohen-Massaro / Cosi-Perin coarticulation model.",
    no_args_is_help=True,
    add_completion=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"coartic {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", is_eager=True, callback=_version,
                                          help="Print coartic's version and exit.")] = False,
) -> None:
    """Fit, sample and animate the Cohen-Massaro / Cosi-Perin coarticulation model."""
    # data that reads but looks wrong (swapped EMA axes, metres taken for mm) is said by every command
    show_data_warnings()


def main() -> None:
    """The `coartic` program (its console script and `python -m coartic.cli`): the app, in a process
    that ends with its command, with two settings of Python's cyclic garbage collector made for such a
    process. The young generation holds 10 000 objects before a collection instead of 700: importing
    NumPy, typer's pydantic and matplotlib makes hundreds of thousands of objects, each 700 of which
    set off a collection. And the objects alive at exit are frozen (`gc.freeze`, after every other
    exit handler, since this one is registered first), so that the interpreter's last collection does
    not walk all that matplotlib and NumPy made (0.15 s of CPU after `speak`'s pictures). CPython
    does not promise finalizers at exit anyway, and every coartic output is written, closed and
    renamed before its command returns. Measured by bench/startup.py and bench/speak_phases.py."""
    gc.set_threshold(YOUNG_GENERATION, *gc.get_threshold()[1:])
    atexit.register(gc.freeze)
    app()


if __name__ == "__main__":
    main()
