"""Settings built in Python check themselves (issue 28 item 1): the estimation settings
(coartic.estimation.settings) refuse a bad value on construction, with the spec key the setting is
written with in a file, so that settings handed straight to build_problem are checked as a spec's."""

from __future__ import annotations

from pathlib import Path

import pytest

from coartic.errors import SpecError
from coartic.estimation.settings import (EstimationSettings, GroupSettings, ModelSettings, Override,
                                         ParameterSettings, PriorSettings, Shrink, Tie)
from coartic.fit.spec import parse_spec


@pytest.mark.parametrize(("build", "key", "message"), [
    (lambda: ModelSettings(variant="modifed"), "model.variant", "'modifed': expected one of"),
    (lambda: ModelSettings(plateau_fraction=1.5), "model.plateau_fraction", "plateau_fraction = 1.5"),
    (lambda: ModelSettings(pauses="all"), "model.pauses", "'all': expected one of postures, one"),
    (lambda: ParameterSettings(free=("kr",)), "parameters.free", "unknown parameter 'kr'"),
    (lambda: ParameterSettings(shared=("target",)), "parameters.shared", "target cannot be shared"),
    (lambda: ParameterSettings(start={"alpha": -1.0}), "parameters.start.alpha", "the model's domain of alpha"),
    (lambda: ParameterSettings(bounds={"theta_bw": (5.0, 1.0)}), "parameters.bounds.theta_bw", "low 5.0 must be below"),
    (lambda: ParameterSettings(channel_bounds={"LLO": {"psi": (0.0, 1.0)}}), "parameters.bounds.LLO.psi",
     "must be > 0 (fitted on a log scale)"),
    (lambda: ParameterSettings(beta_bounds=(2.0, 1.0)), "model.beta_bounds", "need 0 <= low < high"),
    (lambda: ParameterSettings(fit_beta=1), "model.fit_beta", "expected true or false"),
    (lambda: ParameterSettings(shared=("theta_bw",), ties=(Tie(("t", "l"), ("theta_bw",)),)), "parameters.shared",
     "both shared by every phoneme and in a [[tie]]"),
    (lambda: PriorSettings(prior_noise=0.0), "parameters.prior_noise", "must be a positive number"),
    (lambda: PriorSettings(target_prior=-2.0), "parameters.target_prior", "expected \"none\", \"estimated\""),
    (lambda: PriorSettings(priors={"p.alpha": (1.0, -0.5, False)}), "parameters.prior.p.alpha", "a positive sd"),
    (lambda: PriorSettings(pooled=("target",)), "parameters.pooled", "target cannot be pooled"),
    (lambda: GroupSettings(offsets=-1.0), "model.offsets", "expected \"none\", \"free\" or a positive number"),
    (lambda: GroupSettings(speakers="offset", offsets="free"), "model.speakers", "cannot be combined"),
    (lambda: Override(("p",), free=("kr",)), "override.free", "unknown parameter 'kr'"),
    (lambda: Tie(("p",), ("theta_bw",)), "tie.phonemes", "a tie needs two phonemes or more"),
    (lambda: Shrink(("a", "i"), ("k_r",), 0.5, log=True), "shrink.scale", "log scale needs positive parameters"),
    (lambda: Shrink(("a", "i"), ("alpha",), 0.5, scale="log"), "shrink", "unknown key(s) ['scale']"),
])
def test_each_part_refuses_a_bad_value_by_its_spec_key(build, key: str, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SpecError) as caught:
        build()
    assert caught.value.key == key and str(caught.value).startswith(f"[{key}] ") and message in str(caught.value)


def test_what_no_part_checks_alone_is_checked_by_the_settings() -> None:
    # named by the source (a spec file's path) and the key a file would give
    with pytest.raises(SpecError, match=r"^x.toml: \[tie #2\] ties alpha of the reference phoneme 'a'") as caught:
        EstimationSettings(parameters=ParameterSettings(ties=(Tie(("t", "l"), ("theta_bw",)),
                                                              Tie(("a", "e"), ("alpha",)))), source="x.toml")
    assert caught.value.file == Path("x.toml") and caught.value.entry == 1 and caught.value.phoneme == "a"
    with pytest.raises(SpecError, match=r"^\[override #1\] sets alpha of the reference phoneme 'i'"):
        EstimationSettings(model=ModelSettings(reference_phoneme="i"),
                           parameters=ParameterSettings(overrides=(Override(("i",), fixed={"alpha": 2.0}),)))
    with pytest.raises(SpecError, match=r"^\[parameters.pooled\] theta_bw is both shared by every phoneme and pooled"):
        EstimationSettings(parameters=ParameterSettings(shared=("theta_bw",)))
    with pytest.raises(SpecError, match=r"^\[model.beta\] beta = 30 is above 20") as caught:
        EstimationSettings(model=ModelSettings(beta=30.0))
    assert caught.value.parameter == "beta" and caught.value.value == 30.0
    # the same settings are fine when their parts agree
    EstimationSettings(model=ModelSettings(beta=30.0), parameters=ParameterSettings(beta_bounds=(0.1, 40.0)))


def test_unknown_fields_and_positional_arguments_are_named() -> None:
    with pytest.raises(SpecError, match=r"ModelSettings has no field\(s\) \['dominanse'\]"):
        ModelSettings(dominanse="centre")  # type: ignore[call-arg]
    with pytest.raises(SpecError, match=r"^\[shrink.sd\] -1.0 must be a positive number"):
        Shrink(("a", "i"), ("alpha",), -1.0)
    with pytest.raises(SpecError, match=r"^\[tie.phonemes\] Got multiple values"):  # given twice
        Tie(("a", "i"), ("alpha",), phonemes=("a", "e"))  # type: ignore[misc]


def test_several_problems_are_all_reported() -> None:
    with pytest.raises(SpecError) as caught:
        ModelSettings(variant="x", dominance="nope")
    assert [k for k, _ in caught.value.problems] == ["model.variant", "model.dominance"]


def test_a_spec_builds_settings_equal_to_those_built_in_python() -> None:
    """The spec's checks and the settings' are one: a file's values give settings that compare equal
    to the settings built in Python from the same values (converted the same way)."""
    spec = parse_spec({"corpus": {"manifest": "m.csv"}, "model": {"beta": 2, "offsets": 1},
                       "parameters": {"bounds": {"alpha": [1, 10]}, "prior_noise": 2}}, Path("/tmp/s.toml"))
    s = spec.estimation_settings()
    assert s.model == ModelSettings(beta=2)
    assert s.groups == GroupSettings(offsets=1)
    assert s.parameters.bounds["alpha"] == (1.0, 10.0) and s.priors == PriorSettings(prior_noise=2, pooled=s.priors.pooled)
