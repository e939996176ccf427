"""Packing, transforms and derivatives of the channel problem (what the engines and MCMC share)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic.estimation.packing import LOG_COLUMNS
from coartic.estimation.problem import ChannelProblem, build_problem
from coartic.fit.simulate import PHONEMES, TRUTH, vcv_utterances
from coartic.errors import SpecError
from coartic.estimation.settings import REFERENCE_ORDER
from coartic.fit.spec import parse_spec
from coartic.table import PARAMETERS

from fit_helpers import paper


def spec(**parameters: object):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]}, **parameters}
    return parse_spec(paper(raw), Path("/tmp/test_spec.toml"))


@pytest.fixture(scope="module")
def utts():  # type: ignore[no-untyped-def]
    return vcv_utterances(np.random.default_rng(3), repetitions=1, rates={"normal": 1.0})


def test_pack_unpack_round_trip(utts) -> None:  # type: ignore[no-untyped-def]
    p = build_problem(spec(model={"channels": ["LLO"], "fit_beta": True}).estimation_settings(), utts, "LLO", start=(TRUTH, 1.0),
                      phonemes=PHONEMES)
    pk = p.packing
    x = pk.pack(TRUTH, 1.0)
    params, beta = pk.unpack(x)
    np.testing.assert_allclose(params, TRUTH, rtol=1e-14)
    assert beta == pytest.approx(1.0)
    # log-scale entries are the logs of alpha, theta, psi (and beta)
    names = pk.names()
    i = names.index("i.theta_bw")
    assert x[i] == pytest.approx(np.log(25.0))
    assert names[-1] == "beta" and x[-1] == pytest.approx(0.0)
    # reference phoneme: alpha fixed at 1, not free
    assert "a.alpha" not in names and params[PHONEMES.index("a"), 1] == 1.0
    lo, hi = pk.bounds()
    assert np.all(lo <= x) and np.all(x <= hi)
    # batch unpack agrees with single unpack
    xs = np.stack([x, x + 0.01])
    pb, bb = pk.unpack_batch(xs)
    np.testing.assert_allclose(pb[1], pk.unpack(x + 0.01)[0])
    assert bb[1] == pytest.approx(pk.unpack(x + 0.01)[1])


def test_jacobian_matches_finite_differences(utts) -> None:  # type: ignore[no-untyped-def]
    s = spec(model={"channels": ["LLO"], "fit_beta": True})
    p = build_problem(s.estimation_settings(), utts, "LLO", start=(TRUTH * np.where(LOG_COLUMNS, 1.1, 1.0), 1.2), phonemes=PHONEMES)
    x = p.packing.pack()
    x = np.clip(x, *p.packing.bounds())
    jac = p.jacobian(x).toarray()
    assert jac.shape == (p.data.corpus.n_samples, p.packing.n_free)
    rng = np.random.default_rng(0)
    for j in rng.choice(p.packing.n_free, 12, replace=False):
        h = 1e-6
        e = np.zeros_like(x)
        e[j] = h
        fd = (p.residuals(x + e) - p.residuals(x - e)) / (2 * h)
        np.testing.assert_allclose(jac[:, j], fd, atol=1e-5 * max(1.0, np.abs(fd).max()),
                                   err_msg=p.packing.names()[j])
    # fused SSE gradient = 2 J^T r
    sse, g = p.sse_gradient(x)
    r = p.residuals(x)
    assert sse == pytest.approx(float(r @ r), rel=1e-12)
    np.testing.assert_allclose(g, 2 * jac.T @ r, rtol=1e-8, atol=1e-8 * np.abs(g).max())
    # the batch SSE agrees
    np.testing.assert_allclose(p.sse_batch(np.stack([x, x])), [sse, sse], rtol=1e-12)


def test_masked_samples_do_not_count(utts) -> None:  # type: ignore[no-untyped-def]
    u = utts[0]
    u.valid["LLO"] = u.valid["LLO"].copy()
    u.observed["LLO"] = u.observed["LLO"].copy()
    u.valid["LLO"][5:15] = False
    u.observed["LLO"][5:15] = np.nan  # a long gap: masked, never NaN in the objective
    p = build_problem(spec().estimation_settings(), utts, "LLO", start=(TRUTH, 1.0), phonemes=PHONEMES)
    r = p.residuals(p.packing.pack())
    assert np.all(np.isfinite(r)) and np.all(r[5:15] == 0.0)
    assert p.data.n_valid == p.data.corpus.n_samples - 10


def test_free_set_overrides_and_variant(utts) -> None:  # type: ignore[no-untyped-def]
    s = spec(override=[{"phonemes": ["p"], "fixed": {"k_r": 1.0}}, {"phonemes": ["t"], "free": ["sigma"]}],
             parameters={"free": ["target", "k_r"]})
    pk = build_problem(s.estimation_settings(), utts, "LLO", phonemes=PHONEMES).packing
    names = pk.names()
    assert "p.k_r" not in names and "t.k_r" in names and "t.sigma" in names and "l.sigma" not in names
    assert pk.base[PHONEMES.index("p"), PARAMETERS.index("k_r")] == 1.0
    orig = build_problem(spec(model={"channels": ["LLO"], "variant": "original"}).estimation_settings(), utts, "LLO").packing
    assert not any(n.endswith((".k_r", ".sigma", ".psi")) for n in orig.names())


def test_targets_start_from_data(utts) -> None:  # type: ignore[no-untyped-def]
    pk = build_problem(spec().estimation_settings(), utts, "LLO", phonemes=PHONEMES).packing
    # the mid-segment mean is near the target for vowels and the always-reached /p/
    for ph in ("a", "p"):
        i = PHONEMES.index(ph)
        assert abs(pk.base[i, 0] - TRUTH[i, 0]) < 2.0


def test_reference_phoneme_must_occur(utts) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SpecError, match=r"\[model.reference_phoneme\] 'u'"):
        build_problem(spec(model={"channels": ["LLO"], "reference_phoneme": "u"}).estimation_settings(), utts, "LLO")


def test_reference_phoneme_chosen_from_the_data_when_the_spec_names_none(utts) -> None:  # type: ignore[no-untyped-def]
    """A spec that names no reference phoneme takes /a/ when the data have it, else the first of
    REFERENCE_ORDER they have (α of it fixed at 1, every other α free); the settings the table
    records say which. A named one absent from the data is still an error (above)."""
    no_a = [u for u in utts if "a" not in u.labels]
    s = spec()
    assert s.model.reference_phoneme is None
    p = build_problem(s.estimation_settings(), no_a, "LLO")
    assert "a" not in p.phonemes and "i" in p.phonemes
    ref = s.reference_for(p.phonemes)
    assert ref == next(q for q in REFERENCE_ORDER if q in p.phonemes) == "i"
    names = p.packing.names()
    assert f"{ref}.alpha" not in names and all(f"{q}.alpha" in names for q in p.phonemes if q != ref)
    assert s.channel_settings("LLO", phonemes=p.phonemes).reference_phoneme == ref
    assert build_problem(s.estimation_settings(), utts, "LLO").packing.names().count("a.alpha") == 0  # /a/ when present
    named = spec(model={"channels": ["LLO"], "reference_phoneme": "u"})
    assert named.reference_for(p.phonemes) == "u"


def test_best_point_tracked(utts) -> None:  # type: ignore[no-untyped-def]
    p: ChannelProblem = build_problem(spec().estimation_settings(), utts, "LLO", phonemes=PHONEMES)
    x0 = p.packing.pack()
    s0 = p.sse(x0)
    x1 = p.packing.pack(TRUTH, 1.0)
    s1 = p.sse(x1)
    p.sse(x0)
    assert s1 < s0 and p.best_sse == pytest.approx(s1) and np.array_equal(p.best_x, x1)


def test_a_refused_start_value_is_named_by_its_spec_key_and_phoneme() -> None:
    # refused where the spec is read (it used to reach the engines, which named the key in prose)
    with pytest.raises(SpecError, match=r"\[parameters.start.alpha\] expected a number, got nan") as e:
        spec(parameters={"start": {"alpha": float("nan")}})
    assert e.value.key == "parameters.start.alpha"
    with pytest.raises(SpecError, match=r"\[override #1.fixed.theta_fw\] theta_fw = -3 \(of p\) is outside "
                                        r"\(0, inf\), the model's domain of theta_fw") as e:
        spec(override=[{"phonemes": ["p"], "fixed": {"theta_fw": -3.0}}])
    assert e.value.key == "override #1.fixed.theta_fw"
