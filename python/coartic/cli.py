"""The `coartic` command. Each sub-command lives beside the code it drives and is registered here."""

import typer

app = typer.Typer(
    name="coartic",
    help="Fit, sample and animate the Cohen-Massaro / Cosi-Perin coarticulation model.",
    no_args_is_help=True,
    add_completion=False,
)

# --- sub-commands (one line each) ---
app.command("animate")(__import__("coartic.runtime.runtime_cli", fromlist=["_"]).animate_command)
app.command("speak")(__import__("coartic.runtime.runtime_cli", fromlist=["_"]).speak_command)
app.command("inspect")(__import__("coartic.io.inspect_cli", fromlist=["_"]).inspect_command)
app.add_typer(__import__("coartic.synthetic_cli", fromlist=["_"]).app, name="corpus")
app.command("demo")(__import__("coartic.demo", fromlist=["_"]).demo_command)
app.command("fit")(__import__("coartic.fit.fit_cli", fromlist=["_"]).fit_command)
app.command("mcmc")(__import__("coartic.mcmc.mcmc_cli", fromlist=["_"]).mcmc_command)

if __name__ == "__main__":
    app()
