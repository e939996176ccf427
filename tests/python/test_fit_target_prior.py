"""The model recommended (docs/REAL_DATA.md) as the default of a spec that sets nothing: rate-aware
dominance, each phoneme's target, alpha and theta free with the dynamics partially pooled
(``[parameters] pooled``, coartic.estimation.pooling), and every target drawn toward the data's own
phoneme mean (``[parameters] target_prior``, its sd estimated); one shared theta per channel
(``[parameters] shared``) on request; the specs of fit/ that keep the paper's model say so."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic import model
from coartic.estimation.problem import build_problem
from coartic.estimation.target_prior import segment_means
from coartic.fit import run
from coartic.jobs.fit import fit_job
from coartic.evaluation.baselines import Baselines
from coartic.fit.choose import set_value
from coartic.evaluation.score import score_recordings
from coartic.fit.simulate import PHONEMES, vcv_utterances
from coartic.estimation.settings import DEFAULT_FREE, DEFAULT_POOLED, DEFAULT_SHARED, DEFAULT_TARGET_PRIOR
from coartic.fit.spec import SETTING_SECTION, SpecError, load_spec, parse_spec
from coartic.table import PARAMETERS

from fit_helpers import EMA, check_problem_derivatives

ROOT = Path(__file__).resolve().parents[2]
CORPUS = {"files": ["x.csv"], "labels": ["x.lab"]}
T, BW, FW = (PARAMETERS.index(p) for p in ("target", "theta_bw", "theta_fw"))


def parsed(tmp_path: Path, **sections: object):  # type: ignore[no-untyped-def]
    return parse_spec({"corpus": CORPUS, **sections}, tmp_path / "spec.toml")


@pytest.fixture(scope="module")
def utts() -> list[model.Utterance]:
    return vcv_utterances(np.random.default_rng(3), repetitions=1, rates={"normal": 1.0}, consonants=("p", "t"))


def test_a_spec_that_sets_nothing_is_the_recommended_model(tmp_path: Path) -> None:
    s = parsed(tmp_path)
    assert (s.model.dominance, s.model.handover, s.model.plateau_fraction) == ("plateau", True, 0.5)
    assert s.parameters.free == DEFAULT_FREE == ("target", "alpha", "theta_bw", "theta_fw")
    assert s.priors.pooled == DEFAULT_POOLED == ("alpha", "theta_bw", "theta_fw") and s.parameters.shared == DEFAULT_SHARED == ()
    assert s.priors.target_prior == DEFAULT_TARGET_PRIOR == "estimated"
    # the template shows the defaults: copying it changes nothing
    t = load_spec(ROOT / "fit" / "template.toml")
    for key in ("variant", "dominance", "handover", "plateau_fraction", "free", "shared", "pooled", "target_prior",
                "prior_noise"):
        section = SETTING_SECTION[key]  # the part of the nested spec that holds it
        assert getattr(getattr(t, section), key) == getattr(getattr(s, section), key), key


def test_a_spec_that_lists_its_free_set_keeps_per_phoneme_dynamics(tmp_path: Path) -> None:
    s = parsed(tmp_path, parameters={"free": ["target", "alpha", "theta_bw"]})
    assert s.parameters.shared == () and s.priors.pooled == () and s.priors.target_prior == DEFAULT_TARGET_PRIOR
    # sharing some of the default's pooled dynamics pools the others
    s = parsed(tmp_path, parameters={"shared": ["theta_bw"]})
    assert s.parameters.shared == ("theta_bw",) and s.priors.pooled == ("alpha", "theta_fw")
    s = parsed(tmp_path, parameters={"free": ["target", "alpha"], "shared": ["alpha"], "target_prior": "none"})
    assert s.parameters.shared == ("alpha",) and s.priors.target_prior is None


@pytest.mark.parametrize("parameters, sections, words", [
    ({"target_prior": -1.0}, {}, "positive number"),
    ({"target_prior": True}, {}, "positive number"),
    ({"target_prior": "off"}, {}, "\"none\""),
    ({"free": ["target"], "shared": ["theta_bw"]}, {}, "theta_bw is not free"),
    ({"free": ["target", "theta_bw"], "shared": ["target"]}, {}, "target cannot be shared"),
    ({"free": ["target", "theta_bw"], "shared": ["theta_bw"]},
     {"tie": [{"phonemes": ["p", "t"], "parameters": ["theta_bw"]}]}, "[[tie]]"),
])
def test_bad_settings_name_their_key(tmp_path: Path, parameters: dict[str, object], sections: dict[str, object],
                                     words: str) -> None:
    with pytest.raises(SpecError) as e:
        parsed(tmp_path, parameters=parameters, **sections)
    key = "parameters.target_prior" if "target_prior" in parameters else "parameters.shared"
    assert f"[{key}]" in str(e.value) and "spec.toml" in str(e.value) and words in str(e.value)


def test_target_prior_rows_pull_toward_each_phonemes_segment_mean(tmp_path: Path, utts: list[model.Utterance]) -> None:
    s = parsed(tmp_path, model={"channels": ["LLO"]}, parameters={"free": ["target", "theta_bw"], "target_prior": 0.5,
                                                                   "prior_noise": 0.7})
    prob = build_problem(s.estimation_settings(), utts, "LLO", phonemes=PHONEMES)
    means = segment_means(utts, "LLO")
    # by hand: every sample inside a segment of the phoneme, over every utterance
    y = np.concatenate([u.observed["LLO"] for u in utts])
    lab = np.concatenate([np.array([*u.labels, "-"])[u.sample_segments()] for u in utts])
    assert set(means) == set(PHONEMES) - {"l"}  # /l/ is in the inventory, not in these data: no prior
    for p in means:
        assert means[p] == pytest.approx(float(y[lab == p].mean()), rel=1e-12), p
    assert means == Baselines.fit(utts, ["LLO"]).step["LLO"]  # the step model's values, one computation
    assert prob.penalty.size == len(means)  # one row per free target with data
    x = prob.packing.pack()
    params, _ = prob.packing.unpack(x)
    rows = prob.penalty.residuals(x)
    want = [0.7 * (params[i, T] - means[p]) / 0.5 for i, p in enumerate(prob.phonemes) if p in means]
    np.testing.assert_allclose(np.sort(rows), np.sort(want), rtol=1e-12)
    check_problem_derivatives(prob, x + 0.05)
    # an explicit prior on a target wins over the data's
    s2 = s.with_options(priors={"priors": {"p.target": (1.0, 2.0, False)}})
    pri = build_problem(s2.estimation_settings(), utts, "LLO", phonemes=PHONEMES).priors
    assert (pri["p.target"].mean, pri["p.target"].sd) == (1.0, 2.0) and pri["t.target"].mean == pytest.approx(means["t"])


def test_a_strong_target_prior_makes_the_targets_the_phoneme_means(tmp_path: Path, utts: list[model.Utterance]) -> None:
    """sd -> 0: the table is the step model's values under the dominance functions; without the
    prior the fitted targets leave them (the test can fail: the two differ)."""
    base = parsed(tmp_path, model={"channels": ["LLO"], "dominance": "centre", "handover": False, "pauses": "one"},
                  parameters={"free": ["target"], "target_prior": 0.001}, fit={"starts": 1})
    means = segment_means(utts, "LLO")
    for sd, close in ((0.001, True), (None, False)):
        fit = run(base.with_options(target_prior=sd), utterances=utts, quiet=True).channels["LLO"]
        gap = max(abs(fit.params[i, T] - means[p]) for i, p in enumerate(fit.phonemes))
        assert (gap < 0.05) == close, (sd, gap)


def test_shared_dynamics_are_one_value_per_channel(tmp_path: Path, utts: list[model.Utterance]) -> None:
    s = parsed(tmp_path, model={"channels": ["LLO"]}, fit={"starts": 1}, staging={"enabled": False},
               parameters={"free": ["target", "theta_bw", "theta_fw"], "shared": ["theta_bw", "theta_fw"]})
    prob = build_problem(s.estimation_settings(), utts, "LLO", phonemes=PHONEMES)
    assert prob.packing.n_free == len(PHONEMES) + 2  # every target, one theta_bw, one theta_fw
    fit = run(s, utterances=utts, quiet=True).channels["LLO"]
    for k in (BW, FW):
        assert np.ptp(fit.params[:, k]) == 0.0 and fit.params[0, k] != s.parameters.start_of(PARAMETERS[k])


def test_cross_validation_can_choose_the_target_prior(tmp_path: Path) -> None:
    s = parsed(tmp_path, choose={"key": "target_prior", "values": [0.1, 1.0], "group": "repetition", "folds": 2})
    assert s.choose is not None and s.choose.rule == "1se"
    assert set_value(s, "target_prior", 0.1).priors.target_prior == 0.1


def test_the_specs_of_fit_keep_the_model_their_figures_were_measured_with() -> None:
    """Only the template and the specs that set nothing but their recordings (the German EMA's
    "defaults" specs and the held-out s1em and two-speaker ones, docs/REAL_DATA.md) take the new
    defaults: make fit (synthetic.toml), the Italian table and the German EMA examples keep the
    paper's model without a target prior (or, for the rate-aware gestures spec, its own)."""
    defaults = ("template.toml", "batch_synthetic.toml", "ema_german_defaults_0024.toml", "ema_german_defaults.toml",
                "ema_s1em.toml", "ema_speakers.toml")
    for f in sorted((ROOT / "fit").glob("*.toml")):
        if f.name in defaults:
            continue
        s = load_spec(f)
        assert s.priors.target_prior is None and s.parameters.shared == (), f.name
        assert (s.model.dominance, s.model.handover) == (("plateau", True) if "rate_aware" in f.name else ("centre", False)), f.name


def test_a_spec_that_sets_nothing_beats_the_step_model_on_real_ema(tmp_path: Path) -> None:
    """The recommendation end to end, as a user runs it: `coartic fit` of one German EMA utterance
    (0024) with a spec that gives only the corpus and channels (fit/ema_german_defaults_0024.toml),
    then `coartic score` of the other
    sentence (0020): the table beats the step model and the constant on both channels, as measured
    and with the offset removed, and nothing is flagged (docs/REAL_DATA.md: by 0.2-0.4 mm on LA and
    JO, with `coartic score`'s own scoring of every segment)."""
    spec = load_spec(ROOT / "fit" / "ema_german_defaults_0024.toml")
    assert spec.priors.target_prior == DEFAULT_TARGET_PRIOR and spec.parameters.shared == DEFAULT_SHARED  # it sets nothing
    fit_job(spec, tmp_path / "fit", quiet=True, report=False)
    sc = score_recordings(tmp_path / "fit" / "table.json", [EMA / "dfgspp_mo1_prosody_0020_ema.csv"],
                          [EMA / "dfgspp_mo1_prosody_0020_Segment.tsv"], channels=["LA", "JO"])
    assert sc.flags() == []
    rows = {(r["channel"], r["model"]): r for r in sc.baseline_rows()}
    for ch in ("LA", "JO"):
        for key in ("rmse_mm", "rmse_offset_removed_mm"):
            table = rows[ch, "table"][key]
            assert table < rows[ch, "step"][key] and table < rows[ch, "constant"][key], (ch, key, rows)
