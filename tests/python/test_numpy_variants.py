"""The dominance variants of the NumPy reference (docs/VARIANTS.md) do what their maths says.

"centre" is MODEL.md §2; "segment" and "interval" measure D's reach in units of a duration, so a
uniformly stretched utterance gives the same curve stretched; "plateau" holds D at α over the middle
of its segment and decays at a rate fixed in seconds, so a transition depends on the boundary, not
on how long the segments around it last. Each test also shows that "centre" does not have the
property (or has it only where the variant reduces to it), so that it can fail.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import random_corpus_arrays, random_params

import numpy_model as nm

VARIANTS = ("modified", "original")


def utterance(rng: np.random.Generator, n: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows, starts, ends (contiguous, from 0) and sample times of one random utterance."""
    d = rng.uniform(0.05, 0.2, n)
    ends = np.cumsum(d)
    starts = np.concatenate([[0.0], ends[:-1]])
    return rng.integers(0, 6, n), starts, ends, np.sort(rng.uniform(0.0, ends[-1], 120))


@pytest.mark.parametrize("variant", VARIANTS)
def test_neutral_settings_give_the_centre_model_bit_for_bit(variant: str) -> None:
    # plateau with h = 0 is max(|τ|, 0) = |τ|; segment and interval with every duration and every
    # target distance equal to d_ref multiply |τ| by exactly 1.0 (durations on a binary grid).
    rng = np.random.default_rng(3)
    params = random_params(rng, 6)
    params[:, nm.DELTA] = 0.0
    starts = np.arange(6) * 0.125
    ends = starts + 0.125
    rows = rng.integers(0, 6, 6)
    times = np.sort(rng.uniform(0.0, ends[-1], 150))
    centre = nm.evaluate_utterance(params, rows, starts, ends, times, 1.3, variant)
    for kw in ({"dominance": "plateau", "plateau_fraction": 0.0},
               {"dominance": "segment", "reference_duration": 0.125},
               {"dominance": "interval", "reference_duration": 0.125}):
        got = nm.evaluate_utterance(params, rows, starts, ends, times, 1.3, variant, **kw)
        np.testing.assert_array_equal(got, centre, err_msg=str(kw))
    # ... and not at other settings
    other = nm.evaluate_utterance(params, rows, starts, ends, times, 1.3, variant, dominance="plateau",
                                  plateau_fraction=0.3)
    assert np.max(np.abs(other - centre)) > 1e-3


@pytest.mark.parametrize("dominance", nm.DOMINANCES)
@pytest.mark.parametrize("variant", VARIANTS)
def test_batch_is_the_reference_bit_for_bit(dominance: str, variant: str) -> None:
    rng = np.random.default_rng(11)
    params = random_params(rng, 6)
    params[:, nm.DELTA] = rng.uniform(-0.08, 0.08, 6)  # some target times clamp to their segment
    utts = [utterance(rng) for _ in range(4)]
    rows, starts, ends, times = (np.array([u[k] for u in utts]) for k in range(4))
    kw: dict[str, Any] = {"dominance": dominance, "reference_duration": 0.09, "plateau_fraction": 0.35,
                          "handover": dominance != "centre"}
    got = nm.evaluate_batch(params, rows, starts, ends, times, 0.7, variant, 0.4, 0.8, **kw)
    for b in range(4):
        want = nm.evaluate_utterance(params, rows[b], starts[b], ends[b], times[b], 0.7, variant, 0.4, 0.8, **kw)
        np.testing.assert_array_equal(got[b], want)


def stretchable(rng: np.random.Generator) -> np.ndarray:
    """A random model whose curve can scale with time: no target lag (δ is in seconds), no shape
    (ψ is in s^-2), and k_R = 1 on the phoneme of the first and last segment (row 0), so that the
    edge extent Λ (in seconds) drops out of every extent."""
    params = random_params(rng, 6)
    params[:, nm.DELTA] = 0.0
    params[:, nm.SIGMA] = 0.0
    params[0, nm.K_R] = 1.0
    return params


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("dominance", ["segment", "interval"])
def test_rate_following_dominance_stretches_with_the_utterance(dominance: str, variant: str) -> None:
    rng = np.random.default_rng(5)
    for _ in range(5):
        params = stretchable(rng)
        rows, starts, ends, times = utterance(rng, 6)
        rows[0] = rows[-1] = 0
        base = nm.evaluate_utterance(params, rows, starts, ends, times, 1.0, variant, dominance=dominance)
        for k in (0.6, 1.7):  # the fast rate of the synthetic session is 0.6
            stretched = nm.evaluate_utterance(params, rows, k * starts, k * ends, k * times, 1.0, variant,
                                              dominance=dominance)
            np.testing.assert_allclose(stretched, base, rtol=0, atol=1e-9 * np.max(np.abs(base)))


@pytest.mark.parametrize("variant", VARIANTS)
def test_centre_dominance_does_not_stretch(variant: str) -> None:
    # The property above is not automatic: MODEL.md's D reaches a fixed time into its neighbours.
    rng = np.random.default_rng(5)
    params = stretchable(rng)
    rows, starts, ends, times = utterance(rng, 6)
    rows[0] = rows[-1] = 0
    base = nm.evaluate_utterance(params, rows, starts, ends, times, 1.0, variant)
    fast = nm.evaluate_utterance(params, rows, 0.6 * starts, 0.6 * ends, 0.6 * times, 1.0, variant)
    assert np.max(np.abs(fast - base)) > 0.05


@pytest.mark.parametrize("dominance", ["plateau", "centre"])
def test_plateau_transitions_depend_on_the_boundary_not_the_durations(dominance: str) -> None:
    # Two segments A | B, equal α, θ, c (original model): with h = 1/2 the plateaus are the segments
    # themselves, D_A = α exp(−θ (t − e_A)_+^c) and D_B = α exp(−θ (s_B − t)_+^c), so F inside
    # [s_A, e_B] depends only on t − e_A: longer segments leave the transition as it is, and F at the
    # boundary is the mean of the targets. The centre model moves it with the segment midpoints.
    params = np.array([[2.0, 1.0, 40.0, 40.0, 1.2, 1.2, 0.0, 0.0, 500.0, 0.0],
                       [9.0, 1.0, 40.0, 40.0, 1.2, 1.2, 0.0, 0.0, 500.0, 0.0]])
    offsets = np.linspace(-0.06, 0.06, 25)  # around the boundary, inside both segments
    curves = []
    for da, db in ((0.08, 0.08), (0.08, 0.2), (0.15, 0.09)):
        starts, ends = np.array([0.0, da]), np.array([da, da + db])
        curves.append(nm.evaluate_utterance(params, [0, 1], starts, ends, da + offsets, 1.0, "original",
                                            dominance=dominance, plateau_fraction=0.5))
    spread = max(np.max(np.abs(c - curves[0])) for c in curves)
    if dominance == "plateau":
        assert spread < 1e-12
        assert curves[0][12] == pytest.approx(5.5, abs=1e-12)
    else:
        assert spread > 0.5


def test_unknown_dominance_is_refused_with_the_choices() -> None:
    rng = np.random.default_rng(0)
    arrays = random_corpus_arrays(rng, n_utterances=1, n_phonemes=3)
    with pytest.raises(ValueError, match="unknown dominance 'gesture'.*centre, segment"):
        nm.evaluate_corpus_arrays(random_params(rng, 3), arrays, dominance="gesture")
    with pytest.raises(ValueError, match="unknown dominance 'gesture'"):
        nm.evaluate_batch(random_params(rng, 3), np.zeros((1, 2), np.int64), np.array([[0.0, 0.1]]),
                          np.array([[0.1, 0.2]]), np.array([[0.05, 0.15]]), dominance="gesture")


@pytest.mark.parametrize("dominance", ["centre", "plateau"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_handover_takes_the_forward_side_from_the_next_segment(dominance: str, variant: str) -> None:
    # handover = the same model with each segment given its own row whose (θ_fw, c_fw) are the next
    # segment's (the last keeps its own); bit for bit.
    rng = np.random.default_rng(2)
    params = random_params(rng, 6)
    rows, starts, ends, times = utterance(rng, 6)
    per_segment = params[rows].copy()
    per_segment[:-1, [nm.THETA_FW, nm.C_FW]] = per_segment[1:, [nm.THETA_FW, nm.C_FW]]
    got = nm.evaluate_utterance(params, rows, starts, ends, times, 1.0, variant, dominance=dominance,
                                handover=True)
    want = nm.evaluate_utterance(per_segment, np.arange(6), starts, ends, times, 1.0, variant,
                                 dominance=dominance)
    np.testing.assert_array_equal(got, want)
    # The first segment's own θ_fw (its phoneme occurs nowhere else) no longer matters; without
    # handover it does.
    rows = np.array([0, 1, 2, 3, 4, 5])
    bumped = params.copy()
    bumped[0, nm.THETA_FW] *= 3.0
    for handover, changes in ((True, False), (False, True)):
        a = nm.evaluate_utterance(params, rows, starts, ends, times, 1.0, variant, dominance=dominance,
                                  handover=handover)
        b = nm.evaluate_utterance(bumped, rows, starts, ends, times, 1.0, variant, dominance=dominance,
                                  handover=handover)
        assert (np.max(np.abs(a - b)) > 1e-6) == changes


@pytest.mark.parametrize("handover", [False, True])
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("seed", range(3))
def test_core_rate_aware_options_match_the_reference(seed: int, variant: str, handover: bool) -> None:
    # The Rust core's dominance="plateau" / handover options (docs/VARIANTS.md) compute the
    # reference's numbers, including δ large enough to clamp target times into their segments.
    from coartic import _core

    rng = np.random.default_rng(100 + seed)
    arrays = random_corpus_arrays(rng, n_utterances=4, n_phonemes=6)
    params = random_params(rng, 6)
    params[:, nm.DELTA] = rng.uniform(-0.08, 0.08, 6)
    h = float(rng.uniform(0.0, 0.8))
    for dominance in ("plateau", "centre"):
        got = _core.evaluate(_core.Corpus(**arrays), params, 0.9,
                             _core.ModelOptions(variant, 0.5, 1.0, dominance=dominance, plateau_fraction=h,
                                                handover=handover))
        want = nm.evaluate_corpus_arrays(params, arrays, 0.9, variant, 0.5, 1.0, dominance=dominance,
                                         plateau_fraction=h, handover=handover)
        assert np.max(np.abs(got - want) / np.maximum(1.0, np.abs(want))) < 1e-12
