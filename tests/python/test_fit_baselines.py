"""Baselines of every held-out figure (coartic.evaluation.baselines, issue 19 item 4): hand-computed values
on a tiny corpus, and the flag raised when a table does not beat the step model."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from coartic.evaluation.baselines import Baselines, beats_step, flag_text, warp_times
from coartic.evaluation.compare import Row
from coartic.evaluation.score import Score
from coartic.evaluation.heldout import SplitScore, flags, pooled
from coartic.model import Utterance
from coartic.table import ParameterTable

T = np.arange(30) / 100.0  # 0.00 .. 0.29 s


def utt(labels: list[str], starts: list[float], ends: list[float], y: np.ndarray, name: str,
        valid: np.ndarray | None = None) -> Utterance:
    v = np.ones(y.size, dtype=bool) if valid is None else valid
    return Utterance(labels, starts, ends, np.arange(y.size) / 100.0, name, {"LA": y.astype(float)}, {"LA": v},
                     {"file": name})


def train_apa() -> Utterance:
    # /a p a/: a = 10 mm (samples 0-9 and 20-29), p = 2 mm (10-19); sample 25 not measured (and 99 there)
    y = np.r_[np.full(10, 10.0), np.full(10, 2.0), np.full(10, 10.0)]
    y[25] = 99.0
    valid = np.ones(30, dtype=bool)
    valid[25] = False
    return utt(["a", "p", "a"], [0.0, 0.1, 0.2], [0.1, 0.2, 0.3], y, "apa", valid)


def test_constant_and_step_by_hand() -> None:
    b = Baselines.fit([train_apa()], ["LA"])
    assert b.constant["LA"] == pytest.approx((19 * 10.0 + 10 * 2.0) / 29)  # the invalid sample left out
    assert b.step["LA"] == pytest.approx({"a": 10.0, "p": 2.0})
    # a test utterance /a m a/ ending before its last sample: m unseen -> the constant, and so the sample
    # outside every segment
    test = utt(["a", "m", "a"], [0.0, 0.1, 0.2], [0.1, 0.2, 0.29], np.zeros(30), "ama")
    step = b.predict_one("step", test, "LA")
    assert step is not None
    np.testing.assert_allclose(step[:10], 10.0)
    np.testing.assert_allclose(step[10:20], b.constant["LA"])
    np.testing.assert_allclose(step[20:29], 10.0)
    assert step[29] == pytest.approx(b.constant["LA"])
    const = b.predict_one("constant", test, "LA")
    assert const is not None and np.all(const == b.constant["LA"])
    # no other token of /a m a/: no warped baseline
    assert b.predict_one("warped", test, "LA") is None
    assert set(b.predict([test], "LA")) == {"constant", "step"}


def test_warped_token_by_hand() -> None:
    # the training token: /a p a/ slower (0-0.2, 0.2-0.3, 0.3-0.6 s), measured = its own time in mm
    t_tok = np.arange(61) / 100.0
    token = Utterance(["a", "p", "a"], [0.0, 0.2, 0.3], [0.2, 0.3, 0.6], t_tok, "slow", {"LA": t_tok.copy()},
                      {"LA": np.ones(61, dtype=bool)}, {"file": "slow.csv"})
    test = utt(["a", "p", "a"], [0.0, 0.1, 0.2], [0.1, 0.2, 0.3], np.zeros(30), "fast")
    # knots: test 0 .05 .1 .15 .2 .25 .3  <->  token 0 .1 .2 .25 .3 .45 .6
    tau = warp_times(test, token)
    assert tau[5] == pytest.approx(0.10)  # the centre of the first a
    assert tau[10] == pytest.approx(0.20)  # the start of p
    assert tau[12] == pytest.approx(0.20 + 0.02 * (0.05 / 0.05))  # within p's first half: slope 1
    assert tau[22] == pytest.approx(0.30 + 0.02 * (0.15 / 0.05))  # within the last a's first half: slope 3
    b = Baselines.fit([token], ["LA"])
    warped = b.predict_one("warped", test, "LA")
    assert warped is not None
    np.testing.assert_allclose(warped, tau, atol=1e-12)  # the token's value (its time) at the mapped time
    # the same file is not "another token" of its sentence
    assert b.predict_one("warped", utt(["a", "p", "a"], [0.0, 0.2, 0.3], [0.2, 0.3, 0.6], t_tok, "slow.csv"),
                         "LA") is None
    # nor is it when named another way (a spec's "fit/../slow.csv", the command line's "slow.csv"): a
    # recording scored in sample was its own warped baseline, RMSE 0.000
    assert b.predict_one("warped", utt(["a", "p", "a"], [0.0, 0.2, 0.3], [0.2, 0.3, 0.6], t_tok, "fit/../slow.csv"),
                         "LA") is None
    # two tokens: the mean of their warped trajectories
    other = Utterance(["a", "p", "a"], [0.0, 0.2, 0.3], [0.2, 0.3, 0.6], t_tok, "slow2", {"LA": t_tok + 1.0},
                      {"LA": np.ones(61, dtype=bool)}, {"file": "slow2.csv"})
    both = Baselines.fit([token, other], ["LA"]).predict_one("warped", test, "LA")
    assert both is not None
    np.testing.assert_allclose(both, tau + 0.5, atol=1e-12)


def score_with(pred: float, measured: np.ndarray) -> Score:
    test = utt(["a", "p", "a"], [0.0, 0.1, 0.2], [0.1, 0.2, 0.3], measured, "test")
    sc = Score(ParameterTable(variant="modified", source="<t>"), ("LA",), [test], {"LA": [np.full(30, pred)]})
    sc.add_baselines([train_apa()])
    return sc


def test_score_reports_baselines_on_the_same_samples_and_flags() -> None:
    # measured exactly the step model: the step baseline is perfect, a constant table is not
    measured = np.r_[np.full(10, 10.0), np.full(10, 2.0), np.full(10, 10.0)]
    sc = score_with(7.0, measured)
    rows = {r["model"]: r for r in sc.baseline_rows()}
    assert set(rows) == {"table", "constant", "step", "warped"}  # /a p a/ is also the training sentence
    assert rows["step"]["rmse_mm"] == pytest.approx(0.0, abs=1e-12)
    assert rows["warped"]["rmse_mm"] == pytest.approx(0.0, abs=1e-12)  # same timing; its gap interpolated
    c = (19 * 10.0 + 20) / 29
    assert rows["constant"]["rmse_mm"] == pytest.approx(math.sqrt((20 * (10 - c) ** 2 + 10 * (2 - c) ** 2) / 30))
    assert rows["table"]["rmse_mm"] == pytest.approx(math.sqrt((20 * 9 + 10 * 25) / 30))
    assert all(r["samples"] == 30 for r in rows.values())
    assert len(sc.flags()) == 1 and sc.flags()[0].startswith("LA: the table does not beat the step model")
    assert sc.summary()["beats_step_model"] == {"LA": False}
    assert "WARNING: LA: the table does not beat the step model" in sc.text()
    # a table better than the step model is not flagged (measured: the step model + 1 mm on p only)
    measured2 = measured.copy()
    measured2[10:20] += 1.0
    sc2 = Score(sc.table, ("LA",), [utt(["a", "p", "a"], [0.0, 0.1, 0.2], [0.1, 0.2, 0.3], measured2, "t")],
                {"LA": [measured2 + 0.01]})
    sc2.add_baselines([train_apa()])
    assert sc2.flags() == [] and sc2.summary()["beats_step_model"] == {"LA": True}


def test_beats_step_needs_both_figures() -> None:
    assert beats_step((1.0, 0.5), (1.1, 0.6))
    assert not beats_step((1.0, 0.7), (1.1, 0.6))  # worse once the offset is removed
    assert not beats_step((1.2, 0.5), (1.1, 0.6))


def test_a_flag_says_when_the_table_wins_on_speech_alone() -> None:
    """A table that loses to the step model only through the pauses (real labels: a long final pause)
    is flagged, and the flag says that on speech alone it wins (issue 25: figures that say what they are)."""
    # (as measured, offset removed, calibrated, speech as measured, speech offset removed)
    step = {"step": (1.766, 1.527, 1.5, 1.826, 1.570)}
    pauses = SplitScore("time split", "JO", 1.3, 1.787, 100, ("", float("nan")), 1.645, baselines=step,
                        test_rmse_speech=1.776, test_rmse_speech_offset_removed=1.550, test_speech_samples=84)
    worse = SplitScore("time split", "JO", 1.3, 1.787, 100, ("", float("nan")), 1.645, baselines=step,
                       test_rmse_speech=1.900, test_rmse_speech_offset_removed=1.550, test_speech_samples=84)
    assert not pauses.beats_step and not worse.beats_step
    assert pauses.flag() == ("time split: JO: the table does not beat the step model (phoneme means, no "
                             "coarticulation): 1.787 vs 1.766 mm as measured, 1.645 vs 1.527 mm offset removed; on "
                             "speech alone (pauses left out) it does: 1.776 vs 1.826 mm as measured, 1.550 vs 1.570 "
                             "mm offset removed, so the pauses decide")
    assert worse.flag() is not None and "speech alone" not in worse.flag()  # it loses there too
    # the pooled line of several splits says the same from the pooled speech figures
    other = replace(pauses, split="LOO")
    assert flags([pauses, other])[-1].startswith("all splits pooled: JO: the table does not beat")
    assert flags([pauses, other])[-1].endswith("so the pauses decide")
    # another session: compared offset removed only, on speech too
    assert "speech alone" in flag_text("JO", (9.0, 1.645), (1.0, 1.527), "speaker s1em is not in the training data",
                                       ((9.0, 1.550), (1.0, 1.570)))


def test_validation_and_compare_flags() -> None:
    good = SplitScore("fold 1", "LA", 0.1, 1.0, 100, ("a", 1.0), 0.8, baselines={"step": (1.5, 1.2, 1.1)})
    bad = SplitScore("fold 2", "LA", 0.1, 2.0, 100, ("a", 2.0), 1.9, baselines={"step": (1.5, 1.2, 1.1)})
    assert good.beats_step and not bad.beats_step
    out = flags([good, bad])
    assert out[0].startswith("fold 2: LA: the table does not beat the step model")
    # pooled: table sqrt((1 + 4) / 2) = 1.58 against the step model's 1.5: flagged too
    assert pooled([good, bad], "step")["LA"][0] == pytest.approx(1.5)
    assert any(f.startswith("all splits pooled: LA") for f in out)
    assert flags([good]) == []
    row = Row("m", "LA", 3, 100, 1.0, 0.1, 2.0, 1.9, "converged", {"step": (1.5, 1.2)})
    assert not row.beats_step and row.as_dict()["beats_step_model"] is False
    assert row.as_dict()["heldout_step_rmse_mm"] == 1.5 and math.isnan(row.as_dict()["heldout_warped_rmse_mm"])


def test_fit_validate_writes_the_baselines_into_summary_report_and_csv(tmp_path: Path) -> None:
    from coartic.evaluation.heldout import held_out
    from coartic.fit.simulate import vcv_utterances
    from coartic.fit.spec import parse_spec
    from coartic.jobs.fit import fit_job

    utts = vcv_utterances(np.random.default_rng(2), repetitions=2, rates={"normal": 1.0}, noise=0.1)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target"]}, "staging": {"enabled": False}, "validate": {"holdout_repetition": 2}}
    res = fit_job(parse_spec(raw, tmp_path / "spec.toml"), tmp_path / "out", utterances=utts, validate=True, quiet=True, report=True)
    scores = held_out(res)
    assert scores and set(scores[0].baselines) == {"constant", "step", "warped"}
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    split = summary["validation"]["splits"][0]
    assert split["split"] == "repetition 2 held out" and {"table", "step", "constant", "warped"} <= set(split)
    assert split["beats_step_model"] is True and summary["validation"]["flags"] == []
    assert "[[Validation]]" in (tmp_path / "out" / "fit_report.txt").read_text()
    html = (tmp_path / "out" / "report.html").read_text()
    assert "beats the step model" in html and "Worse than the step model" not in html
    header = (tmp_path / "out" / "validation" / "validation.csv").read_text().splitlines()[0]
    assert {"warped_rmse_mm", "beats_step_model"} <= set(header.split(","))
    # a table worse than the step model: flagged in the report
    from coartic.report.html import write_report

    scores[0].test_rmse = 99.0
    write_report(res, tmp_path / "out")
    html = (tmp_path / "out" / "report.html").read_text()
    assert "Worse than the step model: repetition 2 held out: LLO: the table does not beat the step model" in html


def test_compare_reports_the_step_model_held_out(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import coartic.jobs.compare as job
    from coartic.fit.simulate import vcv_utterances
    from coartic.fit.spec import parse_spec

    utts = vcv_utterances(np.random.default_rng(2), repetitions=2, rates={"normal": 1.0}, noise=0.1)
    real_job = job.fit_job

    def fit_on_vcv(spec, out=None, **kw):  # type: ignore[no-untyped-def]
        kw.setdefault("utterances", utts)  # the specs' corpus: these utterances, not files
        return real_job(spec, out, **kw)

    monkeypatch.setattr(job, "fit_job", fit_on_vcv)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target"]}, "staging": {"enabled": False}, "validate": {"holdout_repetition": 2}}
    cmp = job.compare([parse_spec(raw, tmp_path / "spec.toml")], tmp_path / "out")
    row = cmp.rows[0]
    assert set(row.baselines) == {"constant", "step", "warped"} and row.beats_step
    assert row.heldout_rmse < row.baselines["step"][0] < row.baselines["constant"][0]
    header = (tmp_path / "out" / "compare.csv").read_text().splitlines()[0]
    assert "heldout_step_rmse_mm" in header and "beats_step_model" in header
    assert "step model (held out)" in (tmp_path / "out" / "compare.html").read_text()
    assert "step " in (tmp_path / "out" / "compare.txt").read_text()
