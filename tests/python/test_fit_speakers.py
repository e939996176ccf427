"""Several speakers in one fit ([model] speakers): speaker-specific target offset and scale,
profiled out with an exact Jacobian, shared dynamics."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from coartic.fit.problem import build_problem
from coartic.fit.simulate import PHONEMES, TRUTH, vcv_utterances
from coartic.fit.spec import SpecError, parse_spec
from coartic.table import PARAMETERS

TARGET = PARAMETERS.index("target")


def spec(speakers: str):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]},
           "model": {"channels": ["LLO"], "speakers": speakers}, "parameters": {"free": ["target", "theta_bw"]}}
    return parse_spec(raw, Path("/tmp/test_spec.toml"))


@pytest.fixture(scope="module")
def utts():  # type: ignore[no-untyped-def]
    """Speaker 1 from the model; speaker 2 = 1.2 × speaker 1 + 0.5 mm (same segments)."""
    one = vcv_utterances(np.random.default_rng(3), repetitions=1, rates={"normal": 1.0})
    out = []
    for u in one:
        u.meta = {**u.meta, "speaker": "s1"}
        v = copy.deepcopy(u)
        v.name, v.meta = u.name + "-s2", {**u.meta, "speaker": "s2"}
        v.observed = {ch: 1.2 * y + 0.5 for ch, y in u.observed.items()}
        out += [u, v]
    return out


def start() -> np.ndarray:
    p = TRUTH.copy()
    p[:, TARGET] += 1.5  # shared targets off, to be recovered
    return p


@pytest.mark.parametrize("mode", ["offset", "offset_scale"])
def test_speaker_jacobian_matches_finite_differences(utts, mode: str) -> None:  # type: ignore[no-untyped-def]
    p = build_problem(spec(mode), utts, "LLO", start=(start(), 1.0), phonemes=PHONEMES)
    x = p.packing.pack()
    jac = p.jacobian(x).toarray()
    for j in range(p.packing.n_free):
        h = 1e-6
        e = np.zeros_like(x)
        e[j] = h
        fd = (p.residuals(x + e) - p.residuals(x - e)) / (2 * h)
        np.testing.assert_allclose(jac[:, j], fd, atol=1e-6 * max(1.0, np.abs(fd).max()),
                                   err_msg=f"{mode} {p.packing.names()[j]}")
    sse, g = p.sse_gradient(x)
    r = p.residuals(x)
    assert sse == pytest.approx(float(r @ r), rel=1e-12)
    np.testing.assert_allclose(g, 2 * jac.T @ r, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(p.sse_batch(np.stack([x, x])), [sse, sse], rtol=1e-12)


def fit(utts, mode: str):  # type: ignore[no-untyped-def]
    p = build_problem(spec(mode), utts, "LLO", start=(start(), 1.0), phonemes=PHONEMES)
    res = least_squares(p.residuals, p.packing.pack(), jac=p.jacobian, bounds=p.packing.bounds(), x_scale="jac")
    rmse = float(np.sqrt(np.sum(res.fun[: p.data.corpus.n_samples] ** 2) / p.data.n_valid))
    return p, res.x, rmse


def test_pooled_offset_scale_recovers_speaker_and_beats_none(utts) -> None:  # type: ignore[no-untyped-def]
    p, x, rmse = fit(utts, "offset_scale")
    coef = p.speaker_coefficients(x)
    assert list(coef) == ["s1", "s2"] and coef["s1"] == (0.0, 1.0)  # reference speaker fixed
    a, b = coef["s2"]
    assert b == pytest.approx(1.2, abs=0.02) and a == pytest.approx(0.5, abs=0.1)
    params, _ = p.packing.unpack(x)  # shared targets are the reference speaker's
    np.testing.assert_allclose(params[1:, TARGET], TRUTH[1:, TARGET], atol=0.2)
    _, _, rmse_none = fit(utts, "none")
    assert rmse < 0.6 * rmse_none
    # docs/FITTING.md: the table for speaker s is its targets mapped a + b·target (F is a
    # dominance-weighted mean of targets), so a + b·F is the model evaluated with those targets
    f = p.evaluate(params, 1.0)
    mapped = params.copy()
    mapped[:, TARGET] = a + b * mapped[:, TARGET]
    np.testing.assert_allclose(p.evaluate(mapped, 1.0), a + b * f, atol=1e-10)


def test_speakers_need_the_column_and_a_known_mode(utts) -> None:  # type: ignore[no-untyped-def]
    bare = [copy.copy(u) for u in utts[:2]]
    bare[1].meta = {}
    with pytest.raises(ValueError, match="has no 'speaker'"):
        build_problem(spec("offset"), bare, "LLO", start=(TRUTH, 1.0), phonemes=PHONEMES)
    with pytest.raises(SpecError, match="model.speakers"):
        spec("scale")
