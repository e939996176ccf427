"""The `coartic` command. Each sub-command lives beside the code it drives and is registered here."""

import typer

from coartic import synthetic_cli
from coartic.console import show_data_warnings
from coartic.batch.cli import batch_command
from coartic.demo import demo_command
from coartic.face.view_cli import view_command
from coartic.fit.fit_cli import fit_command
from coartic.fit.compare_cli import compare_command
from coartic.fit.score_cli import score_command
from coartic.io.inspect_cli import inspect_command
from coartic.mcmc.mcmc_cli import mcmc_command
from coartic.runtime.runtime_cli import animate_command, speak_command

app = typer.Typer(
    name="coartic",
    help="Fit, sample and animate the Cohen-Massaro / Cosi-Perin coarticulation model.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def _main() -> None:
    """Fit, sample and animate the Cohen-Massaro / Cosi-Perin coarticulation model."""
    # data that reads but looks wrong (swapped EMA axes, metres taken for mm) is said by every command
    show_data_warnings()


app.add_typer(synthetic_cli.app, name="corpus")  # coartic corpus synth OUT
app.command("inspect")(inspect_command)
app.command("fit")(fit_command)
app.command("score")(score_command)
app.command("compare")(compare_command)
app.command("mcmc")(mcmc_command)
app.command("animate")(animate_command)
app.command("speak")(speak_command)
app.command("demo")(demo_command)
app.command("view")(view_command)
app.command("batch")(batch_command)

if __name__ == "__main__":
    app()
