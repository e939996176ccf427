"""`coartic mcmc` end to end on a small synthetic session: fit, sample, report, resume, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.mcmc.sampler import ChainStore
from conftest import without_overview

SPEC = """
name = "mcmc cli test"
[corpus]
manifest = "{manifest}"
select = {{ vowel = ["a"] }}
[model]
channels = ["LLO"]
reference_phoneme = "a"
[parameters]
free = ["target", "theta_bw", "theta_fw", "k_r"]
[staging]
enabled = false
{mcmc}
"""
MCMC = """
[mcmc]
phonemes = ["p"]
walkers = 14
ensembles = 2
chunk_steps = 100
min_steps = 100
max_steps = 200
"""


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from coartic.jobs.fit import fit_job
    from coartic.report.html import write_report
    root = tmp_path_factory.mktemp("mcmc_cli")
    with without_overview() as gen:  # the trials are what is fitted and sampled; the session's figure is not used
        manifest = gen.generate(root / "session", quick=True, progress=False, consonants=["p"])
    spec = root / "spec.toml"
    spec.write_text(SPEC.format(manifest=manifest, mcmc=MCMC))
    result = fit_job(spec, root / "fit", quiet=True)  # the least-squares fit ignores [mcmc]
    write_report(result, root / "fit")
    return spec, root / "fit"


def without_plots(spec: Path, tmp_path: Path) -> Path:
    """The fixture's spec with ``[mcmc] plots = false``, for the tests that do not look at the
    plots: the trace, corner and predictive plots of a posterior cost more CPU than these short
    runs' sampling (test_unconverged_run_says_so_writes_everything_and_resumes checks them)."""
    quiet = tmp_path / "no_plots.toml"
    quiet.write_text(spec.read_text().replace("[mcmc]\n", "[mcmc]\nplots = false\n"))
    return quiet


@pytest.mark.slow
def test_unconverged_run_says_so_writes_everything_and_resumes(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    shared, fit = fitted
    spec = tmp_path / "spec.toml"  # a copy: the resume below samples it without plots
    spec.write_text(shared.read_text())
    out = tmp_path / "mcmc"
    runner = CliRunner()
    r = runner.invoke(app, ["mcmc", str(spec), "--fit", str(fit), "--out", str(out), "--strict", "--quiet"])
    assert r.exit_code == 3, r.output
    assert "NOT CONVERGED" in r.output and "chain too short" in r.output
    table = json.loads((out / "table.json").read_text())
    q = table["uncertainty"]["p"]["LLO"]
    assert set(q) == {"target", "theta_bw", "theta_fw", "k_r"}
    assert q["target"]["q2.5"] < q["target"]["q50"] < q["target"]["q97.5"]
    assert table["metadata"]["mcmc"]["not_converged"] == ["LLO /p/"]
    summary = json.loads((out / "LLO" / "p" / "summary.json").read_text())
    assert summary["converged"] is False and summary["convergence"]["problems"]
    for name in ("trace.png", "corner.png", "predictive.png"):
        assert (out / "LLO" / "p" / name).stat().st_size > 1000
    report = (fit / "report.html").read_text()
    assert report.count("coartic-mcmc begin") == 1 and "NOT CONVERGED" in report
    assert (fit / "report_mcmc.html").is_file()

    # the same command with a longer budget continues the saved chains. Its plots are the ones checked
    # above, drawn again: the spec (the output folder records its path) now says plots = false
    before = ChainStore(out / "LLO" / "p" / "chains").load(0, 6, 14)[0]
    spec.write_text(without_plots(spec, tmp_path).read_text())
    r = runner.invoke(app, ["mcmc", str(spec), "--fit", str(fit), "--out", str(out), "--max-steps", "300", "--quiet"])
    assert r.exit_code == 0, r.output
    after = ChainStore(out / "LLO" / "p" / "chains").load(0, 6, 14)[0]
    assert len(before) == 200 and len(after) == 300
    np.testing.assert_array_equal(after[:200], before)
    assert (fit / "report.html").read_text().count("coartic-mcmc begin") == 1


def test_errors_name_the_file_and_key(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    spec, fit = fitted
    runner = CliRunner()
    bad = tmp_path / "bad.toml"
    bad.write_text(spec.read_text().replace("walkers = 14", "walkerz = 14"))
    # A terminal narrower than the temporary path must not break the message (soft wrap only).
    narrow = {"COLUMNS": "20"}
    r = runner.invoke(app, ["mcmc", str(bad), "--fit", str(fit), "--out", str(tmp_path / "o")], env=narrow)
    assert r.exit_code == 2 and f"{bad}: [mcmc] walkerz: unknown key" in r.output
    r = runner.invoke(app, ["mcmc", str(spec), "--fit", str(tmp_path), "--out", str(tmp_path / "o")], env=narrow)
    assert r.exit_code == 2 and "expected one parameter table" in r.output
    r = runner.invoke(app, ["mcmc", str(spec), "--fit", str(fit), "--out", str(tmp_path / "o"), "--phonemes", "zz"],
                      env=narrow)
    assert r.exit_code == 2 and "zz do not occur in the LLO data" in r.output


@pytest.mark.slow
def test_ctrl_c_in_the_command_saves_and_the_rerun_resumes(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    import signal
    import subprocess
    import sys
    import time

    spec, fit = fitted
    spec = without_plots(spec, tmp_path)
    out = tmp_path / "mcmc"
    cmd = [sys.executable, "-m", "coartic.cli", "mcmc", str(spec), "--fit", str(fit), "--out", str(out),
           "--max-steps", "2000", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    chains = out / "LLO" / "p" / "chains"
    deadline = time.monotonic() + 120
    while not list(chains.glob("ens01_chunk*.npz")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    output, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, output
    assert "Run the same command again to resume" in output.replace("\n", " ")
    saved = ChainStore(chains).load(0, 6, 14)[0]
    assert len(saved) >= 100
    import arviz as az  # the chains so far as InferenceData too, marked as interrupted

    assert az.from_netcdf(out / "LLO" / "p" / "posterior.nc").posterior.attrs["interrupted"] == 1
    r = CliRunner().invoke(app, ["mcmc", str(spec), "--fit", str(fit), "--out", str(out), "--max-steps", str(len(saved) + 100), "--quiet"])
    assert r.exit_code == 0, r.output
    resumed = ChainStore(chains).load(0, 6, 14)[0]
    assert len(resumed) == len(saved) + 100
    np.testing.assert_array_equal(resumed[: len(saved)], saved)


def test_inference_data_and_dataframe_from_the_library_function(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    """coartic.mcmc.sample is the command's job; each posterior's posterior.nc is ArviZ's."""
    import arviz as az
    import pandas as pd

    from coartic.mcmc import sample
    from coartic.mcmc.convergence import walker_chains

    spec, fit = fitted
    out = tmp_path / "mcmc"
    result = sample(without_plots(spec, tmp_path), fit, out)
    assert [r.label for r in result.runs] == ["LLO /p/"] and not result.interrupted and not result.converged
    run = result.runs[0]
    idata = az.from_netcdf(out / "LLO" / "p" / "posterior.nc")
    assert {"posterior", "sample_stats", "observed_data"} <= set(idata.groups())
    theta = idata.posterior["theta"]
    assert theta.dims == ("chain", "draw", "entry") and theta.sizes["chain"] == 2 * 14
    assert list(theta["entry"].values) == [s.name for s in run.summaries]
    assert list(theta["parameter"].values) == ["target", "theta_bw", "theta_fw", "k_r", "sigma_n", "offset_sd"]
    assert list(theta["phoneme"].values) == ["p"] * 4 + ["", ""] and str(theta["channel"].values) == "LLO"
    burn, thin = run.result.report.burn_in, run.result.report.thin  # type: ignore[union-attr]
    want = run.posterior.to_natural(walker_chains(run.result.chains, burn, thin))
    np.testing.assert_array_equal(theta.values, want)
    np.testing.assert_array_equal(idata.sample_stats["lp"].values[:, 0],
                                  np.concatenate([lp[burn] for lp in run.result.log_probs]))
    # the summaries are made of the same draws
    q50 = float(np.percentile(theta.sel(entry="p.target").values, 50))
    assert q50 == pytest.approx(run.summaries[0].quantiles["q50"], rel=1e-12)
    assert idata.observed_data["y"].size == int(run.posterior.data.weights.sum())
    assert idata.posterior.attrs["converged"] == 0 and idata.posterior.attrs["burn_in"] == burn
    assert az.summary(idata, var_names=["theta"]).shape[0] == 6  # ArviZ's own tools read it
    index = json.loads((out / "mcmc.json").read_text())
    assert index[0]["inference_data"] == "LLO/p/posterior.nc"
    assert not list((out / "LLO" / "p").glob(".posterior.tmp-*"))  # written aside, then renamed

    df = result.to_dataframe()
    assert isinstance(df, pd.DataFrame) and len(df) == 6
    row = df[(df.phoneme == "p") & (df.parameter == "target")].iloc[0]
    assert row["q50"] == run.summaries[0].quantiles["q50"] and row["channel"] == "LLO" and not row["converged"]
    assert all(pd.api.types.is_float_dtype(df[c]) for c in ("start", "mean", "sd", "q2.5", "q97.5", "rhat"))


def test_a_table_fitted_to_other_data_is_refused(fitted: tuple[Path, Path], tmp_path: Path) -> None:
    spec, fit = fitted
    doc = json.loads((fit / "table.json").read_text())
    doc["metadata"]["rmse"]["LLO"] *= 1.05  # as if the data had changed since the fit
    stale = tmp_path / "stale.json"
    stale.write_text(json.dumps(doc))
    r = CliRunner().invoke(app, ["mcmc", str(spec), "--fit", str(stale), "--out", str(tmp_path / "o"), "--quiet"])
    assert r.exit_code == 2 and "fitted to other data than the spec gives now" in r.output.replace("\n", " ")
    assert not (tmp_path / "o" / "LLO").exists()


def test_mcmc_command_samples_a_speakers_fit(tmp_path: Path) -> None:
    """`coartic mcmc` on a fit with [model] speakers = "offset_scale": the speakers' offset and scale
    are sampled (summary.json), the table gets the phoneme's quantiles only, and a spec without the
    speakers is refused for that table (exit 2, naming both)."""
    from coartic.jobs.fit import fit_job
    with without_overview() as gen:
        manifest = gen.generate(tmp_path / "session", quick=True, progress=False, consonants=["p"], speakers=2)
    # the fewest steps the MCMC section takes (one chunk); no plots (what is checked is the sampled names)
    mcmc = MCMC.replace("max_steps = 200", "max_steps = 100").replace("walkers = 14", "walkers = 18") + "plots = false\n"
    spec = tmp_path / "spec.toml"
    text = SPEC.format(manifest=manifest, mcmc=mcmc).replace('select = { vowel = ["a"] }',
                                                              'select = { vowel = ["a"], repetition = ["1"] }')
    spec.write_text(text.replace('reference_phoneme = "a"', 'reference_phoneme = "a"\nspeakers = "offset_scale"'))
    fit_job(spec, tmp_path / "fit", quiet=True, report=False)
    out = tmp_path / "mcmc"
    r = CliRunner().invoke(app, ["mcmc", str(spec), "--fit", str(tmp_path / "fit"), "--out", str(out), "--quiet"])
    assert r.exit_code == 0, r.output
    names = [p["name"] for p in json.loads((out / "LLO" / "p" / "summary.json").read_text())["parameters"]]
    assert "speaker_offset:s02" in names and "speaker_scale:s02" in names and "speaker_offset:s01" not in names
    table = json.loads((out / "table.json").read_text())
    assert set(table["uncertainty"]) == {"p"}
    plain = tmp_path / "plain.toml"
    plain.write_text(text)
    bad = CliRunner().invoke(app, ["mcmc", str(plain), "--fit", str(tmp_path / "fit"), "--out", str(tmp_path / "m2"),
                                   "--quiet"])
    assert bad.exit_code != 0 and "speakers = 'offset_scale'" in bad.output and "Traceback" not in bad.output
