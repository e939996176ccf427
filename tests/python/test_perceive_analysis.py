"""coartic perceive's analysis recovers effects planted in simulated answers (stored in a real SQLite
database through the server's own path), finds none where none was planted, excludes whom it says,
and writes an escaped HTML report; the export and analyse commands on a study directory."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.perceive.analysis import analyse
from coartic.perceive.report import write_report
from coartic.perceive.simulate import Plant, simulate
from coartic.perceive.storage import Store
from coartic.perceive.tidy import tidy_answers
from test_perceive_study import fake_manifest


def simulated(tmp_path: Path, manifest: dict[str, Any], n: int, plant: Plant, seed: int = 1) -> tuple[Store, pd.DataFrame]:
    store = Store(f"sqlite:///{tmp_path / 'results.sqlite'}", manifest, "key", durable=False)
    simulate(store, n, plant, seed)
    return store, tidy_answers(manifest, store.answer_rows())


def test_a_planted_intelligibility_effect_is_recovered(tmp_path: Path) -> None:
    m = fake_manifest(conditions=2, items=6, snrs=(-6.0, 0.0))
    _, tidy = simulated(tmp_path, m, 30, Plant(effects={"c1": -1.0}, snr_slope=0.15))
    result = analyse(m, tidy)
    keyframe = result.effect("condition[c1]")
    assert keyframe.credible and abs(keyframe.estimate - (-1.0)) < 0.35
    snr = result.effect("snr_db[0.0]")  # 6 dB at 0.15 per dB
    assert snr.credible and abs(snr.estimate - 0.9) < 0.35
    assert 0.2 < result.variance["participant sd (logit)"] < 0.9
    # the confusion matrices count every stimulus answer once, by phoneme and by viseme
    data = tidy[(tidy["kind"] == "stimulus") & ~tidy["participant"].isin(list(result.excluded))]
    for cond in ("c0", "c1"):
        n = int((data["condition"] == cond).sum())
        assert int(result.confusions[cond].to_numpy().sum()) == n
        assert int(result.confusions[f"{cond}, by viseme"].to_numpy().sum()) == n
    cells = result.cells.set_index(["condition", "snr_db"])
    assert cells.loc[("c1", -6.0), "mean"] < cells.loc[("c0", -6.0), "mean"]
    assert (cells["low"] <= cells["mean"]).all() and (cells["mean"] <= cells["high"]).all()


def test_the_fast_glmm_fits_as_statsmodels_bit_for_bit() -> None:
    """coartic.perceive.vb's model forms the random-effect sums without scipy.sparse, in the same
    order: from one start, with a warm start too, the same fit as BinomialBayesMixedGLM to the last
    bit (on 240 answers of 12 participants x 5 items, as the analysis lays them out)."""
    import numpy as np
    from scipy import sparse
    from statsmodels.genmod.bayes_mixed_glm import BinomialBayesMixedGLM

    from coartic.perceive.vb import InterceptsBinomialGLMM

    rng = np.random.default_rng(5)
    person, item = np.repeat(np.arange(12), 20), np.tile(np.arange(5), 48)
    x = np.column_stack([np.ones(240), rng.integers(0, 2, 240)]).astype(float)
    y = (rng.random(240) < 1 / (1 + np.exp(-(0.5 - x[:, 1] + 0.5 * rng.normal(size=12)[person])))).astype(float)
    exog_vc = sparse.hstack([sparse.csr_matrix((np.ones(240), (np.arange(240), c)), shape=(240, c.max() + 1))
                             for c in (person, item)]).tocsr()
    ident = np.array([0] * 12 + [1] * 5)
    start = np.zeros(2 + 2 + 17), np.full(2 + 2 + 17, np.exp(-0.5))
    fits = []
    for cls in (BinomialBayesMixedGLM, InterceptsBinomialGLMM):
        model = cls(y, x, exog_vc, ident)
        first = model.fit_vb(mean=start[0], sd=start[1])
        again = model.fit_vb(mean=first.params, sd=1.5 * np.sqrt(first.cov_params()))
        fits.append([first.params, first.cov_params(), again.params, again.cov_params()])
    assert fits[0][0][1] < -0.3  # a real fit: the planted effect is found
    for ours, theirs in zip(fits[1], fits[0]):
        assert np.array_equal(ours, theirs)
    with pytest.raises(ValueError, match="one indicator column"):
        InterceptsBinomialGLMM(y, x, 2 * exog_vc, ident)


@pytest.mark.slow
def test_intervals_are_calibrated_over_simulated_studies(tmp_path: Path) -> None:
    """Six studies of 16 simulated participants, with and without a planted effect: a 95 % interval
    excludes a planted -1.0 every time, and 0 where nothing was planted at most once (calibrated
    intervals do so 5 % of the time: twice or more in six has probability 3 %)."""
    m = fake_manifest(conditions=2, items=6, snrs=(-6.0, 0.0), attention_every=0)
    planted, null = [], []
    for seed in range(6):
        for effect, found in ((-1.0, planted), (0.0, null)):
            where = tmp_path / f"{seed}_{effect}"
            where.mkdir()
            _, tidy = simulated(where, m, 16, Plant(effects={"c1": effect}), seed=seed)
            found.append(analyse(m, tidy).effect("condition[c1]"))
    assert all(e.credible and e.high < -0.2 for e in planted)
    assert abs(sum(e.estimate for e in planted) / 6 - (-1.0)) < 0.2
    assert sum(e.credible for e in null) <= 1
    assert abs(sum(e.estimate for e in null) / 6) < 0.2


def test_planted_preferences_are_recovered(tmp_path: Path) -> None:
    m = fake_manifest(design="preference", conditions=3, items=6, snrs=(None,))
    _, tidy = simulated(tmp_path, m, 30, Plant(effects={"c1": 0.8, "c2": -0.5}))
    result = analyse(m, tidy)
    assert abs(result.effect("strength[c1]").estimate - 0.8) < 0.3 and result.effect("strength[c1]").credible
    assert abs(result.effect("strength[c2]").estimate + 0.5) < 0.3 and result.effect("strength[c2]").credible
    assert not result.effect("shown first (position)").credible  # none planted


def test_planted_mushra_ratings_are_recovered_and_reference_post_screening_excludes(tmp_path: Path) -> None:
    m = fake_manifest(design="mushra", conditions=3, items=6, snrs=(None,), attention_every=0)
    store, _ = simulated(tmp_path, m, 20, Plant(effects={"c2": -15.0}))
    # one participant who cannot tell the reference: rates everything 50
    p = store.start()
    for k, t in enumerate(p.trials):
        store.record(p, k, {c: 50 for c in t["conditions"]})
    result = analyse(m, tidy_answers(m, store.answer_rows()))
    assert list(result.excluded) == ["P0021"] and "hidden reference" in result.excluded["P0021"]
    e = result.effect("condition[c2]")  # against c1, the first condition that is not the reference
    assert abs(e.estimate - (-15.0)) < 3.0 and e.credible


def test_attention_failures_exclude_and_typed_answers_count_words(tmp_path: Path) -> None:
    m = fake_manifest(conditions=2, items=4, snrs=(0.0,), attention_every=2)
    m["response"] = "text"
    m["items"] = [{"index": i, "text": t, "answer": t} for i, t in enumerate(["la casa bianca", "un gatto nero",
                                                                              "il mare blu", "una strada lunga"])]
    store, _ = simulated(tmp_path, m, 12, Plant(attention_pass=1.0, effects={"c1": -1.0}))
    careless = store.start()
    for k, t in enumerate(careless.trials):
        store.record(careless, k, "none of these" if t["kind"] == "attention" else "x")
    tidy = tidy_answers(m, store.answer_rows())
    result = analyse(m, tidy)
    assert list(result.excluded) == ["P0013"]
    typed = tidy[(tidy["kind"] == "stimulus") & (tidy["participant"] != "P0013")]
    assert set(typed["correct"].round(6)) <= {0.0, round(1 / 3, 6), round(2 / 3, 6), 1.0}
    # each typed answer weighs as its three words
    assert result.effect("condition[c1]").estimate < 0


def test_the_report_is_escaped_and_complete(tmp_path: Path) -> None:
    m = fake_manifest(conditions=2, items=4, snrs=(0.0,))
    m["title"] = "<script>alert('x')</script> & co"
    _, tidy = simulated(tmp_path, m, 6, Plant(attention_pass=1.0))
    out = tmp_path / "report"
    out.mkdir()
    page = write_report(analyse(m, tidy), m, tidy, out, "coartic perceive analyse <dir>").read_text()
    assert "<script>alert" not in page and "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; co" in page
    assert "&lt;dir&gt;" in page
    for f in ("answers.csv", "summary.json", "cells.png", "effects.png", "confusion_1.png"):
        assert (out / f).is_file() and f in page or f.endswith(".png")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["participants"] == 6 and summary["simulated"] == 6
    csv = pd.read_csv(out / "answers.csv")
    assert len(csv) == len(tidy) and list(csv.columns[:4]) == ["study", "participant", "simulated", "trial"]


def test_export_and_analyse_commands(tmp_path: Path) -> None:
    m = fake_manifest(conditions=2, items=4, snrs=(0.0,))
    study = tmp_path / "study"
    study.mkdir()
    (study / "study.json").write_text(json.dumps(m))
    (study / "secret.key").write_text("k\n")
    runner = CliRunner()
    res = runner.invoke(app, ["perceive", "simulate", str(study), "-n", "8", "--effect", "c1=-2"])
    assert res.exit_code == 0, res.output
    csv = tmp_path / "answers.csv"
    assert runner.invoke(app, ["perceive", "export", str(study), "--out", str(csv)]).exit_code == 0
    rows = pd.read_csv(csv)
    assert rows["participant"].nunique() == 8 and (rows["simulated"] == 1).all()
    again = runner.invoke(app, ["perceive", "export", str(study), "--out", str(csv)])
    assert again.exit_code == 2 and "--force" in again.output
    res = runner.invoke(app, ["perceive", "analyse", str(study), "--out", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert "condition[c1]" in res.output and (tmp_path / "rep" / "report.html").is_file()
    bad = runner.invoke(app, ["perceive", "analyse", str(tmp_path), "--out", str(tmp_path / "rep2")])
    assert bad.exit_code == 2 and "not a prepared study" in bad.output
