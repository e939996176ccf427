"""`coartic corpus synth OUT`: write the synthetic ELITE-style session of corpus-synthetic/.

The generator is not part of the installed package: it lives in the source checkout
(``corpus-synthetic/generate.py``, beside its ground-truth table and settings), which the editable
install points at. This module finds it there and runs it.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Annotated, Optional

import typer
from rich.console import Console
from coartic.console import handled
from coartic.errors import CoarticError
from coartic.outputs import OutputDir

app = typer.Typer(help="The synthetic ELITE-style session (corpus-synthetic/).", no_args_is_help=True)

GENERATOR_MODULE = "coartic_corpus_synthetic_generate"


class GeneratorNotFound(CoarticError, RuntimeError):
    """corpus-synthetic/ is not beside the package (a non-editable install)."""


def corpus_dir() -> Path:
    """The corpus-synthetic/ directory of the source checkout this package runs from."""
    here = Path(__file__).resolve()
    # python/coartic/synthetic_cli.py -> the repository root is two levels above the package.
    root = here.parents[2]
    path = root / "corpus-synthetic"
    if not (path / "generate.py").is_file():
        raise GeneratorNotFound(
            f"the synthetic-session generator was not found at {path / 'generate.py'}: it lives in the "
            f"coartic source checkout (corpus-synthetic/), and this coartic ({here.parent}) is not an "
            f"editable install of one. Clone the repository and run `pip install -e .` there."
        )
    return path


def load_generator() -> ModuleType:
    """Import corpus-synthetic/generate.py (once) and return it as a module."""
    if GENERATOR_MODULE in sys.modules:
        return sys.modules[GENERATOR_MODULE]
    path = corpus_dir() / "generate.py"
    spec = importlib.util.spec_from_file_location(GENERATOR_MODULE, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[GENERATOR_MODULE] = module  # dataclasses resolve their module through sys.modules
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[GENERATOR_MODULE]
        raise
    return module


@app.command("synth")
def synth(
    out: Annotated[Path, typer.Argument(help="Output directory (new, empty, or this same session generated earlier).")],
    seed: Annotated[Optional[int], typer.Option(help="Random seed (default: the one in session.toml).")] = None,
    quick: Annotated[bool, typer.Option("--quick", help="Only the first 2 repetitions (for tests).")] = False,
    flavour: Annotated[
        str,
        typer.Option(help="model: the channels are the model's (ground truth known); gestures: critically "
                     "damped gestures towards the same targets, data the model did not make; italian: the model "
                     "with every Italian phoneme (seven vowels and /j w/ in VCV, CV and VC, ground_truth_italian.json), "
                     "each trial also as an EMA file with the tongue (ema/); emotive: /a i u/ with /p b m f v t/ said "
                     "neutrally and with Ekman's six emotions, each moving the lip targets "
                     "(corpus-synthetic/emotions.toml; 'emotion' and 'intensity' manifest columns)."),
    ] = "model",
    speakers: Annotated[
        int,
        typer.Option(min=1, help="Number of speakers: more than 1 writes one session per speaker into OUT/s01, "
                     "OUT/s02... (speakers differ in target scale and speaking rate, corpus-synthetic/speakers.toml) "
                     "and OUT/manifest.csv with a 'speaker' column over all of them."),
    ] = 1,
    force: Annotated[bool, typer.Option("--force", help="Replace OUT even if it holds another run's output.")] = False,
    intensities: Annotated[
        str,
        typer.Option(help="emotive: comma-separated intensities every emotion is said at (e.g. 0.5,1), its "
                     "deviations scaled by each (default: emotions.toml's intensity, 1)."),
    ] = "",
    emotion_dynamics: Annotated[
        bool,
        typer.Option("--emotion-dynamics", help="emotive: also plant each emotion's own rates "
                     "(emotions.toml \\[dynamics]; by default every emotion keeps the neutral dynamics)."),
    ] = False,
) -> None:
    """Generate the session: C3D + CSV markers, TextGrid + .lab labels, manifest, ground truth."""
    console = Console(stderr=True)
    gen = load_generator()
    # the session is staged and swapped in whole (docs/OUTPUTS.md): an interrupted run leaves
    # OUT as it was, and a session of other settings is never mixed with (or replaced by) this one
    identity: dict[str, object] = {"seed": gen.load_settings()["seed"] if seed is None else seed,
                                   "flavour": flavour, "quick": quick, "speakers": speakers}
    levels = None
    if intensities:
        try:
            levels = [float(v) for v in intensities.split(",") if v.strip()]
        except ValueError:
            raise typer.BadParameter(f"{intensities!r}: expected numbers separated by commas",
                                     param_hint="--intensities") from None
        identity["intensities"] = levels
    if emotion_dynamics:
        identity["emotion_dynamics"] = True
    if (levels is not None or emotion_dynamics) and flavour != "emotive":
        raise typer.BadParameter("only with --flavour emotive", param_hint="--intensities/--emotion-dynamics")
    output = OutputDir(out, "corpus synth", identity, force=force, recognise=_earlier_session)
    with output as staging:
        try:
            gen.generate(staging, seed=seed, quick=quick, progress=True, flavour=flavour, speakers=speakers,
                         intensities=levels, emotion_dynamics=emotion_dynamics)
        except KeyboardInterrupt:
            output.abandon()  # half a session is worth nothing: generation takes seconds
            raise
    manifest = out / "manifest.csv"
    n = sum(1 for _ in open(manifest, encoding="utf-8")) - 1
    who = f" of {speakers} speakers" if speakers > 1 else ""
    console.print(f"wrote {n} trials{who} to {out} (manifest: {manifest})")


def _earlier_session(out: Path) -> bool:
    """A session generated before output directories were marked: the generator's own files."""
    return (out / "manifest.csv").is_file() and ((out / "ground_truth.json").is_file()
                                                  or (out / "speakers.json").is_file())


def run() -> None:
    """Entry point of ``python corpus-synthetic/generate.py OUT [--seed N] [--quick]``."""
    typer.run(handled(synth))
