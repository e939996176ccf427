"""One error handler for every command (coartic.console.ERRORS: exception -> exit status ->
message), and the hostile cases it and the commands must survive: inputs reached through a
symlinked output folder, user folders named like coartic's own staging, lock and swap names, the
root as --out, unbounded numbers, options that would be silently ignored."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from coartic.cli import COMMANDS, app, load_command
from coartic.console import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_NOTHING, EXIT_OK, EXIT_UNCONFIRMED, ERRORS,
                             error_exit)
from coartic.errors import SpecError
from coartic.io.errors import DataError
from coartic.outputs import OutputDir, OutputError

from test_runtime_animate import LABELS, make_table


def run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "300"})
    assert "Traceback" not in r.output
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        raise r.exception  # a traceback the handler did not turn into a message
    return r.exit_code, " ".join(r.output.split())


@pytest.fixture()
def anim_inputs(tmp_path: Path) -> tuple[Path, Path]:
    table = tmp_path / "t.json"
    make_table().save(table)
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    return table, labels


# ------------------------------------------------------------------------------- the table
def test_the_table_maps_each_kind_of_error_to_its_status_and_message() -> None:
    assert [code for _, code, _ in ERRORS] == [EXIT_INTERRUPTED, EXIT_ERROR, EXIT_ERROR, EXIT_ERROR, EXIT_ERROR]
    assert (EXIT_OK, EXIT_NOTHING, EXIT_ERROR, EXIT_UNCONFIRMED, EXIT_INTERRUPTED) == (0, 1, 2, 3, 130)
    assert error_exit(SpecError.at("s.toml", "fit.starts", "too many")) == (2, "s.toml: [fit.starts] too many")
    assert error_exit(DataError("x.csv: line 3: bad")) == (2, "x.csv: line 3: bad")
    code, text = error_exit(FileNotFoundError(errno.ENOENT, "No such file or directory", "x.toml"))  # type: ignore[misc]
    assert code == 2 and text == "x.toml: does not exist: check the path"
    code, text = error_exit(IsADirectoryError(errno.EISDIR, "Is a directory", "out"))  # type: ignore[misc]
    assert code == 2 and text == "out: is a folder: give a file's path" and "Errno" not in text
    code, text = error_exit(KeyboardInterrupt())  # type: ignore[misc]
    assert code == 130 and "interrupted" in text
    code, text = error_exit(MemoryError())  # type: ignore[misc]
    assert code == 2 and "out of memory" in text and "lower it" in text
    assert error_exit(AssertionError("a bug")) is None  # in no row: a bug keeps its traceback


# one refused input per command: each goes through the handler (exit 2, one `error:` line)
BAD_INPUT: dict[str, list[str]] = {
    "inspect": ["inspect", "{tmp}/nothere.c3d"],
    "fit": ["fit", "{tmp}/nothere.toml", "--out", "{tmp}/o"],
    "score": ["score", "{tmp}/nothere.json", "{tmp}/rec.csv", "--labels", "{tmp}/rec.tsv"],
    "compare": ["compare", "{tmp}/nothere.toml", "--out", "{tmp}/o"],
    "mcmc": ["mcmc", "{tmp}/nothere.toml", "--fit", "{tmp}/fit", "--out", "{tmp}/o"],
    "animate": ["animate", "{tmp}/nothere.tsv", "--out", "{tmp}/o"],
    "speak": ["speak", "ciao", "--lang", "fr", "--out", "{tmp}/o"],
    "demo": ["demo", "--out", "/"],
    "view": ["view", "{tmp}/nothere"],
    "batch": ["batch", "{tmp}/nothere.toml", "--out", "{tmp}/o"],
    "corpus": ["corpus", "synth", "/"],
    "align": ["align", "{tmp}/nothere.wav", "--text", "ciao", "--out", "{tmp}/o"],
    "perceive": ["perceive", "prepare", "{tmp}/nothere.toml", "--out", "{tmp}/o"],
}


def test_every_command_has_a_bad_input_case_and_is_handled() -> None:
    assert set(BAD_INPUT) == set(COMMANDS)
    for name in COMMANDS:
        cmd = load_command(name)
        callbacks = [c.callback for c in cmd.commands.values()] if hasattr(cmd, "commands") else [cmd.callback]
        assert callbacks and all(getattr(cb, "coartic_handled", False) for cb in callbacks), name


@pytest.mark.parametrize("name", sorted(BAD_INPUT))
def test_each_command_reports_an_error_through_the_handler(name: str, tmp_path: Path) -> None:
    code, text = run(*(a.format(tmp=tmp_path) for a in BAD_INPUT[name]))
    assert code == EXIT_ERROR and text.count("error:") == 1, (name, text)


# ----------------------------------------------------------------------------- data lost
def test_an_input_reached_through_a_symlink_to_the_output_is_never_deleted(tmp_path: Path,
                                                                          anim_inputs: tuple[Path, Path]) -> None:
    table, _ = anim_inputs
    anim = tmp_path / "anim"
    anim.mkdir()
    (anim / "labels.tsv").write_text(LABELS)
    (anim / "notes.txt").write_text("mine")
    (tmp_path / "alink").symlink_to(anim)
    for labels in (tmp_path / "alink" / "labels.tsv", anim / "labels.tsv"):
        code, text = run("animate", labels, "-t", table, "--out", anim, "--preview", "none", "--force")
        assert code == 2 and "an input of this run" in text and "choose another --out" in text, text
    # through `..` and a symlinked parent as well
    (tmp_path / "sub").mkdir()
    via = tmp_path / "sub" / ".." / "alink" / "labels.tsv"
    code, text = run("animate", via, "-t", table, "--out", tmp_path / "alink", "--preview", "none", "--force")
    assert code == 2 and "an input of this run" in text, text
    assert sorted(p.name for p in anim.iterdir()) == ["labels.tsv", "notes.txt"]


@pytest.mark.parametrize("name", [".o.partial", ".o.old"])
def test_a_user_folder_named_like_coartics_staging_is_not_deleted(tmp_path: Path, name: str,
                                                                  anim_inputs: tuple[Path, Path]) -> None:
    table, labels = anim_inputs
    mine = tmp_path / name
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    for force in ([], ["--force"]):
        code, text = run("animate", labels, "-t", table, "--out", tmp_path / "o", "--preview", "none", *force)
        assert code == 2 and f"{mine}: coartic uses this name" in text and "Move it away" in text, text
    assert (mine / "thesis.tex").read_text() == "precious"


def test_a_user_file_named_like_coartics_lock_is_not_overwritten(tmp_path: Path,
                                                                 anim_inputs: tuple[Path, Path]) -> None:
    table, labels = anim_inputs
    lock = tmp_path / ".o.lock"
    lock.write_text("my shopping list")
    code, text = run("animate", labels, "-t", table, "--out", tmp_path / "o", "--preview", "none", "--force")
    assert code == 2 and "not coartic's lock file" in text, text
    assert lock.read_text() == "my shopping list"
    lock.unlink()
    (tmp_path / "elsewhere").write_text("x")
    lock.symlink_to(tmp_path / "elsewhere")
    code, text = run("animate", labels, "-t", table, "--out", tmp_path / "o", "--preview", "none")
    assert code == 2 and "not coartic's lock file" in text, text
    assert (tmp_path / "elsewhere").read_text() == "x"


def test_coartics_own_leftovers_are_still_tidied(tmp_path: Path) -> None:
    out = tmp_path / "o"
    # a killed run's staging (marked), an empty one, and a stale lock of a dead process
    with OutputDir(out, "test", {"a": 1}):
        pass
    staged = OutputDir(out, "test", {"a": 1})
    staged.__enter__()  # never left: as if killed (its lock is released by hand below)
    assert (tmp_path / ".o.partial" / "coartic_run.json").is_file()
    staged._unlock()
    (tmp_path / ".o.lock").write_text("pid 1, coartic test, since 2026-01-01")
    with OutputDir(out, "test", {"a": 1}) as d:
        (d / "t").write_text("1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


# ----------------------------------------------------------------------------- tracebacks
def test_the_root_as_output_is_refused_before_anything(tmp_path: Path, anim_inputs: tuple[Path, Path]) -> None:
    table, labels = anim_inputs
    (tmp_path / "root").symlink_to("/")
    for out in ("/", tmp_path / "root", tmp_path / "root" / ".."):
        code, text = run("animate", labels, "-t", table, "--out", out, "--preview", "none", "--force")
        assert code == 2 and "the root directory cannot be an output directory" in text, text
    with pytest.raises(OutputError, match="resolves to /"):
        OutputDir(tmp_path / "root", "test", {})


@pytest.mark.parametrize("fps", ["inf", "nan", "-inf", "0", "-5"])
def test_a_frame_rate_that_is_not_one_is_refused(tmp_path: Path, fps: str, anim_inputs: tuple[Path, Path]) -> None:
    table, labels = anim_inputs
    code, text = run("animate", labels, "-t", table, "--out", tmp_path / "o", "--preview", "none", "--fps", fps)
    assert code == 2 and "--fps" in text and "finite number of frames per second above 0" in text, text
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("port", "bound"), [("70000", "65535"), ("-1", "0")])
def test_a_port_out_of_range_is_refused(tmp_path: Path, port: str, bound: str) -> None:
    code, text = run("view", tmp_path, "--serve", "--port", port)
    assert code == 2 and "--port" in text and bound in text, text


def test_output_paths_through_a_file_or_a_folder_name_the_option_and_the_fix(
        tmp_path: Path, anim_inputs: tuple[Path, Path]) -> None:
    table, labels = anim_inputs
    (tmp_path / "file").write_text("x")
    code, text = run("animate", labels, "-t", table, "--out", tmp_path / "file" / "sub", "--preview", "none")
    assert code == 2 and "is a file, not a folder" in text and "choose another --out" in text, text
    assert "Errno" not in text
    code, text = run("animate", labels, "-t", table, "--out", tmp_path / "file", "--preview", "none")
    assert code == 2 and "is a file, not a directory" in text and "Errno" not in text, text
    (tmp_path / "plots").mkdir()
    code, text = run("inspect", labels, "--plot", tmp_path / "plots")
    assert code == 2 and f"--plot {tmp_path / 'plots'}: is a folder; give the file to write" in text, text
    code, text = run("inspect", labels, "--plot", tmp_path / "file" / "x.png")
    assert code == 2 and "is a file, not a folder" in text and "Errno" not in text, text
    # checked before Chromium runs
    code, text = run("view", tmp_path, "--screenshot", tmp_path / "plots")
    assert code == 2 and f"--screenshot {tmp_path / 'plots'}: is a folder; give the file to write, e.g. --screenshot " \
        f"{tmp_path / 'plots' / 'view.png'}" in text, text


# ------------------------------------------------------------------- bounds and silent no-ops
def test_tls_certificates_without_a_scheduler_are_refused(tmp_path: Path) -> None:
    code, text = run("batch", tmp_path / "b.toml", "--out", tmp_path / "o", "--tls-ca-file", tmp_path / "ca.pem")
    assert code == 2 and "--tls-ca-file" in text and "--scheduler tls://" in text, text


def test_start_counts_are_bounded_with_the_bound_in_the_message(tmp_path: Path) -> None:
    from fit_helpers import spec_of

    with pytest.raises(SpecError, match=r"\[fit.starts\] 1000000000000: at most 10000"):
        spec_of(tmp_path, fit={"starts": 10**12})
    code, text = run("fit", tmp_path / "s.toml", "--starts", "1000000000")
    assert code == 2 and "--starts" in text and "10000" in text, text


def test_probe_lengths_and_worker_counts_are_bounded_with_the_bound_in_the_message(tmp_path: Path) -> None:
    from fit_helpers import spec_of

    from coartic.batch.run import MAX_WORKERS, run_batch
    from coartic.errors import UsageError

    with pytest.raises(SpecError, match=r"\[fit.probe\] 1000000000: at most 10000"):
        spec_of(tmp_path, fit={"probe": 10**9})
    code, text = run("batch", tmp_path / "b.toml", "--out", tmp_path / "o", "--workers", "1000000")
    assert code == 2 and "--workers" in text and str(MAX_WORKERS) in text, text
    with pytest.raises(UsageError, match=f"workers = 0: between 1 and {MAX_WORKERS}"):
        run_batch(None, tmp_path / "o", workers=0)  # type: ignore[arg-type]  # refused before the spec is read
    assert not (tmp_path / "o").exists()


def test_beta_beyond_its_fit_box_is_refused(tmp_path: Path) -> None:
    from fit_helpers import spec_of

    with pytest.raises(SpecError, match=r"\[model.beta\] beta = 1e\+308 is above 20, the upper end of \[model\] "
                                        "beta_bounds"):
        spec_of(tmp_path, model={"channels": ["LLO"], "beta": 1e308})
    spec_of(tmp_path, model={"channels": ["LLO"], "beta": 30.0, "beta_bounds": [0.05, 40.0]})  # widened: fine


def test_a_holdout_repetition_that_is_not_there_is_said(tmp_path: Path) -> None:
    import numpy as np

    from coartic.fit.simulate import vcv_utterances
    from coartic.evaluation.validate import splits
    from fit_helpers import spec_of

    for bad in (-1, 0):
        with pytest.raises(SpecError, match=r"\[validate.holdout_repetition\] expected a positive integer"):
            spec_of(tmp_path, validate={"holdout_repetition": bad})
    utts = vcv_utterances(np.random.default_rng(2), repetitions=2, noise=0.1)
    notes: list[str] = []
    got = splits(spec_of(tmp_path, validate={"holdout_repetition": 99}), utts, notes)
    assert [n for n, _, _ in got] == ["fit normal rate, test fast rate"]
    assert len(notes) == 1 and "holdout_repetition = 99: the corpus's repetitions are 1, 2" in notes[0]


def test_nothing_free_is_refused_not_reported_as_a_multistart(tmp_path: Path) -> None:
    from fit_helpers import german_utterance_spec

    spec = german_utterance_spec(tmp_path / "free.toml", '[model]\nchannels = ["LLO"]\n[parameters]\nfree = []\n')
    code, text = run("fit", spec, "--out", tmp_path / "o", "--no-report", "--quiet")
    assert code == 2 and "[parameters.free] LLO: no parameter is free" in text and "starts" not in text, text
    assert not (tmp_path / "o").exists()


WAV = Path(__file__).resolve().parents[1] / "data" / "realdata" / "emu-ema-german" / "derived" / \
    "dfgspp_mo1_prosody_0020.wav"


@pytest.mark.parametrize("command", ["align", "animate"])
@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_a_recording_length_limit_must_be_a_duration(tmp_path: Path, command: str, value: str) -> None:
    # NaN used to pass the limit (every comparison with it is false), -1 read as "-1:59:59"
    code, text = run(command, WAV, "--text", "hallo", "--lang", "de", "--out", tmp_path / "o", "--max-duration", value)
    assert code == 2 and "--max-duration" in text and "give a finite number above 0" in text, text
    assert not (tmp_path / "o").exists()
