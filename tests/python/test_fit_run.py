"""End to end: `coartic fit` on a quick synthetic session (recovery of the truth) and on the real
German EMA recordings (an RMSE that must not get worse)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.jobs.fit import fit_job
from coartic.fit.spec import load_spec
from coartic.table import ParameterTable

from conftest import without_overview
from fit_helpers import PAPER_TOML

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def quick_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The /p f t/ trials of the quick session, the only ones these tests select: the same trials as
    the whole session's (each trial's random stream is its own), a seventh of its generation;
    `coartic corpus synth` itself is tested in test_synthetic.py."""
    out = tmp_path_factory.mktemp("session")
    with without_overview() as gen:  # the session's trials are what is fitted; its figure is not used
        gen.generate(out / "s", quick=True, progress=False, consonants=["p", "f", "t"])
    return out / "s"


@pytest.mark.slow
def test_cli_fit_recovers_synthetic_truth(quick_session: Path, tmp_path: Path) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text(f"""
[corpus]
manifest = "{quick_session / 'manifest.csv'}"
select = {{ consonant = ["p", "f", "t"] }}
[model]
channels = ["LLO"]
{PAPER_TOML[0]}[parameters]
{PAPER_TOML[1]}free = ["target", "alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "k_r", "delta"]
[[override]]
phonemes = ["a", "p", "b", "m"]
free = ["sigma", "psi"]
""")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "LLO" in res.output and (out / "report.html").is_file()
    for f in ("table.json", "table.csv", "rmse.csv", "parameters.csv", "fit_report.txt",
              "figures/trajectories_LLO.png", "figures/rmse_map.png", "figures/truth.png"):
        assert (out / f).is_file(), f
    table = ParameterTable.load(out / "table.json")
    truth = ParameterTable.load(quick_session / "ground_truth.json")
    assert table.metadata["rmse"]["LLO"] < 0.3
    rows = (out / "rmse.csv").read_text().splitlines()
    vowel_rows = [r.split(",") for r in rows if ",vowel," in r]
    assert len(vowel_rows) == 3 and all(float(r[3]) < 0.3 for r in vowel_rows)
    # the spec of fit/synthetic.toml (shape only where phonetics expects it): every target recovered
    for ph in ("#", "a", "i", "u", "p", "f", "t"):
        assert abs(table.values[ph]["LLO"]["target"] - truth.values[ph]["LLO"]["target"]) < 0.2, ph
    for ph in ("p", "f"):
        assert table.values[ph]["LLO"]["k_r"] >= 0.9, ph


# Today's figures (fit/ema_german.toml, `coartic fit fit/ema_german.toml`): LA 0.547 mm, JO 0.189 mm.
EMA_RMSE_LIMIT = {"LA": 0.60, "JO": 0.21}


@pytest.mark.slow
def test_real_ema_rmse_does_not_get_worse(tmp_path: Path) -> None:
    # no HTML report: a fifth of this test's CPU time, and nothing here reads it (the report of a
    # real-EMA fit is written and read by test_fit_multistart's CLI test)
    result = fit_job(load_spec(ROOT / "fit" / "ema_german.toml"), tmp_path, quiet=True, report=False)
    assert not result.interrupted
    for ch, limit in EMA_RMSE_LIMIT.items():
        assert result.channels[ch].rmse < limit, f"{ch}: RMSE {result.channels[ch].rmse:.3f} mm > {limit}"
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["channels"]) == {"LA", "JO"}
    # every phoneme of the German utterances got a row, and the table round-trips
    t = ParameterTable.load(tmp_path / "table.json")
    assert {"#", "a", "p", "b", "m"} <= set(t.phonemes)
    assert np.isfinite(t.metadata["rmse"]["LA"])


def test_cli_reports_spec_errors(tmp_path: Path) -> None:
    spec = tmp_path / "bad.toml"
    spec.write_text('[corpus]\nmanifest = "none.csv"\n[engine]\nname = "gauss"\n')
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    assert "engine.name" in res.output and "bad.toml" in res.output and "Traceback" not in res.output
    spec.write_text('[corpus]\nmanifest = "none.csv"\n')
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "corpus.manifest" in res.output and "does not exist" in res.output


def test_cli_fit_progress_goes_to_stderr_as_lines_and_quiet_silences_it(quick_session: Path, tmp_path: Path) -> None:
    spec = tmp_path / "spec.toml"
    spec.write_text(f"""
[corpus]
manifest = "{quick_session / 'manifest.csv'}"
select = {{ consonant = ["p"] }}
[model]
channels = ["LLO"]
[parameters]
free = ["target", "alpha"]
""")
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "a"), "--no-report"])
    assert res.exit_code == 0, res.output
    # not a terminal: a line per stage and channel, the last with the channel's status, nothing drawn
    done = [line for line in res.stderr.splitlines() if line.startswith("LLO done")]
    assert len(done) == 1 and " evaluations RMSE " in done[0] and "[converged]" in done[0], res.stderr
    assert res.stderr.splitlines()[0].startswith("loading trials") and "\x1b" not in res.stderr
    assert "RMSE (mm)" in res.stdout and "evaluations" not in res.stdout
    quiet = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "b"), "--no-report", "--quiet"])
    assert quiet.exit_code == 0, quiet.output
    assert quiet.stderr == "" and "RMSE (mm)" in quiet.stdout
