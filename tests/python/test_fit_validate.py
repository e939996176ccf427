"""Validation splits: held-out repetition and the other speaking rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic.fit.simulate import vcv_utterances
from coartic.fit.spec import SpecError, parse_spec
from coartic.fit.validate import splits, validate_all


def spec(tmp_path: Path, **validate: object):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target", "alpha", "theta_bw", "theta_fw", "k_r"]},
           "staging": {"enabled": False}, "validate": validate}
    return parse_spec(raw, tmp_path / "spec.toml")


def test_splits_and_scores(tmp_path: Path) -> None:
    utts = vcv_utterances(np.random.default_rng(2), repetitions=3, noise=0.1)
    s = spec(tmp_path, holdout_repetition=3)
    names = [(n, len(tr), len(te)) for n, tr, te in splits(s, utts)]
    assert names == [("repetition 3 held out", 24, 12), ("fit normal rate, test fast rate", 18, 18)]
    scores = validate_all(s, tmp_path / "val", utterances=utts)
    assert [sc.split for sc in scores] == ["repetition 3 held out", "fit normal rate, test fast rate"]
    for sc in scores:
        # the model made the data: held-out RMSE stays at the noise level
        assert sc.test_rmse < 0.15 and sc.train_rmse < 0.12 and sc.test_samples > 0
    assert (tmp_path / "val" / "validation.csv").read_text().count("\n") == 3


def test_nothing_to_hold_out(tmp_path: Path) -> None:
    utts = vcv_utterances(np.random.default_rng(2), repetitions=1, rates={"normal": 1.0})
    with pytest.raises(SpecError, match=r"\[validate\]"):
        splits(spec(tmp_path, holdout_repetition=5, train_rate="normal", test_rate="fast"), utts)
