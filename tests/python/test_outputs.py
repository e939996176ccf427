"""Outputs are whole or absent and never mix two runs (coartic.outputs, docs/OUTPUTS.md): the
staged output directory, its refusal of another run's output, interruption, kill -9, locks; and
the commands that use it (fit, animate, mcmc)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from coartic import outputs
from coartic.cli import app
from coartic.outputs import RUN_MARKER, OutputDir, OutputError, atomic_write_text, read_marker
from coartic.table import ParameterTable


def write_run(out: Path, identity: dict[str, str], files: dict[str, str], **kw: object) -> None:
    with OutputDir(out, "test", identity, **kw) as d:  # type: ignore[arg-type]
        for name, text in files.items():
            (d / name).parent.mkdir(parents=True, exist_ok=True)
            (d / name).write_text(text)


def listing(d: Path) -> set[str]:
    return {str(p.relative_to(d)) for p in d.rglob("*") if p.is_file()}


def test_a_run_is_swapped_in_whole_and_replaces_its_own_output(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"spec": "a"}, {"table.json": "1", "figures/old.png": "x"})
    assert listing(out) == {"table.json", "figures/old.png", RUN_MARKER}
    with OutputDir(out, "test", {"spec": "a"}) as d:
        assert d != out and d.name == ".out.partial"
        (d / "table.json").write_text("2")
        assert (out / "table.json").read_text() == "1"  # nothing visible before the run ends
    # the same run again: replaced whole, the stale figure gone
    assert listing(out) == {"table.json", RUN_MARKER}
    assert (out / "table.json").read_text() == "2"
    marker = read_marker(out)
    assert marker is not None and marker["status"] == "complete" and marker["identity"] == {"spec": "a"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging, old copy or lock left


def test_a_symlinked_output_directory_keeps_its_link(tmp_path: Path) -> None:
    (tmp_path / "disk").mkdir()
    write_run(tmp_path / "disk" / "out", {"spec": "a"}, {"t": "1"})
    (tmp_path / "link").symlink_to(tmp_path / "disk" / "out")
    write_run(tmp_path / "link", {"spec": "a"}, {"t": "2"})
    assert (tmp_path / "link").is_symlink() and (tmp_path / "disk" / "out" / "t").read_text() == "2"


def test_another_runs_output_is_refused_unless_forced(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"spec": "a"}, {"table.json": "1"})
    with pytest.raises(OutputError, match=r"out: holds coartic test spec a; this run \(coartic test spec b\).*--force"):
        write_run(out, {"spec": "b"}, {"table.json": "2"})
    assert (out / "table.json").read_text() == "1"
    write_run(out, {"spec": "b"}, {"other.txt": "2"}, force=True)
    assert listing(out) == {"other.txt", RUN_MARKER}
    # files no coartic run wrote: refused; an empty directory is fine
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="no coartic run wrote"):
        write_run(foreign, {"spec": "a"}, {"t": "1"})
    assert (foreign / "notes.txt").read_text() == "mine"
    (tmp_path / "empty").mkdir()
    write_run(tmp_path / "empty", {"spec": "a"}, {"t": "1"})


def test_inputs_inside_the_output_and_the_current_directory_are_never_replaced(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "spec.toml").write_text("")
    with pytest.raises(OutputError, match="spec.toml, an input of this run"):
        write_run(out, {"spec": "a"}, {"t": "1"}, force=True, protect=[out / "spec.toml"])
    monkeypatch.chdir(out)
    with pytest.raises(OutputError, match="current directory"):
        write_run(Path("."), {"spec": "a"}, {"t": "1"}, force=True)
    assert (out / "spec.toml").exists()


def test_a_failed_run_leaves_the_previous_output_and_an_interrupted_one_is_kept(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"spec": "a"}, {"table.json": "1"})
    with pytest.raises(RuntimeError):
        with OutputDir(out, "test", {"spec": "a"}) as d:
            (d / "table.json").write_text("half")
            raise RuntimeError("engine crashed")
    assert (out / "table.json").read_text() == "1" and not (tmp_path / ".out.partial").exists()
    # Ctrl-C: what was written is the result (the best point of an interrupted fit), marked so
    with pytest.raises(KeyboardInterrupt):
        with OutputDir(out, "test", {"spec": "a"}) as d:
            (d / "table.json").write_text("best so far")
            raise KeyboardInterrupt
    assert (out / "table.json").read_text() == "best so far"
    assert read_marker(out)["status"] == "interrupted"  # type: ignore[index]
    # abandoned (nothing worth keeping): the previous output stays
    write_run(out, {"spec": "a"}, {"x": ""})
    o = OutputDir(out, "test", {"spec": "a"})
    with o as d:
        (d / "table.json").write_text("nothing")
        o.abandon()
    assert listing(out) == {"x", RUN_MARKER}


def test_two_runs_cannot_write_one_directory(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with OutputDir(out, "test", {"spec": "a"}):
        with pytest.raises(OutputError, match=r"another coartic run is writing it \(pid \d+, coartic test"):
            write_run(out, {"spec": "a"}, {"t": "1"})
    write_run(out, {"spec": "a"}, {"t": "1"})  # released


KILLED = """
import os, signal, sys
from pathlib import Path
from coartic.outputs import OutputDir
with OutputDir(Path(sys.argv[1]), "test", {"spec": "a"}) as d:
    (d / "table.json").write_text("new, half written")
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_kill_9_during_a_run_loses_nothing_and_the_next_run_cleans_up(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"spec": "a"}, {"table.json": "1", "rmse.csv": "old"})
    p = subprocess.run([sys.executable, "-c", KILLED, str(out)], capture_output=True)
    assert p.returncode == -9
    assert listing(out) == {"table.json", "rmse.csv", RUN_MARKER} and (out / "table.json").read_text() == "1"
    assert (tmp_path / ".out.partial").exists()  # the dead run's staging, its lock released with it
    write_run(out, {"spec": "a"}, {"table.json": "2"})
    assert listing(out) == {"table.json", RUN_MARKER}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_swap_without_renameat2_and_a_kill_between_its_renames(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(outputs, "_exchange", lambda a, b: False)
    out = tmp_path / "out"
    write_run(out, {"spec": "a"}, {"table.json": "1"})
    write_run(out, {"spec": "a"}, {"table.json": "2"})
    assert listing(out) == {"table.json", RUN_MARKER} and (out / "table.json").read_text() == "2"
    # killed after moving the old output aside, before moving the new one in: the old one comes back
    os.replace(out, tmp_path / ".out.old")
    (tmp_path / ".out.partial").mkdir()
    with OutputDir(out, "test", {"spec": "a"}) as d:
        assert (out / "table.json").read_text() == "2"
        (d / "table.json").write_text("3")
    assert (out / "table.json").read_text() == "3"


def test_atomic_write_leaves_the_old_file_on_failure(tmp_path: Path) -> None:
    p = tmp_path / "table.json"
    atomic_write_text(p, "old")
    with pytest.raises(ZeroDivisionError):
        with outputs.atomic_path(p) as tmp:
            assert tmp.suffix == ".json" and tmp.parent == tmp_path
            tmp.write_text("half")
            1 / 0
    assert p.read_text() == "old" and [x.name for x in tmp_path.iterdir()] == ["table.json"]


# ------------------------------------------------------------------------- the commands
SPEC = """
name = "outputs test"
[corpus]
manifest = "{manifest}"
select = {{ vowel = ["a"] }}
[model]
channels = ["LLO", "ULO"]
[parameters]
free = ["target"]
[staging]
enabled = false
"""


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from coartic.synthetic_cli import load_generator

    root = tmp_path_factory.mktemp("outputs")
    manifest = load_generator().generate(root / "session", quick=True, progress=False, consonants=["p"])
    spec = root / "spec.toml"
    spec.write_text(SPEC.format(manifest=manifest))
    return spec, root


def fit(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(app, ["fit", *args, "--no-report"])
    return r.exit_code, r.output.replace("\n", " ")


def test_fit_over_another_runs_output_is_refused_and_a_rerun_replaces_its_own(session: tuple[Path, Path],
                                                                              tmp_path: Path) -> None:
    spec, _ = session
    out = tmp_path / "fit"
    code, text = fit(str(spec), "--out", str(out))
    assert code == 0, text
    assert set(ParameterTable.load(out / "table.json").channels) == {"LLO", "ULO"}
    before = (out / "table.json").read_bytes()
    # a JO-only (here LLO-only) fit of the same spec must not wipe the LLO+ULO table
    code, text = fit(str(spec), "--out", str(out), "--channels", "LLO")
    assert code == 2 and "holds coartic fit spec" in text and "--force" in text, text
    assert (out / "table.json").read_bytes() == before
    # the same spec and channels again: its own output replaced whole (a stale file does not survive)
    (out / "report_mcmc.html").write_text("<p>posterior of the previous fit</p>")
    code, text = fit(str(spec), "--out", str(out))
    assert code == 0, text
    assert not (out / "report_mcmc.html").exists()
    marker = json.loads((out / RUN_MARKER).read_text())
    assert marker["command"] == "fit" and marker["status"] == "complete"
    assert marker["identity"] == {"spec": str(spec.resolve()), "channels": "LLO,ULO"}
    code, text = fit(str(spec), "--out", str(out), "--channels", "LLO", "--force")
    assert code == 0, text
    assert set(ParameterTable.load(out / "table.json").channels) == {"LLO"}


def test_fit_output_written_before_markers_is_recognised(session: tuple[Path, Path], tmp_path: Path) -> None:
    """`make fit` over a results/synthetic of an earlier version: its summary.json names the spec."""
    spec, _ = session
    out = tmp_path / "fit"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"spec": str(spec), "channels": {"LLO": {}, "ULO": {}}}))
    code, text = fit(str(spec), "--out", str(out))
    assert code == 0, text
    (out / RUN_MARKER).unlink()
    (out / "summary.json").write_text(json.dumps({"spec": str(spec), "channels": {"JO": {}}}))
    code, text = fit(str(spec), "--out", str(out))
    assert code == 2 and "no coartic run wrote" in text, text


def test_ctrl_c_in_a_fit_keeps_the_best_point_and_while_loading_keeps_the_previous_output(
        session: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from coartic.fit import data
    from coartic.estimation.problem import ChannelProblem

    spec, _ = session
    out = tmp_path / "a" / "fit"  # parents created as needed (a fresh clone has no results/)
    assert fit(str(spec), "--out", str(out))[0] == 0
    (out / "stale.txt").write_text("")
    orig = ChannelProblem.residuals
    calls = {"n": 0}

    def residuals(self: ChannelProblem, x: object) -> object:
        calls["n"] += 1
        if calls["n"] == 4:  # one Ctrl-C inside the engine, on the first channel
            raise KeyboardInterrupt
        return orig(self, x)  # type: ignore[arg-type]

    monkeypatch.setattr(ChannelProblem, "residuals", residuals)
    code, text = fit(str(spec), "--out", str(out))
    assert code == 130 and "interrupted" in text, text
    assert json.loads((out / RUN_MARKER).read_text())["status"] == "interrupted"
    assert set(ParameterTable.load(out / "table.json").channels) == {"LLO"} and not (out / "stale.txt").exists()
    monkeypatch.setattr(ChannelProblem, "residuals", orig)
    assert fit(str(spec), "--out", str(out))[0] == 0
    before = listing(out)

    def loading(*a: object, **k: object) -> object:
        raise KeyboardInterrupt

    monkeypatch.setattr(data, "load_utterances", loading)
    code, text = fit(str(spec), "--out", str(out))
    assert code == 130 and "nothing was fitted" in text, text
    assert listing(out) == before and json.loads((out / RUN_MARKER).read_text())["status"] == "complete"


def test_mcmc_into_the_fit_directory_is_refused(session: tuple[Path, Path], tmp_path: Path) -> None:
    spec, _ = session
    out = tmp_path / "fit"
    assert fit(str(spec), "--out", str(out))[0] == 0
    before = (out / "table.json").read_bytes()
    for o in (out, out / "mcmc"):
        r = CliRunner().invoke(app, ["mcmc", str(spec), "--fit", str(out), "--out", str(o), "--quiet"])
        text = r.output.replace("\n", " ")
        assert r.exit_code == 2 and "fit directory" in text and "beside it" in text, text
    assert (out / "table.json").read_bytes() == before and not (out / "mcmc").exists()
    # chains of another spec: refused (resuming them would mix two runs), not deleted
    other = tmp_path / "mcmc"
    with OutputDir(other, "mcmc", {"spec": "/elsewhere/spec.toml", "fit": str(out / "table.json")}, staged=False) as d:
        (d / "mcmc.json").write_text("[]")
    r = CliRunner().invoke(app, ["mcmc", str(spec), "--fit", str(out), "--out", str(other), "--quiet"])
    text = r.output.replace("\n", " ")
    assert r.exit_code == 2 and "holds coartic mcmc spec /elsewhere/spec.toml" in text, text
    assert (other / "mcmc.json").read_text() == "[]"


def test_animate_into_a_used_directory(tmp_path: Path) -> None:
    from test_runtime_animate import LABELS, make_table

    table = tmp_path / "table.json"
    make_table().save(table)
    a, b = tmp_path / "a.tsv", tmp_path / "b.tsv"
    a.write_text(LABELS)
    b.write_text(LABELS)
    out = tmp_path / "anim"

    def animate(labels: Path, *extra: str) -> tuple[int, str]:
        r = CliRunner().invoke(app, ["animate", str(labels), "--table", str(table), "--out", str(out),
                                     "--fps", "25", *extra])
        return r.exit_code, r.output.replace("\n", " ")

    code, text = animate(a, "--preview", "none")
    assert code == 0, text
    first = listing(out)
    code, text = animate(b, "--preview", "none")
    assert code == 2 and "holds coartic animate labels" in text, text
    assert listing(out) == first
    code, text = animate(b, "--preview", "none", "--force")
    assert code == 0, text
    assert "b.fap" in listing(out) and "a.fap" not in listing(out)
