"""`coartic --help` and `--version` start without the heavy libraries; sub-commands load on use.

Not a timing test (bench/startup.py measures the time): what is imported is checked in a fresh
interpreter, where nothing else has loaded SciPy or matplotlib before.
"""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from coartic.cli import COMMANDS, app, load_command

HEAVY = ("scipy", "matplotlib", "emcee", "arviz", "dask", "distributed", "casadi", "nlopt", "ezc3d",
         "coartic._core", "pydantic")  # pydantic: the fit spec's schema, for the commands that read a spec
PYTHON_DIR = str(Path(__file__).resolve().parents[2] / "python")

_PROBE = """
import json, sys
from coartic.cli import app
try:
    app(sys.argv[1:], standalone_mode=False)
except BaseException:  # --help and --version exit; no arguments is help, an error outside standalone mode
    pass
heavy = sorted({m for m in sys.modules if m.split('.')[0] in HEAVY or m in HEAVY})
print(json.dumps(heavy))
"""


def _imported_by(args: list[str]) -> list[str]:
    env = {**os.environ, "PYTHONPATH": PYTHON_DIR, "COLUMNS": "100"}
    code = f"HEAVY = {HEAVY!r}\n{_PROBE}"
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    heavy: list[str] = json.loads(proc.stdout.strip().splitlines()[-1])
    return heavy


@pytest.mark.parametrize("args", [["--help"], ["--version"], []])
def test_top_level_imports_no_heavy_library(args: list[str]) -> None:
    assert _imported_by(args) == []


def test_the_probe_sees_heavy_imports() -> None:
    # the same probe on a command that does use SciPy (fit imports the least-squares engines)
    assert "scipy" in _imported_by(["fit", "--help"])


GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"


@pytest.mark.festival
@pytest.mark.parametrize("preview", ["gif", "none"])
def test_speak_runs_without_scipy(tmp_path: Path, preview: str) -> None:
    # the runtime path (Festival, the model, the FAP file, the pictures) evaluates the model only:
    # SciPy, which fitting needs for the Jacobian (coartic.jacobian), is not loaded
    out = tmp_path / "o"
    heavy = _imported_by(["speak", "Il babbo mangia la pappa.", "--table", str(GROUND_TRUTH), "--out", str(out),
                          "--preview", preview])
    assert (out / "channels.csv").exists() and (out / "segments.tsv").exists()  # it did speak
    assert not [m for m in heavy if m.split(".")[0] == "scipy"], heavy
    assert "coartic._core" in heavy  # the model did run
    # nor matplotlib: the pictures are drawn with Pillow (coartic.runtime.raster)
    assert "matplotlib" not in heavy and (out / "channels.png").exists() == (preview != "none")


def test_version() -> None:
    from coartic import __version__

    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"coartic {__version__}"


def test_help_lists_every_command_with_its_own_first_paragraph() -> None:
    result = CliRunner().invoke(app, ["--help"], env={"COLUMNS": "300"})
    assert result.exit_code == 0
    for name, (_, _, listed) in COMMANDS.items():
        cmd = load_command(name)
        first = " ".join(inspect.cleandoc(cmd.help or "").split("\n\n")[0].split())
        assert listed == first, name
        assert name in result.output


def test_unknown_command_is_refused() -> None:
    result = CliRunner().invoke(app, ["spake"])
    assert result.exit_code != 0
    assert "spake" in result.output


def test_the_program_tunes_the_collector_for_a_short_process() -> None:
    # the console script (pyproject) and `python -m coartic.cli` run main(): a larger young generation
    # and gc.freeze as the last exit handler (bench/startup.py measures what they save)
    import tomllib

    from coartic.cli import YOUNG_GENERATION

    scripts = tomllib.loads((Path(PYTHON_DIR).parent / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["coartic"] == "coartic.cli:main"
    code = ("import atexit, gc, sys\nfrom coartic.cli import main\nsys.argv = ['coartic', '--version']\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\nprint(gc.get_threshold()[0], gc.get_freeze_count())\n"
            "atexit._run_exitfuncs()\nprint(gc.get_freeze_count() > 0)")
    env = {**os.environ, "PYTHONPATH": PYTHON_DIR}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.split("\n")
    assert lines[0] == f"coartic {__import__('coartic').__version__}"
    assert lines[1] == f"{YOUNG_GENERATION} 0" and lines[2] == "True"
