"""coartic.model: segment lists and a table in, trajectories (and Jacobians) out."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp  # type: ignore[import-untyped]

import numpy_model as nm
from coartic import _core
from coartic.jacobian import trajectory_jacobians
from coartic.model import (
    ModelInputError,
    Utterance,
    build_corpus,
    evaluate_corpus,
    jacobian_columns,
    segment_weights,
    trajectories,
)
from coartic.table import ParameterTable

LABELS = ["#", "a", "p", "a", "#"]
STARTS = np.array([0.0, 0.15, 0.29, 0.39, 0.55])
ENDS = np.array([0.15, 0.29, 0.39, 0.55, 0.7])
TIMES = np.arange(70) / 100.0


def test_trajectories_match_the_reference(illustrative_table: ParameterTable) -> None:
    out = trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES)
    assert list(out) == ["LLO"] and out["LLO"].shape == (70,)
    phonemes = illustrative_table.phonemes_for("LLO")
    params, beta = illustrative_table.to_matrix("LLO")
    rows = [phonemes.index(lab) for lab in LABELS]
    want = nm.evaluate_utterance(params, rows, STARTS, ENDS, TIMES, beta, "modified")
    np.testing.assert_allclose(out["LLO"], want, rtol=1e-12, atol=1e-12)
    # /p/ has k_R = 1 and σ = 0: its target is reached at its target time.
    t_p = trajectories(illustrative_table, LABELS, STARTS, ENDS, [0.34])["LLO"][0]
    assert t_p == pytest.approx(illustrative_table.values["p"]["LLO"]["target"], abs=1e-12)


def test_trajectories_with_jacobian(illustrative_table: ParameterTable) -> None:
    out = trajectory_jacobians(illustrative_table, LABELS, STARTS, ENDS, TIMES, channels=["LLO"])
    values, jac = out["LLO"]
    np.testing.assert_array_equal(values, trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES)["LLO"])
    phonemes = illustrative_table.phonemes_for("LLO")
    assert isinstance(jac, sp.csr_matrix) and jac.shape == (70, 10 * len(phonemes) + 1)
    cols = jacobian_columns(phonemes)
    assert len(cols) == jac.shape[1] and cols[-1] == "beta" and cols[10 * phonemes.index("p")] == "p.target"
    # ∂F/∂T of a phoneme that is not in the utterance is zero.
    assert not jac[:, cols.index("f.target")].toarray().any()


def test_segment_weights_are_the_normalised_dominance(illustrative_table: ParameterTable) -> None:
    table = illustrative_table
    table.values["a"]["LLO"]["sigma"] = 0.0
    w = segment_weights(table, "LLO", LABELS, STARTS, ENDS, TIMES)
    assert w.shape == (5, 70)
    np.testing.assert_allclose(w.sum(axis=0), 1.0, atol=1e-12)
    targets = np.array([table.values[lab]["LLO"]["target"] for lab in LABELS])
    np.testing.assert_allclose(targets @ w, trajectories(table, LABELS, STARTS, ENDS, TIMES)["LLO"], atol=1e-12)


def test_evaluate_corpus_splits_per_utterance(illustrative_table: ParameterTable) -> None:
    utts = [
        Utterance(LABELS, STARTS, ENDS, TIMES, name="apa"),
        Utterance(["#", "a", "f", "a", "#"], STARTS, ENDS, TIMES[:30], name="afa"),
    ]
    out = evaluate_corpus(illustrative_table, "LLO", utts)
    assert [len(o) for o in out] == [70, 30]
    np.testing.assert_array_equal(out[0], trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES)["LLO"])


def test_build_corpus_layout() -> None:
    corpus = build_corpus(
        [Utterance(["a", "p"], [0.0, 0.1], [0.1, 0.2], [0.05, 0.15]), Utterance(["p"], [0.0], [0.3], [0.1])],
        ["p", "a"],
    )
    assert isinstance(corpus, _core.Corpus)
    assert (corpus.n_utterances, corpus.n_segments, corpus.n_samples, corpus.n_phonemes) == (2, 3, 3, 2)


@pytest.mark.parametrize(
    ("labels", "starts", "ends", "times", "pattern"),
    [
        (["a", "x"], [0.0, 0.1], [0.1, 0.2], [0.1], r"utterance 'u7': label 'x' \(segment 2\) is not a phoneme of the table"),
        (["a", "p"], [0.0, 0.05], [0.1, 0.2], [0.1], r"utterance 'u7': segment 2 'p' starts at 0.05 s, before segment 1 'a' ends at 0.1 s"),
        (["a", "p"], [0.0, 0.1], [0.1, 0.1], [0.1], r"utterance 'u7': segment 2 'p' ends at 0.1 s, not after its start 0.1 s"),
        (["a", "p"], [0.0, 0.1], [0.1], [0.1], r"utterance 'u7': 2 labels, 2 starts and 1 ends"),
        (["a"], [0.0], [0.1], [0.1, np.nan], r"utterance 'u7': times\[1\] = nan is not finite"),
        (["a"], [0.0], [0.1], [[0.1]], r"utterance 'u7': times must be one-dimensional"),
        ([], [], [], [0.1], r"utterance 'u7': no segments"),
    ],
)
def test_build_corpus_errors_name_utterance_and_label(labels: list[str], starts: list[float], ends: list[float],
                                                      times: list[float], pattern: str) -> None:
    with pytest.raises(ModelInputError, match=pattern):
        build_corpus([Utterance(labels, starts, ends, times, name="u7")], ["a", "p"])


def test_trajectories_errors(illustrative_table: ParameterTable) -> None:
    with pytest.raises(ModelInputError, match=r"label 'o' \(segment 3\) is not a phoneme of <table> \(known: # a p f t\)"):
        trajectories(illustrative_table, ["#", "a", "o", "a", "#"], STARTS, ENDS, TIMES)
    with pytest.raises(ValueError, match=r"channel 'JO' is not in the table"):
        trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES, channels=["JO"])
    # A value the table accepts but the core rejects is named by phoneme, not by row index.
    illustrative_table.bounds = {"LLO": {"c_bw": (-1.0, 3.0)}}
    illustrative_table.values["p"]["LLO"]["c_bw"] = -0.5
    with pytest.raises(ModelInputError, match=r"channel 'LLO': phoneme 'p', parameter c_bw"):
        trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES)
    with pytest.raises(ModelInputError) as e:
        trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES, channels=["LLO"])
    # The phoneme by name, from the core error's attributes (not re-parsed from its message).
    assert str(e.value) == "channel 'LLO': phoneme 'p', parameter c_bw: value -0.5 is outside its domain > 0"
    assert (e.value.channel, e.value.phoneme, e.value.parameter, e.value.value) == ("LLO", "p", "c_bw", -0.5)
    assert e.value.reason == "is outside its domain > 0" and e.value.utterance is None


def test_build_corpus_errors_carry_the_place(illustrative_table: ParameterTable) -> None:
    from coartic.errors import CoarticError

    with pytest.raises(CoarticError) as e:
        build_corpus([Utterance(["a"], [0.0], [0.1], [0.0]),
                      Utterance(["a", "p"], [0.0, 0.05], [0.1, 0.2], [0.1])], ["a", "p"])
    assert str(e.value).startswith("utterance 2: segment 2 'p' starts at 0.05 s, before segment 1 'a' ends")
    assert isinstance(e.value, ValueError)
    assert (e.value.utterance, e.value.segment, e.value.phoneme, e.value.value) == (1, 1, "p", 0.05)


def test_rate_aware_options_go_from_spec_to_table_to_core(illustrative_table: ParameterTable, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """docs/MODEL.md §2.1: [model] dominance / plateau_fraction / handover are the fit's options, the
    table records them (JSON and CSV, only when not the defaults) and evaluates with them."""
    from pathlib import Path

    from coartic.errors import SpecError
    from coartic.fit.spec import parse_spec

    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"], "dominance": "plateau",
                                                               "plateau_fraction": 0.4, "handover": True}}
    spec = parse_spec(raw, Path("/tmp/s.toml"))
    cs = spec.channel_settings("LLO")
    assert (cs.dominance, cs.plateau_fraction, cs.handover) == ("plateau", 0.4, True)
    for bad, key in (({"dominance": "segment"}, "model.dominance"), ({"plateau_fraction": 2.0}, "model.plateau_fraction"),
                     ({"handover": "yes"}, "model.handover")):
        with pytest.raises(SpecError, match=rf"\[{key}\]"):
            parse_spec({**raw, "model": {"channels": ["LLO"], **bad}}, Path("/tmp/s.toml"))

    plain_json = illustrative_table.to_json_dict()
    assert "dominance" not in plain_json["channels"]["LLO"]  # today's tables are written as before
    before = trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES)["LLO"]
    settings = illustrative_table.channels["LLO"]
    settings.dominance, settings.plateau_fraction, settings.handover = cs.dominance, cs.plateau_fraction, cs.handover
    out = trajectories(illustrative_table, LABELS, STARTS, ENDS, TIMES)["LLO"]
    phonemes = illustrative_table.phonemes_for("LLO")
    params, beta = illustrative_table.to_matrix("LLO")
    rows = [phonemes.index(lab) for lab in LABELS]
    want = nm.evaluate_utterance(params, rows, STARTS, ENDS, TIMES, beta, "modified", dominance="plateau",
                                 plateau_fraction=0.4, handover=True)
    np.testing.assert_allclose(out, want, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(out - before)) > 1e-3
    for name in ("t.json", "t.csv"):
        illustrative_table.save(tmp_path / name)
        back = ParameterTable.load(tmp_path / name)
        b = back.channels["LLO"]
        assert (b.dominance, b.plateau_fraction, b.handover) == ("plateau", 0.4, True), name
        assert np.array_equal(trajectories(back, LABELS, STARTS, ENDS, TIMES)["LLO"], out), name
