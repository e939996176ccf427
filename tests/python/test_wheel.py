"""`make wheel`: an abi3 wheel that installs with pip into a fresh virtual environment without Rust.

The wheel is built as `make wheel` builds it (maturin, release, into the checkout's own target
directory, which `make setup` has already filled, so only the packaging is new work). A fresh
virtual environment (no pip of its own) gets it from the shared environment's pip, with
`--no-index --no-deps` and no Rust on the PATH: nothing can be compiled or fetched. Its
dependencies come from the environment these tests run in, appended to the fresh one's path
after its own site-packages, so `coartic` itself can only come from the wheel. The installed
package then evaluates a model and must give the numbers of the checkout's build.
"""

from __future__ import annotations

import json
import os
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
BUILD_TIMEOUT_S = 1800  # a cold Rust build (fat LTO); with make setup's target directory, seconds

EVALUATE = """
import json, sys
import numpy as np
import coartic, coartic._core
from coartic.demo import illustrative_table
times = np.arange(70) / 100
out = coartic.trajectories(illustrative_table(), ["#", "a", "p", "a", "#"], np.array([0.0, 0.15, 0.29, 0.39, 0.55]),
                           np.array([0.15, 0.29, 0.39, 0.55, 0.70]), times)
from coartic.runtime.shipped import load_shipped_table
shipped = load_shipped_table()
print(json.dumps({"coartic": coartic.__file__, "core": coartic._core.__file__, "LLO": out["LLO"].tolist(),
                  "shipped": [str(shipped.source), len(shipped.phonemes)]}))
"""


def no_rust_env() -> dict[str, str]:
    """This environment without Rust: no cargo or rustc on the PATH, no Rust variables, no
    PYTHONPATH (which would put a checkout's coartic first)."""
    path = [d for d in os.environ.get("PATH", "").split(os.pathsep)
            if d and not (Path(d) / "cargo").exists() and not (Path(d) / "rustc").exists()]
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "CARGO_HOME", "RUSTUP_HOME", "CARGO_TARGET_DIR", "VIRTUAL_ENV")}
    env["PATH"] = os.pathsep.join(path)
    return env


def built_wheel(tmp_path: Path) -> Path:
    """The folder holding the wheel: `make test` builds it once, for `make test-core`, and passes it
    here as COARTIC_WHEEL_DIR (the same maturin command); run alone, this test builds its own."""
    given = os.environ.get("COARTIC_WHEEL_DIR")
    if given:
        return Path(given)
    dist = tmp_path / "dist"
    build = subprocess.run([sys.executable, "-m", "maturin", "build", "--release", "--quiet", "-o", str(dist)],
                           cwd=ROOT, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S,
                           env={k: v for k, v in os.environ.items() if k != "CARGO_TARGET_DIR"})
    assert build.returncode == 0, build.stderr[-3000:]
    return dist


def test_wheel_installs_into_a_fresh_venv_without_rust_and_evaluates(tmp_path: Path) -> None:
    dist = built_wheel(tmp_path)
    wheels = list(dist.glob("coartic-*.whl"))
    assert len(wheels) == 1, wheels
    wheel = wheels[0]
    assert "-cp311-abi3-" in wheel.name  # one wheel for every CPython >= 3.11
    names = zipfile.ZipFile(wheel).namelist()
    assert [n for n in names if n.endswith(".so")] == ["coartic/_core.abi3.so"] and "coartic/_core.pyi" in names
    assert "coartic/py.typed" in names and "coartic/estimator.py" in names
    # package data: the shipped Italian table (the default of speak/animate) and the phone maps
    assert {"coartic/runtime/italian_table.json", "coartic/runtime/italian_table.provenance.json",
            "coartic/runtime/phones_italian.tsv", "coartic/runtime/phones_english.tsv"} <= set(names)

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    env = no_rust_env()
    install = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-index",
                              "--no-deps", "--no-compile", "--quiet", str(wheel)],
                             capture_output=True, text=True, timeout=300, env=env)
    assert install.returncode == 0, install.stderr
    fresh = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                capture_output=True, text=True, check=True, env=env).stdout.strip())
    assert (fresh / "coartic" / "_core.abi3.so").is_file()
    # the dependencies (NumPy, SciPy, ...) of the environment running this test, after the wheel's own
    ours = [p for p in {sysconfig.get_path("purelib"), *site.getsitepackages()} if Path(p).is_dir()]
    (fresh / "zz_test_dependencies.pth").write_text("\n".join(ours) + "\n")

    run = subprocess.run([str(py), "-c", EVALUATE], capture_output=True, text=True, timeout=300, env=env,
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout)
    assert Path(got["coartic"]).is_relative_to(fresh) and Path(got["core"]).is_relative_to(fresh)
    assert Path(got["shipped"][0]).is_relative_to(fresh) and got["shipped"][1] == 31  # every Italian phoneme

    import coartic
    from coartic.demo import illustrative_table

    times = np.arange(70) / 100
    here = coartic.trajectories(illustrative_table(), ["#", "a", "p", "a", "#"], np.array([0.0, 0.15, 0.29, 0.39, 0.55]),
                                np.array([0.15, 0.29, 0.39, 0.55, 0.70]), times)["LLO"]
    np.testing.assert_allclose(got["LLO"], here, rtol=1e-12, atol=1e-12)
    assert np.ptp(here) > 5  # the lips do move: /a/ open, /p/ closed
