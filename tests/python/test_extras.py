"""Installs sized to their use (coartic/extras.py): pyproject's extras say what coartic.extras says,
and each command that needs an extra names it before doing any work.

Run in the full environment (`make test-python`), the extras' packages are blocked in the child
processes that run the commands (an import hook that finds nothing), so every message is checked
there too (make test leaves them to make test-core's run, conftest.py). Run by `make test-core` in a fresh environment holding the core wheel alone, nothing is
blocked: the packages are really absent (`test_the_extras_are_really_absent` checks that there).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import format_fixtures as ff
from coartic.extras import EXTRAS, IMPORT_NAMES, MissingExtra, missing_modules, require

ROOT = Path(__file__).resolve().parents[2]
EXTRA_MODULES = sorted({m for mods in EXTRAS.values() for m in mods})
# A fresh environment with only `pip install coartic` (make test-core) sets this.
CORE_ONLY = os.environ.get("COARTIC_CORE_ONLY") == "1"

# Prepended to the child's program: an import hook under which the extras' packages are not found.
BLOCK = f"""
import importlib.abc, sys
class _NoExtras(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {EXTRA_MODULES!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None
sys.meta_path.insert(0, _NoExtras())
"""


def run_core(args: list[str], cwd: Path, program: str | None = None) -> subprocess.CompletedProcess[str]:
    """`coartic ARGS` (or `program`) in a child process that has the core alone."""
    code = ("" if CORE_ONLY else BLOCK) + (program or "from coartic.cli import main\nmain()")
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1"}
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300, env=env)


def _requirement_name(req: str) -> str:
    """The import name a requirement brings ("dtw-python>=1.5" → "dtw")."""
    name = req.split(";")[0].split(">")[0].split("<")[0].split("=")[0].split("[")[0].strip().lower()
    return IMPORT_NAMES.get(name, name)


@pytest.mark.full_env
@pytest.mark.skipif(CORE_ONLY, reason="the checkout's pyproject.toml is checked in the full environment")
def test_pyproject_extras_match_the_table() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    optional = project["optional-dependencies"]
    core = {_requirement_name(r) for r in project["dependencies"]}
    for extra, modules in EXTRAS.items():
        names = {_requirement_name(r) for r in optional[extra]}
        # dask[distributed] brings distributed
        if any(r.startswith("dask[distributed]") for r in optional[extra]):
            names.add("distributed")
        assert set(modules) <= names, (extra, modules, names)
        assert not set(modules) & core, f"the core installs {set(modules) & core}, an extra's packages"
    assert optional["all"] == [f"coartic[{','.join(EXTRAS)}]"]


@pytest.mark.skipif(not CORE_ONLY, reason="make test-core: a fresh environment with the core wheel alone")
def test_the_extras_are_really_absent() -> None:
    import coartic

    assert missing_modules(EXTRA_MODULES) == EXTRA_MODULES
    assert "site-packages" in coartic.__file__  # the wheel, not the checkout


def test_require_names_the_extra() -> None:
    with pytest.raises(MissingExtra, match=r"^the thing needs coartic's \[engines\] extra \(no_such_module "
                                           r"is not installed\): pip install 'coartic\[engines\]'$") as e:
        require("engines", "the thing", ("no_such_module",))
    assert e.value.extra == "engines" and isinstance(e.value, ImportError)
    require("engines", "the thing", ("json",))  # installed: nothing said


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A spec over one EMA file and its fit, made by the core alone (SciPy, report, table)."""
    d = tmp_path_factory.mktemp("core")
    m = ff.motion(200.0)
    data = ff.write_lab_csv(d / "utt.csv", m)
    labels = ff.write_mfa_textgrid(d / "utt.TextGrid", m)
    spec = d / "spec.toml"
    spec.write_text("[corpus]\n"
                    f"files = {json.dumps([str(data)])}\nlabels = {json.dumps([str(labels)])}\n"
                    'label_map = "english_arpabet"\n'
                    '[model]\nchannels = ["LA"]\nreference_phoneme = "a"\n'
                    'dominance = "centre"\nhandover = false\n'
                    '[parameters]\nfree = ["target"]\ntarget_prior = "none"\n[fit]\nstarts = 1\n')
    r = run_core(["fit", str(spec), "--out", str(d / "fit")], d)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (d / "fit" / "table.json").is_file() and (d / "fit" / "report.html").is_file()
    return spec, d / "fit"


def test_the_core_fits_and_scores(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    spec, fit = fitted
    data = spec.parent / "utt.csv"
    r = run_core(["score", str(fit / "table.json"), str(data), "--labels", str(spec.parent / "utt.TextGrid"),
                  "--label-map", "english_arpabet"], tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "LA" in r.stdout


REFUSED = {
    "mcmc": ["mcmc", "{spec}", "--fit", "{fit}", "--out", "{tmp}/mcmc"],
    "nlopt": ["fit", "{spec}", "--out", "{tmp}/nl", "--engine", "nlopt"],
    "casadi": ["fit", "{spec}", "--out", "{tmp}/ca", "--engine", "casadi"],
    "perceive": ["perceive", "analyse", "{tmp}", "--out", "{tmp}/ca"],
    "batch": ["batch", str(ROOT / "fit" / "batch_synthetic.toml"), "--out", "{tmp}/b"],
}

# Runs each command of argv lists (JSON, the first argument) in turn as `coartic` does (coartic.cli.main),
# its exit code and output kept apart (click, typer and rich write to sys.stdout and sys.stderr as they
# find them); an exception other than the exit is kept as its traceback.
EACH_COMMAND = """
import contextlib, io, json, sys, traceback
from coartic.cli import main
said = []
for argv in json.loads(sys.argv[1]):
    out, code = io.StringIO(), None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        sys.argv = ["coartic", *argv]
        try:
            main()
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else 1
        except BaseException:
            traceback.print_exc()
            code = 1
    said.append([code, out.getvalue()])
print(json.dumps(said))
"""


@pytest.fixture(scope="module")
def refusals(fitted: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[int, str, Path]]:
    """{name: (exit code, output, its directory)} of each command of REFUSED, in one child process
    with the core alone: a child per command cost a second of CPU each, most of it the interpreter's
    start and coartic.cli's imports, the same for all of them (every command refuses before its work,
    and an extra blocked for the first is blocked for the next)."""
    spec, fit = fitted
    dirs = {name: tmp_path_factory.mktemp(name) for name in REFUSED}
    argvs = [[a.format(spec=spec, fit=fit, tmp=dirs[name]) for a in args] for name, args in REFUSED.items()]
    r = run_core([json.dumps(argvs)], spec.parent, EACH_COMMAND)
    assert r.returncode == 0, r.stdout + r.stderr
    said = json.loads(r.stdout.splitlines()[-1])
    return {name: (code, out, dirs[name]) for name, (code, out) in zip(REFUSED, said)}


@pytest.mark.parametrize(("name", "extra", "missing"), [
    ("mcmc", "mcmc", "emcee, corner, arviz, xarray, pandas are"),
    ("nlopt", "engines", "nlopt is"),
    ("casadi", "engines", "casadi is"),
    ("perceive", "perceive", "flask, waitress, sqlalchemy, psycopg, statsmodels, pandas are"),
])
def test_each_command_names_its_extra(refusals: dict[str, tuple[int, str, Path]], name: str, extra: str,
                                      missing: str) -> None:
    code, out, where = refusals[name]
    assert code != 0 and "Traceback" not in out, out
    assert f"needs coartic's [{extra}] extra ({missing} not installed): pip install 'coartic[{extra}]'" in out, out
    assert not any(p.name in ("mcmc", "nl", "ca") for p in where.iterdir())  # refused before any output


def test_batch_on_a_cluster_names_its_extra(refusals: dict[str, tuple[int, str, Path]]) -> None:
    code, out, where = refusals["batch"]
    assert code != 0 and "Traceback" not in out, out
    assert ("coartic batch on a Dask cluster (--serial runs without Dask) needs coartic's [batch] extra "
            "(dask, distributed are not installed): pip install 'coartic[batch]'") in out, out
    assert not (where / "b").exists()


def test_to_dataframe_names_its_extra(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    _, fit = fitted
    program = ("import sys\nfrom coartic.table import ParameterTable\nfrom coartic.extras import MissingExtra\n"
               "try:\n    ParameterTable.load(sys.argv[1]).to_dataframe()\n"
               "except MissingExtra as e:\n    print(e)\n")
    r = run_core([str(fit / "table.json")], tmp_path, program)
    assert ("to_dataframe() needs coartic's [dataframe] extra (pandas is not installed): "
            "pip install 'coartic[dataframe]'") in r.stdout, r.stdout + r.stderr


@pytest.mark.skipif(not os.environ.get("COARTIC_WHEEL"), reason="make test-core, after the core tests: the "
                    "extra installed on demand into the core environment")
def test_an_extra_installs_on_demand(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    """`pip install 'coartic[dataframe]'` over the core install, then what refused works. make test-core
    runs it in the same session as the core's tests, so it stays the last test of this file and this
    file the last of CORE_TESTS (Makefile): every test before it sees the core alone."""
    wheel = os.environ["COARTIC_WHEEL"]
    # --no-compile: what pip installs is the same; compiling all of pandas ahead (7.8 of its 10.7 CPU-s here) is
    # not, and the program below writes the bytecode of what it imports (bench/results/test_suite_cpu_core3.txt)
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-compile",
                          f"coartic[dataframe] @ file://{wheel}"],
                         capture_output=True, text=True, timeout=900)
    assert pip.returncode == 0, pip.stderr[-3000:]
    _, fit = fitted
    program = ("import sys\nfrom coartic.table import ParameterTable\n"
               "print(len(ParameterTable.load(sys.argv[1]).to_dataframe()))\n")
    r = subprocess.run([sys.executable, "-c", program, str(fit / "table.json")], capture_output=True, text=True,
                       timeout=300, cwd=tmp_path)
    assert r.returncode == 0 and int(r.stdout) > 0, r.stdout + r.stderr
