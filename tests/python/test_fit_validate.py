"""Validation splits: held-out repetition and the other speaking rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic.fit.simulate import vcv_utterances
from coartic.errors import SpecError
from coartic.fit.spec import parse_spec
from coartic.jobs.fit import fit_job
from coartic.evaluation.validate import splits, validate_all

from fit_helpers import german_utterance_spec, paper


def spec(tmp_path: Path, **validate: object):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target", "alpha", "theta_bw", "theta_fw", "k_r"]},
           "staging": {"enabled": False}, "validate": validate}
    return parse_spec(paper(raw), tmp_path / "spec.toml")


def test_splits_and_scores(tmp_path: Path) -> None:
    utts = vcv_utterances(np.random.default_rng(2), repetitions=3, noise=0.1)
    s = spec(tmp_path, holdout_repetition=3)
    names = [(n, len(tr), len(te)) for n, tr, te in splits(s, utts)]
    assert names == [("repetition 3 held out", 24, 12), ("fit normal rate, test fast rate", 18, 18)]
    scores = validate_all(s, tmp_path / "val", utterances=utts, fit=fit_job)
    assert [sc.split for sc in scores] == ["repetition 3 held out", "fit normal rate, test fast rate"]
    for sc in scores:
        # the model made the data: held-out RMSE stays at the noise level
        assert sc.test_rmse < 0.15 and sc.train_rmse < 0.12 and sc.test_samples > 0
        # every baseline on the same samples (other repetitions / the other rate are tokens of each
        # sentence), all beaten by the model that made the data; the warped token beats the step model
        assert set(sc.baselines) == {"constant", "step", "warped"} and sc.beats_step
        assert sc.baselines["warped"][0] < sc.baselines["step"][0] < sc.baselines["constant"][0]
        assert sc.test_rmse < sc.baselines["warped"][0]
        assert sc.worst_vowel[0] in {"a", "i", "u"} and sc.worst_vowel[1] >= sc.test_rmse  # the worst VCV context
    text = (tmp_path / "val" / "validation.csv").read_text()
    assert text.count("\n") == 3 and "step_rmse_offset_removed_mm" in text.splitlines()[0]


def test_nothing_to_hold_out(tmp_path: Path) -> None:
    utts = vcv_utterances(np.random.default_rng(2), repetitions=1, rates={"normal": 1.0})
    with pytest.raises(SpecError, match=r"\[validate\]"):
        splits(spec(tmp_path, holdout_repetition=5, train_rate="normal", test_rate="fast"), utts)


def test_kfold_by_any_grouping_without_a_manifest(tmp_path: Path) -> None:
    utts = vcv_utterances(np.random.default_rng(2), repetitions=2, noise=0.1)  # 24 utterances
    # by utterance, 3 folds: every utterance held out exactly once
    s = spec(tmp_path, group="utterance", folds=3)
    sp = splits(s, utts)
    assert [n.split(" (")[0] for n, _, _ in sp] == ["fold 1/3", "fold 2/3", "fold 3/3"]
    held = [u.name for _, _, te in sp for u in te]
    assert sorted(held) == sorted(u.name for u in utts)
    assert all(len(tr) + len(te) == len(utts) and not set(map(id, tr)) & set(map(id, te)) for _, tr, te in sp)
    # by rate: one fold per rate (leave one rate out)
    sp = splits(spec(tmp_path, group="rate"), utts)
    assert [n for n, _, _ in sp] == ["fold 1/2 (rate fast held out)", "fold 2/2 (rate normal held out)"]
    assert {u.meta["rate"] for u in sp[0][2]} == {"fast"} and {u.meta["rate"] for u in sp[0][1]} == {"normal"}
    # a grouping the corpus does not have
    with pytest.raises(SpecError, match=r"\[validate.group\] 'speaker': the corpus has no 'speaker' column"):
        splits(spec(tmp_path, group="speaker"), utts)


def test_kfold_scores_pooled_with_and_without_offsets(tmp_path: Path) -> None:
    from coartic.evaluation.heldout import pooled

    utts = vcv_utterances(np.random.default_rng(4), repetitions=2, rates={"normal": 1.0}, noise=0.1)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target"]}, "validate": {"group": "repetition"}}
    s = parse_spec(raw, tmp_path / "spec.toml")
    scores = validate_all(s, tmp_path / "val", utterances=utts, fit=fit_job)
    assert len(scores) == 2 and all(np.isfinite(sc.test_rmse_offset_removed) for sc in scores)
    rm, ro, n = pooled(scores)["LLO"]
    assert n == sum(sc.test_samples for sc in scores) and ro <= rm + 1e-12
    text = (tmp_path / "val" / "validation.csv").read_text()
    assert "test_rmse_offset_removed_mm" in text and text.count("\n") == 3


@pytest.mark.parametrize("validate, key", [
    ({"group": "speakers"}, "validate.group"),
    ({"group": "utterance", "folds": 1}, "validate.folds"),
    ({"folds": 3}, "validate.folds"),
])
def test_kfold_spec_errors(tmp_path: Path, validate: dict[str, object], key: str) -> None:
    with pytest.raises(SpecError, match=rf"\[{key}\]"):
        spec(tmp_path, **validate)


def test_time_split_from_the_command_line_with_class_fallbacks(tmp_path: Path) -> None:
    """``coartic fit --validate-by time``: every utterance cut at its middle segment, each half
    fitted and the other held out; a held-out phoneme the half lacks is scored as its class's
    fallback (a note says which); one with no fallback the half has skips that fold, with a note."""
    from typer.testing import CliRunner

    from coartic.cli import app
    from coartic.evaluation.validate import halves

    utts = vcv_utterances(np.random.default_rng(2), repetitions=1, rates={"normal": 1.0})
    sp = splits(spec(tmp_path, group="time"), utts)
    assert [n for n, _, _ in sp] == ["time split: first halves fitted, second halves held out",
                                     "time split: second halves fitted, first halves held out"]
    first, second = halves(utts[0])
    assert first.labels + second.labels == utts[0].labels and first.times[-1] < second.starts[0] <= second.times[0]
    assert len(first.times) + len(second.times) == len(utts[0].times)
    assert [u.name for u in sp[0][1]] == [u.name for u in sp[1][2]]

    # German EMA 0024's LA with its targets alone free, no pooling, one stage: what is tested is the
    # split and what its halves' phonemes leave to the class fallbacks, which no model setting
    # changes; the default spec's pooled fits of the whole and both halves took 7.6 CPU-s here (now 0.4)
    # (its own fit is tested in test_fit_target_prior.py)
    s = german_utterance_spec(tmp_path / "s.toml", '[model]\nchannels = ["LA"]\n[parameters]\ntarget_prior = "none"\n'
                              'free = ["target"]\n[staging]\nenabled = false\n', utterance="0024")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["fit", str(s), "--starts", "1", "--no-report", "--quiet", "--out", str(out),
                                   "--validate-by", "time"])
    assert res.exit_code == 0, res.output
    text = (out / "validation" / "validation.csv").read_text()
    assert "\"time split: first halves fitted, second halves held out\",LA," in text
    # real speech has no vowel context: no "worst vowel" (it was "(?)", read as the glottal stop)
    import csv
    rows = list(csv.DictReader(text.splitlines()))
    assert rows and all(r["worst_vowel"] == "" for r in rows)
    flat = " ".join(res.output.split())
    assert "the table has no /E/ (scored as /e/)" in flat
    assert "second halves fitted, first halves held out: the test utterances contain phonemes the training " \
           "fit never saw, with no phonetic-class fallback it saw: ['v']; not scored" in flat
    res = CliRunner().invoke(app, ["fit", str(s), "--validate-by", "halves"])
    assert res.exit_code == 2 and "--validate-by 'halves': unknown split" in " ".join(res.output.split())
