"""coartic.Coarticulation: the estimator over the one fit layer (coartic.fit.run) and the scorer, taking
estimation's settings objects built in Python (coartic.estimation.settings)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from coartic import Coarticulation
from coartic.estimator import NotFittedError
from coartic.estimation.problem import build_problem
from coartic.estimation.settings import (EstimationSettings, GroupSettings, ModelSettings, Override,
                                         ParameterSettings, PriorSettings, Shrink, Tie)
from coartic.fit import run
from coartic.fit.spec import FitSpec, parse_spec
from coartic.fit.simulate import vcv_utterances
from coartic.errors import SpecError

from conftest import without_overview
from fit_helpers import PAPER_TOML

FREE = ("target", "alpha", "theta_bw", "theta_fw", "k_r")
# the paper's model, which the synthetic trials are made with (fit_helpers.PAPER)
PAPER = EstimationSettings(model=ModelSettings(dominance="centre", handover=False, pauses="one"),
                           parameters=ParameterSettings(free=FREE), priors=PriorSettings(target_prior=None, pooled=()))


@pytest.fixture(scope="module")
def trials() -> list:  # type: ignore[type-arg]
    return vcv_utterances(np.random.default_rng(3), repetitions=2, consonants=("p", "t"))


@pytest.fixture(scope="module")
def fitted(trials: list) -> Coarticulation:  # type: ignore[type-arg]
    return Coarticulation(PAPER, channels=["LLO"], staging={"enabled": False}).fit(trials[::2])


def test_fit_is_coartic_fit_run_bit_for_bit(fitted: Coarticulation, trials: list) -> None:  # type: ignore[type-arg]
    direct = run(fitted.spec, utterances=trials[::2], quiet=True)
    assert fitted.table_ is not None and fitted.table_.values == direct.table().values
    assert fitted.spec.model.variant == "modified" and fitted.spec.parameters.free == FREE and not fitted.spec.staging.enabled
    assert fitted.settings.parameters.free == FREE and fitted.settings.model.dominance == "centre"
    assert fitted.table_.metadata["corpus"] == "trials given in Python"


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
    # a setting built in Python checks itself, named by the spec file's key it would be written with
    with pytest.raises(SpecError, match=r"^\[model.variant\] 'modifed'"):
        Coarticulation(EstimationSettings(model=ModelSettings(variant="modifed")))
    with pytest.raises(SpecError, match=r"\[parameters.free\].*'kr'"):
        Coarticulation(EstimationSettings(parameters=ParameterSettings(free=("kr",))))
    with pytest.raises(SpecError, match=r"\[parameters.bounds.theta_bw\] low 5.0 must be below high 1.0"):
        Coarticulation(EstimationSettings(parameters=ParameterSettings(bounds={"theta_bw": (5.0, 1.0)})))
    with pytest.raises(SpecError, match=r"^\[tie.phonemes\] a tie needs two phonemes or more"):
        Coarticulation(EstimationSettings(parameters=ParameterSettings(ties=(Tie(("p",), ("theta_bw",)),))))
    with pytest.raises(SpecError, match=r"FitSpec has no field\(s\) \['dominanse'\]"):
        Coarticulation(dominanse="segment")
    with pytest.raises(SpecError, match=r"free: an estimation setting, given in the settings"):
        Coarticulation(free=["target"])
    with pytest.raises(SpecError, match=r"\[corpus\] no corpus to read"):
        Coarticulation().fit(None)
    with pytest.raises(TypeError, match="expected coartic.estimation.settings.EstimationSettings, got dict"):
        Coarticulation({"model": {}})  # type: ignore[arg-type]
    with pytest.raises(NotFittedError, match="call fit"):
        Coarticulation().predict(trials)
    with pytest.raises(TypeError, match="got ndarray"):
        Coarticulation().fit([np.zeros(3)])  # type: ignore[list-item]
    assert "not fitted" in repr(Coarticulation())


@pytest.mark.slow
def test_trials_from_a_manifest_and_a_spec_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """fit(manifest path) reads the recordings as a fit spec's [corpus] does; from_spec takes a file."""
    with without_overview() as gen:  # the trials are what is fitted; the session's figure is not used
        manifest = gen.generate(tmp_path / "session", quick=True, progress=False, consonants=["p"])
    model = Coarticulation(PAPER, channels=["LLO"], staging={"enabled": False}).fit(manifest)
    assert model.result_ is not None and model.result_.channels["LLO"].rmse < 0.3
    assert model.score(manifest) == pytest.approx(model.result_.channels["LLO"].rmse, rel=1e-9)
    spec = tmp_path / "spec.toml"
    spec.write_text(f'[corpus]\nmanifest = "{manifest}"\n[model]\nchannels = ["LLO"]\n{PAPER_TOML[0]}[parameters]\n'
                    f'{PAPER_TOML[1]}free = {list(FREE)!r}\n[staging]\nenabled = false\n'.replace("'", '"'))
    again = Coarticulation.from_spec(spec).fit(None)
    assert again.table_ is not None and model.table_ is not None and again.table_.values == model.table_.values


def test_a_spec_and_the_settings_it_builds_are_one_problem(trials: list) -> None:  # type: ignore[type-arg]
    """The TOML spec is one way to write the settings: its settings give a spec back that gives the
    same settings, and settings built in Python (defaults included) give the problem the file does."""
    raw = {"corpus": {"manifest": "m.csv"}, "model": {"channels": ["LLO"], "fit_beta": True, "speakers": "none"},
           "parameters": {"free": ["target", "alpha", "theta_bw"], "start": {"theta_bw": 40.0},
                          "bounds": {"alpha": [0.1, 10.0]}, "prior": {"p.alpha": [1.0, 0.5]}, "pooled": ["theta_bw"]},
           "override": [{"phonemes": ["p"], "free": ["k_r"], "start": {"k_r": 0.9}}],
           "tie": [{"phonemes": ["t", "l"], "parameters": ["theta_bw"]}],
           "shrink": [{"phonemes": ["a", "i"], "parameters": ["alpha"], "sd": 0.5, "scale": "log"}]}
    spec = parse_spec(raw, Path("/tmp/x.toml"))
    settings = spec.estimation_settings()
    again = FitSpec.from_settings(settings, spec.path, spec.name, spec.corpus, channels=spec.channels)
    assert again.estimation_settings() == settings and again == spec
    built = EstimationSettings(
        model=ModelSettings(), groups=GroupSettings(),
        parameters=ParameterSettings(free=("target", "alpha", "theta_bw"), fit_beta=True, start={"theta_bw": 40.0},
                                     bounds={"alpha": (0.1, 10.0)},
                                     overrides=(Override(("p",), free=("k_r",), start={"k_r": 0.9}),),
                                     ties=(Tie(("t", "l"), ("theta_bw",)),)),
        priors=PriorSettings(priors={"p.alpha": (1.0, 0.5, False)}, pooled=("theta_bw",),
                             shrinks=(Shrink(("a", "i"), ("alpha",), 0.5, log=True, key="shrink #1"),)))
    for a, b in [(settings, built), (parse_spec({"corpus": {"manifest": "m.csv"}}, Path("/tmp/y.toml"))
                                     .estimation_settings(), EstimationSettings())]:
        pa, pb = build_problem(a, trials, "LLO"), build_problem(b, trials, "LLO")
        assert pa.packing.names() == pb.packing.names() and pa.packing.bound_sources == pb.packing.bound_sources
        np.testing.assert_array_equal(pa.packing.pack(), pb.packing.pack())
        np.testing.assert_array_equal(pa.residuals(pa.packing.pack()), pb.residuals(pb.packing.pack()))
        assert pa.priors == pb.priors and pa.shrink_groups == pb.shrink_groups
