"""coartic.Coarticulation: the estimator over the one fit layer (coartic.fit.run) and the scorer."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from coartic import Coarticulation
from coartic.estimator import NotFittedError
from coartic.fit import run
from coartic.fit.simulate import vcv_utterances
from coartic.errors import SpecError

from fit_helpers import PAPER_TOML

FREE = ["target", "alpha", "theta_bw", "theta_fw", "k_r"]
# the paper's model, which the synthetic trials are made with (fit_helpers.PAPER)
PAPER_KW: dict = {"dominance": "centre", "handover": False, "spec": {"model": {"pauses": "one"}, "parameters": {"target_prior": "none"}}}  # type: ignore[type-arg]


@pytest.fixture(scope="module")
def trials() -> list:  # type: ignore[type-arg]
    return vcv_utterances(np.random.default_rng(3), repetitions=2, consonants=("p", "t"))


@pytest.fixture(scope="module")
def fitted(trials: list) -> Coarticulation:  # type: ignore[type-arg]
    return Coarticulation(channels=["LLO"], staging=False, free=FREE, **PAPER_KW).fit(trials[::2])


def test_fit_is_coartic_fit_run_bit_for_bit(fitted: Coarticulation, trials: list) -> None:  # type: ignore[type-arg]
    direct = run(fitted.spec, utterances=trials[::2], quiet=True)
    assert fitted.table_ is not None and fitted.table_.values == direct.table().values
    assert fitted.spec.variant == "modified" and fitted.spec.free == tuple(FREE) and not fitted.spec.staging


def test_predict_is_the_table_evaluated_and_score_its_rmse(fitted: Coarticulation, trials: list) -> None:  # type: ignore[type-arg]
    from coartic.model import evaluate_corpus
    from coartic.model import utterances_for_table

    held = trials[1::2]
    pred = fitted.predict(held)
    assert len(pred) == len(held)
    assert fitted.table_ is not None
    # the labels as the table reads them: the pause postures it records (a final pause is #end)
    for p, want in zip(pred, evaluate_corpus(fitted.table_, "LLO", utterances_for_table(fitted.table_, held))):
        np.testing.assert_array_equal(p["LLO"], want)
    resid = np.concatenate([p["LLO"] - u.observed["LLO"] for p, u in zip(pred, held)])
    assert fitted.score(held) == pytest.approx(float(np.sqrt(np.mean(resid ** 2))), rel=1e-12)
    assert fitted.score(held) == fitted.score(held, channel="LLO")
    assert 0.08 < fitted.score(held) < 0.12  # the simulated noise is 0.1 mm
    assert fitted.score_report(held).channel_rows()[0]["samples"] == resid.size


def test_results_convert_to_dataframes(fitted: Coarticulation) -> None:
    assert fitted.result_ is not None and fitted.table_ is not None
    df = fitted.result_.to_dataframe()
    assert {"channel", "phoneme", "parameter", "value", "stderr", "free", "lower", "upper"} <= set(df.columns)
    assert all(pd.api.types.is_float_dtype(df[c]) for c in ("value", "stderr", "lower", "upper", "prior_mean"))
    fixed = df[(df.phoneme == "p") & (df.parameter == "psi")].iloc[0]
    assert not fixed["free"] and np.isnan(fixed["stderr"])  # not estimated: no standard error, NaN not ""
    kr = df[(df.phoneme == "p") & (df.parameter == "k_r")].iloc[0]
    assert kr["value"] == fitted.table_.values["p"]["LLO"]["k_r"] and kr["stderr"] >= 0
    rmse = fitted.result_.to_dataframe("rmse")
    assert rmse.iloc[0]["group"] == "all" and pd.api.types.is_float_dtype(rmse["rmse_mm"])
    with pytest.raises(ValueError, match="expected 'parameters' or 'rmse'"):
        fitted.result_.to_dataframe("tables")


def test_mistakes_are_named(trials: list) -> None:  # type: ignore[type-arg]
    with pytest.raises(SpecError, match=r"<Coarticulation settings>: \[model.variant\] 'modifed'"):
        Coarticulation(variant="modifed")
    with pytest.raises(SpecError, match=r"\[model\] unknown key\(s\) \['dominanse'\]"):
        Coarticulation(dominanse="segment")
    with pytest.raises(SpecError, match=r"\[parameters.free\].*'kr'"):
        Coarticulation(free=["kr"])
    with pytest.raises(NotFittedError, match="call fit"):
        Coarticulation().predict(trials)
    with pytest.raises(TypeError, match="got ndarray"):
        Coarticulation().fit([np.zeros(3)])  # type: ignore[list-item]
    assert "not fitted" in repr(Coarticulation())


@pytest.mark.slow
def test_trials_from_a_manifest_and_a_spec_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """fit(manifest path) reads the recordings as a fit spec's [corpus] does; from_spec takes a file."""
    from coartic.synthetic_cli import load_generator

    manifest = load_generator().generate(tmp_path / "session", quick=True, progress=False, consonants=["p"])
    model = Coarticulation(channels=["LLO"], staging=False, free=FREE, **PAPER_KW).fit(manifest)
    assert model.result_ is not None and model.result_.channels["LLO"].rmse < 0.3
    assert model.score(manifest) == pytest.approx(model.result_.channels["LLO"].rmse, rel=1e-9)
    spec = tmp_path / "spec.toml"
    spec.write_text(f'[corpus]\nmanifest = "{manifest}"\n[model]\nchannels = ["LLO"]\n{PAPER_TOML[0]}[parameters]\n'
                    f'{PAPER_TOML[1]}free = {FREE!r}\n[staging]\nenabled = false\n'.replace("'", '"'))
    again = Coarticulation.from_spec(spec).fit(None)
    assert again.table_ is not None and model.table_ is not None and again.table_.values == model.table_.values
