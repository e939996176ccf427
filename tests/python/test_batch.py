"""coartic batch: many speakers, units as Dask tasks on a LocalCluster of 2 worker processes.

One tiny two-speaker corpus (``coartic corpus synth --speakers 2``, 2 consonants, 2 repetitions),
two channels, the pooled fit, and each speaker's /p/ posterior on LLO: 8 units. The serial run is the reference; the cluster run must give
the same files bit for bit, although one of its workers is killed in the middle of a unit.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import cloudpickle
import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.batch import load_batch_spec
from coartic.batch.layout import is_done, unit_dir
from coartic.batch.run import plan_units, run_batch
from coartic.batch.tasks import UnitKey
from coartic.cli import app
from coartic.errors import SpecError
from coartic.outputs import OutputError
from coartic.synthetic_cli import load_generator
from coartic.table import CHANNELS, ParameterTable

from conftest import without_overview

# The kill hook below runs on the workers: ship this module's functions by value.
cloudpickle.register_pickle_by_value(sys.modules[__name__])

FIT_SPEC = """name = "tiny"
[corpus]
manifest = "unused.csv"   # replaced by the batch's groups
[model]
channels = ["LLO", "JO"]
dominance = "centre"      # the paper's model, which the synthetic speakers are made with
handover = false
[parameters]
target_prior = "none"
free = ["target", "alpha", "theta_bw", "theta_fw"]
# k_R free for the consonants only: the vowels' k_R are not identified on JO by these trials
# (docs/MCMC.md), and left free there s01's JO fit wandered along them until it ran out of its
# evaluation budget (3431 evaluations, 18 CPU-s, two thirds of a whole batch's fitting; with them
# at their start value it converges in under a second, RMSE 0.142 mm against 0.140)
[[override]]
phonemes = ["p", "t"]
free = ["k_r"]
[staging]
enabled = false
[mcmc]                    # the posteriors of /p/ on LLO, short chains (the batch test is about scheduling)
phonemes = ["p"]
channels = ["LLO"]
plots = false
# one ensemble of 100 steps (3 of 200 before: 5 of a serial batch's 10 CPU-s, paid again by the
# cluster, failed-unit and Ctrl-C runs): what is tested is that each speaker's posterior is sampled,
# landed and reproduced bit for bit on the cluster, and that it sits around its own fit, apart from
# the other speaker's (/p/'s LLO target 0.8 against 1.2 times the truth's: -2.21 and -3.32 mm, 95 %
# intervals 0.07 and 0.12 mm wide with these chains)
ensembles = 1
chunk_steps = 100
min_steps = 100
max_steps = 100
"""
BATCH_SPEC = """name = "two speakers <script>alert(1)</script>"
fit = "fit.toml"
[corpus]
manifest = "corpus/manifest.csv"
group_by = ["speaker"]
[posteriors]
enabled = true
"""
TABLE_FILES = ("table.csv", "rmse.csv", "parameters.csv")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("batch")
    with without_overview() as gen:  # no test here looks at the speakers' overview figures
        gen.generate(root / "corpus", quick=True, progress=False, consonants=["p", "t"], speakers=2)
    (root / "fit.toml").write_text(FIT_SPEC)
    (root / "batch.toml").write_text(BATCH_SPEC)
    return root


@pytest.fixture(scope="module")
def serial(corpus: Path) -> Path:
    out = corpus / "serial"
    outcome = run_batch(load_batch_spec(corpus / "batch.toml"), out, serial=True, quiet=True)
    assert outcome.complete and len(outcome.landed) == 8
    return out


def kill_own_worker_once(key: UnitKey) -> None:
    """The first time unit s01 LLO starts, its worker process dies (as a lost node would). Before,
    every socket listening in the test's process tree (client, scheduler, nannies, workers) is
    written down, while the cluster runs."""
    marker = Path(os.environ["COARTIC_TEST_KILL_MARKER"])
    sockets = marker.with_name("listening.json")
    if not sockets.exists():
        import psutil

        top = psutil.Process(int(os.environ["COARTIC_TEST_CLIENT_PID"]))
        found = []
        for p in [top, *top.children(recursive=True)]:
            try:
                found += [[c.laddr.ip, c.laddr.port] for c in p.net_connections(kind="inet")
                          if c.status == psutil.CONN_LISTEN]
            except psutil.NoSuchProcess:  # the worker the other unit kills, gone while the tree was read
                continue
        sockets.write_text(json.dumps(found))
    if key == UnitKey("s01", "LLO") and not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)


@pytest.fixture(scope="module")
def cluster_run(corpus: Path) -> tuple[Path, Any, Path]:
    out = corpus / "cluster"
    marker = corpus / "killed.pid"
    os.environ["COARTIC_TEST_KILL_MARKER"] = str(marker)  # the nannies pass it on to the workers
    os.environ["COARTIC_TEST_CLIENT_PID"] = str(os.getpid())
    try:
        # no report: its page and figures are the serial run's (test_report_escapes_...), drawn from
        # the tables compared here; they were 1.5 of the cluster run's 20 CPU-s
        outcome = run_batch(load_batch_spec(corpus / "batch.toml"), out, workers=2, quiet=True,
                            before=kill_own_worker_once, report=False)
    finally:
        del os.environ["COARTIC_TEST_KILL_MARKER"], os.environ["COARTIC_TEST_CLIENT_PID"]
    return out, outcome, marker


# ----------------------------------------------------------------------------- synthetic speakers


def test_speakers_differ_in_target_scale_and_rate_and_record_their_truth(corpus: Path) -> None:
    c = corpus / "corpus"
    with open(c / "manifest.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert [r["speaker"] for r in rows].count("s01") == [r["speaker"] for r in rows].count("s02") == 24
    assert all((c / r["file"]).is_file() and r["file"].startswith(r["speaker"] + "/") for r in rows)
    record = json.loads((c / "speakers.json").read_text())["speakers"]
    base = ParameterTable.load(load_generator().GROUND_TRUTH)
    for name, sp in record.items():
        truth = ParameterTable.load(c / sp["ground_truth"])
        for ch in CHANNELS:
            rest = base.values["#"][ch]["target"]
            for ph in ("a", "p", "u"):
                want = rest + sp["target_scale"] * (base.values[ph][ch]["target"] - rest)
                assert truth.values[ph][ch]["target"] == pytest.approx(want, abs=1e-12)
                assert truth.values[ph][ch]["theta_bw"] == base.values[ph][ch]["theta_bw"]  # dynamics shared
    s1, s2 = record["s01"], record["s02"]
    assert {s1["target_scale"], s2["target_scale"]} == {0.8, 1.2}
    assert {s1["duration_scale"], s2["duration_scale"]} == {0.8, 1.25}

    def vcv_length(speaker: str) -> float:  # first vowel to second vowel, normal rate, every trial
        total = 0.0
        for r in rows:
            if r["speaker"] == speaker and r["rate"] == "normal":
                with np.load(c / r["truth"]) as z:
                    total += float(z["ends"][3] - z["starts"][1])
        return total

    ratio = vcv_length("s01") / vcv_length("s02")
    assert ratio == pytest.approx(s1["duration_scale"] / s2["duration_scale"], rel=0.06)
    # The same trial of two speakers is another recording, not a copy.
    a, b = (c / "s01/csv/apa_normal_01.csv").read_bytes(), (c / "s02/csv/apa_normal_01.csv").read_bytes()
    assert a != b


# ----------------------------------------------------------------------------- serial and cluster


def test_serial_batch_writes_what_coartic_fit_writes_for_each_speaker(corpus: Path, serial: Path) -> None:
    from coartic.jobs.fit import fit_job

    spec = load_batch_spec(corpus / "batch.toml")
    group = spec.groups[1]
    fit_job(group.spec, corpus / "fit-s02", quiet=True, report=False)
    for name in TABLE_FILES:
        assert (serial / "groups/s02" / name).read_bytes() == (corpus / "fit-s02" / name).read_bytes(), name
    table = ParameterTable.load(serial / "groups/s02/table.json")
    assert list(table.channels) == ["LLO", "JO"]


def test_cluster_gives_the_serial_tables_bit_for_bit(serial: Path, cluster_run: tuple[Path, Any, Path]) -> None:
    out, outcome, _ = cluster_run
    assert outcome.complete and outcome.workers == 2 and outcome.threads == max(1, (os.cpu_count() or 1) // 2)
    for where in ("groups/s01", "groups/s02", "pooled"):
        for name in TABLE_FILES:
            assert (out / where / name).read_bytes() == (serial / where / name).read_bytes(), f"{where}/{name}"
    assert (out / "rmse_groups.csv").read_bytes() == (serial / "rmse_groups.csv").read_bytes()
    for g in ("s01", "s02"):  # the posteriors too: same chains, same quantiles
        assert (out / f"groups/{g}/table_mcmc.csv").read_bytes() == (serial / f"groups/{g}/table_mcmc.csv").read_bytes()
    assert (out / "spread.csv").read_bytes() == (serial / "spread.csv").read_bytes()
    info = json.loads((unit_dir(out, UnitKey("s02", "JO")) / "unit.json").read_text())
    assert info["rayon_threads"] == str(outcome.threads) and info["pid"] != os.getpid()


def test_the_local_cluster_listens_on_loopback_only(cluster_run: tuple[Path, Any, Path]) -> None:
    """Scheduler, dashboard, nannies and workers: nothing reachable from another machine."""
    _, _, marker = cluster_run
    listening = json.loads(marker.with_name("listening.json").read_text())
    assert len(listening) >= 4, listening  # the scheduler, its HTTP server (dashboard), a nanny and a worker at least
    assert all(ip in ("127.0.0.1", "::1") for ip, _ in listening), listening


def test_a_killed_worker_loses_its_unit_and_the_unit_is_redone(cluster_run: tuple[Path, Any, Path]) -> None:
    out, outcome, marker = cluster_run
    killed = int(marker.read_text())  # the hook did kill a worker process
    info = json.loads((unit_dir(out, UnitKey("s01", "LLO")) / "unit.json").read_text())
    assert info["pid"] != killed and info["status"] == "converged"
    assert UnitKey("s01", "LLO") in outcome.landed and not outcome.failed


def test_a_rerun_skips_finished_units_and_redoes_only_missing_ones(corpus: Path, serial: Path) -> None:
    out = corpus / "rerun"
    shutil.copytree(serial, out)
    spec = load_batch_spec(corpus / "batch.toml")
    again = run_batch(spec, out, serial=True, quiet=True, report=False)
    assert again.skipped == 8 and again.landed == [] and again.complete
    shutil.rmtree(unit_dir(out, UnitKey("s02", "JO")))
    (unit_dir(out, UnitKey("s01", "JO")) / "unit.json").unlink()  # as if killed before its last file
    third = run_batch(spec, out, serial=True, quiet=True, report=False)
    assert sorted(k.label for k in third.landed) == ["s01 JO", "s02 JO"] and third.skipped == 6
    assert all(is_done(out, k) for k in plan_units(spec))
    for name in TABLE_FILES:
        assert (out / "groups/s02" / name).read_bytes() == (serial / "groups/s02" / name).read_bytes()


def test_a_failed_unit_is_reported_and_the_others_land(corpus: Path, tmp_path: Path) -> None:
    def fail_jo(key: UnitKey) -> None:
        if key.channel == "JO":
            raise RuntimeError("JO refused by the test")

    out = tmp_path / "failing"
    spec = load_batch_spec(corpus / "batch.toml")
    outcome = run_batch(spec, out, serial=True, quiet=True, before=fail_jo, report=False)
    assert sorted(outcome.failed) == ["pooled JO", "s01 JO", "s02 JO"]
    assert "JO refused by the test" in outcome.failed["s01 JO"]
    assert is_done(out, UnitKey("s01", "LLO")) and not (out / "groups/s01").exists()
    status = json.loads((out / "status.json").read_text())
    assert status["finished"] == 5 and "s01 JO" in status["missing"]  # 3 LLO fits, 2 LLO posteriors


def test_ctrl_c_keeps_every_finished_unit_and_the_rerun_completes(corpus: Path, serial: Path, tmp_path: Path) -> None:
    def ctrl_c_at_s02(key: UnitKey) -> None:
        if key.group == "s02":
            raise KeyboardInterrupt

    out = tmp_path / "interrupted"
    spec = load_batch_spec(corpus / "batch.toml")
    first = run_batch(spec, out, serial=True, quiet=True, before=ctrl_c_at_s02, report=False)
    assert first.interrupted and [k.label for k in first.landed] == ["s01 LLO", "s01 JO"]
    assert json.loads((out / "coartic_run.json").read_text())["status"] == "interrupted"
    assert (out / "groups/s01/table.csv").read_bytes() == (serial / "groups/s01/table.csv").read_bytes()
    second = run_batch(spec, out, serial=True, quiet=True, report=False)
    assert not (out / "report.html").exists() and (out / "rmse_groups.csv").is_file()
    assert second.complete and second.skipped == 2 and len(second.landed) == 6
    for name in TABLE_FILES:
        assert (out / "groups/s02" / name).read_bytes() == (serial / "groups/s02" / name).read_bytes()


# ----------------------------------------------------------------------------- report, CLI, errors


def test_each_speaker_gets_posteriors_around_its_own_fit(serial: Path) -> None:
    for g in ("s01", "s02"):
        fitted = ParameterTable.load(serial / f"groups/{g}/table.json")
        with_q = ParameterTable.load(serial / f"groups/{g}/table_mcmc.json")
        assert with_q.values == fitted.values  # the least-squares values, with the posterior beside them
        q = with_q.uncertainty["p"]["LLO"]["target"]
        assert q["q2.5"] < fitted.values["p"]["LLO"]["target"] < q["q97.5"]
        assert set(with_q.uncertainty) == {"p"} and set(with_q.uncertainty["p"]) == {"LLO"}
        index = json.loads((serial / f"posteriors/{g}/LLO/posteriors.json").read_text())
        assert [r["label"] for r in index] == ["LLO /p/"]
        import arviz as az  # the same InferenceData as coartic mcmc writes (coartic.mcmc.job.sample_table)

        idata = az.from_netcdf(serial / f"posteriors/{g}/LLO" / index[0]["directory"] / "posterior.nc")
        assert str(idata.posterior["channel"].values) == "LLO" and set(idata.posterior["phoneme"].values) == {"p", ""}
    # s01 speaks with targets 0.8x the truth, s02 1.2x: the /p/ closures (LLO < 0) differ beyond the intervals.
    q1 = ParameterTable.load(serial / "groups/s01/table_mcmc.json").uncertainty["p"]["LLO"]["target"]
    q2 = ParameterTable.load(serial / "groups/s02/table_mcmc.json").uncertainty["p"]["LLO"]["target"]
    assert q2["q97.5"] < q1["q2.5"]


def test_report_escapes_what_comes_from_the_spec_and_shows_every_group(serial: Path) -> None:
    html = (serial / "report.html").read_text(encoding="utf-8")
    assert "<script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "groups/s01/table.json" in html and "pooled/table.json" in html
    assert "Posteriors (coartic.mcmc)" in html and "converged" in html
    for fig in ("rmse.png", "spread_LLO.png", "spread_JO.png"):
        assert (serial / "figures" / fig).stat().st_size > 1000
    with open(serial / "rmse_groups.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["group"], r["channel"]) for r in rows] == [
        ("s01", "LLO"), ("s01", "JO"), ("s02", "LLO"), ("s02", "JO"), ("pooled", "LLO"), ("pooled", "JO")]
    # Speakers whose targets differ by a factor 1.5 are fitted to the noise; so is the pooled fit,
    # whose shared dynamics take each speaker's targets as offset + scale ([model] speakers =
    # "offset_scale" by group; one set of targets for both gave 0.93 mm on LLO).
    by = {(r["group"], r["channel"]): float(r["rmse_mm"]) for r in rows}
    worst = max(by[(g, ch)] for g in ("s01", "s02") for ch in ("LLO", "JO"))
    assert worst < 0.25 and by[("pooled", "LLO")] < 0.25 and by[("pooled", "JO")] < 0.25
    pooled = json.loads((serial / "pooled" / "table.json").read_text(encoding="utf-8"))["metadata"]["speakers"]
    assert pooled["mode"] == "offset_scale" and pooled["column"] == "group"
    assert pooled["coefficients"]["LLO"]["s01"] == {"offset_mm": 0.0, "scale": 1.0}
    assert pooled["coefficients"]["LLO"]["s02"]["scale"] == pytest.approx(1.5, abs=0.05)


def test_cli_refuses_another_batchs_folder_and_names_bad_keys(corpus: Path, serial: Path, tmp_path: Path) -> None:
    other = tmp_path / "other.toml"
    other.write_text(BATCH_SPEC.replace('group_by = ["speaker"]', 'group_by = ["speaker", "rate"]')
                     .replace('"fit.toml"', f'"{corpus / "fit.toml"}"')
                     .replace('"corpus/manifest.csv"', f'"{corpus / "corpus/manifest.csv"}"'))
    with pytest.raises(OutputError, match="holds coartic batch spec .*batch.toml"):
        run_batch(load_batch_spec(other), serial, serial=True, quiet=True)
    res = CliRunner().invoke(app, ["batch", str(other), "--out", str(serial), "--serial"])
    assert res.exit_code == 2 and "--force" in res.output
    bad = tmp_path / "bad.toml"
    bad.write_text(BATCH_SPEC.replace("speaker", "talker").replace('"fit.toml"', f'"{corpus / "fit.toml"}"')
                   .replace('"corpus/manifest.csv"', f'"{corpus / "corpus/manifest.csv"}"'))
    with pytest.raises(SpecError, match=r"bad.toml: \[corpus.group_by\] 'talker' is not a column"):
        load_batch_spec(bad)
    bad.write_text('fit = "fit.toml"\n[corpus]\nfolders = ["nowhere/*"]\n')
    with pytest.raises(SpecError, match=r"\[fit\] .*no such fit spec"):
        load_batch_spec(bad)
    res = CliRunner().invoke(app, ["batch", str(corpus / "batch.toml"), "--out", str(tmp_path / "o"),
                                   "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"])
    assert res.exit_code == 2 and "--workers" in res.output


def test_folders_name_the_groups(corpus: Path) -> None:
    spec_path = corpus / "folders.toml"
    spec_path.write_text('fit = "fit.toml"\n[corpus]\nfolders = ["corpus/s*"]\n[pooled]\nenabled = false\n')
    spec = load_batch_spec(spec_path)
    assert spec.group_names == ("s01", "s02") and not spec.pooled
    assert [str(k.label) for k in plan_units(spec)] == ["s01 LLO", "s01 JO", "s02 LLO", "s02 JO"]  # no posteriors
    by_column = load_batch_spec(corpus / "batch.toml")
    assert spec.groups[0].spec.corpus.manifest == corpus / "corpus/s01/manifest.csv"
    assert by_column.groups[0].spec.corpus.select == {"speaker": ("s01",)}


def test_a_manifest_or_fit_spec_that_is_a_directory_is_named_as_such(tmp_path: Path) -> None:
    # issue 21: a manifest that is a directory "does not exist"
    (tmp_path / "fit.toml").write_text('[corpus]\nmanifest = "m.csv"\n')
    (tmp_path / "session").mkdir()
    b = tmp_path / "batch.toml"
    b.write_text('fit = "fit.toml"\n[corpus]\nmanifest = "session"\ngroup_by = ["speaker"]\n')
    with pytest.raises(SpecError, match=r"\[corpus.manifest\] .*session is a directory: name the manifest file") as e:
        load_batch_spec(b)
    assert (e.value.file, e.value.key, e.value.section) == (b, "corpus.manifest", "corpus")
    b.write_text('fit = "session"\n[corpus]\nmanifest = "m.csv"\ngroup_by = ["speaker"]\n')
    with pytest.raises(SpecError, match=r"\[fit\] .*session: is a directory, not a fit spec"):
        load_batch_spec(b)
