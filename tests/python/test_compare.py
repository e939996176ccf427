"""coartic compare: specs side by side by held-out RMSE and AIC/BIC (issue 10 item 4)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest
from typer.testing import CliRunner

from coartic.cli import app
from fit_helpers import german_utterance_spec
from coartic.jobs.compare import compare


def write_spec(tmp_path: Path, name: str, variant: str, free: str, validate: str = "") -> Path:
    return german_utterance_spec(tmp_path / f"{variant}_{len(free)}.toml",
                                 f'[model]\nvariant = "{variant}"\nchannels = ["JO"]\n[parameters]\nfree = {free}\n'
                                 '[staging]\nenabled = false\n' + validate, name=name)


def test_compare_tabulates_aic_bic_and_writes_table_and_plot(tmp_path: Path) -> None:
    a = write_spec(tmp_path, "targets <script>alert(1)</script>", "modified", '["target"]')
    b = write_spec(tmp_path, "targets and k_R", "modified", '["target", "k_r"]')
    cmp = compare([a, b], tmp_path / "out", validate=False)
    ra, rb = cmp.rows
    assert (ra.channel, rb.channel) == ("JO", "JO") and ra.n_samples == rb.n_samples
    assert rb.n_free > ra.n_free and rb.sse <= ra.sse * (1 + 1e-9)  # nested: more parameters fit no worse
    n = ra.n_samples
    assert ra.aic == pytest.approx(n * math.log(ra.sse / n) + 2 * ra.n_free)
    assert rb.bic == pytest.approx(n * math.log(rb.sse / n) + rb.n_free * math.log(n))
    assert math.isnan(ra.heldout_rmse)  # not validated
    html = (tmp_path / "out" / "compare.html").read_text()
    assert "<script>alert" not in html and "&lt;script&gt;" in html and 'src="compare.png"' in html
    assert (tmp_path / "out" / "compare.png").stat().st_size > 0
    assert (tmp_path / "out" / "compare.csv").read_text().count("\n") == 3
    assert cmp.best("JO", "rmse") == cmp.models[1]


def test_compare_command_reports_held_out_rmse_and_refuses_bad_specs(tmp_path: Path) -> None:
    # one utterance: its [validate] group cannot hold anything out; the comparison says so and goes on
    a = write_spec(tmp_path, "one", "modified", '["target"]', '[validate]\ngroup = "utterance"\n')
    res = CliRunner().invoke(app, ["compare", str(a), "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    assert "no validation" in (tmp_path / "c" / "compare.txt").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text('[corpus]\nmanifest = "none.csv"\n[engine.options]\nmax_nfev = 0\n')
    res = CliRunner().invoke(app, ["compare", str(a), str(bad), "--out", str(tmp_path / "d")])
    assert res.exit_code == 2 and "[engine.options.max_nfev]" in res.output


def test_compare_varies_a_setting_to_choose_a_prior_strength(tmp_path: Path) -> None:
    a = write_spec(tmp_path, "prior on theta", "modified", '["target", "theta_bw"]\nprior = { theta_bw = [5.0, 1.0] }')
    res = CliRunner().invoke(app, ["compare", str(a), "--no-validate", "--vary", "prior_noise=0.01,3",
                                   "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    with (tmp_path / "c" / "compare.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and "prior_noise = 0.01" in rows[0]["model"] and "prior_noise = 3" in rows[1]["model"]
    rmse = [float(r["rmse_mm"]) for r in rows]
    assert rmse[1] > rmse[0]  # a strong prior (noise 3 mm) pulls theta_bw to 5 ms and away from the data
    res = CliRunner().invoke(app, ["compare", str(a), "--vary", "speed=1,2", "--out", str(tmp_path / "d")])
    assert res.exit_code == 2 and "not a setting compare can vary" in res.output


def test_compare_exits_3_when_a_fit_did_not_converge(tmp_path: Path) -> None:
    """Issue 25 item 3: compare exited 0 while two of its fits ended best-found-once. A fit stopped at
    its evaluation limit (max-evaluations) makes it exit 3, as `coartic fit` does, naming the fit."""
    a = write_spec(tmp_path, "targets", "modified", '["target"]')
    b = write_spec(tmp_path, "capped", "modified", '["target", "theta_bw"]', '[engine.options]\nmax_nfev = 3\n')
    res = CliRunner().invoke(app, ["compare", str(a), str(b), "--no-validate", "--out", str(tmp_path / "c")])
    assert res.exit_code == 3, res.output
    said = " ".join(res.output.split())
    assert "2. capped" in said and "JO: max-evaluations" in said and "exit status 3" in said
    assert (tmp_path / "c" / "compare.csv").is_file()  # written all the same
    res = CliRunner().invoke(app, ["compare", "--help"], terminal_width=120)
    assert "Exit status: 0 every fit converged; 3" in " ".join(res.output.replace("│", " ").split())
