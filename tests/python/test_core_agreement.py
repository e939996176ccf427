"""The Rust core agrees with the plain NumPy implementation of MODEL.md, and with itself."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import random_corpus_arrays, random_params

import numpy_model as nm
from coartic import _core

VARIANTS = ["modified", "original"]


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("seed", range(8))
def test_matches_numpy_reference(variant: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    arrays = random_corpus_arrays(rng, n_utterances=5, n_phonemes=6)
    params = random_params(rng, 6)
    beta = float(rng.uniform(0.0, 3.0))
    apex = float(rng.uniform(0.2, 0.8))
    edge = float(rng.uniform(0.3, 2.0))
    corpus = _core.Corpus(**arrays)
    got = _core.evaluate(corpus, params, beta, _core.ModelOptions(variant, apex, edge))
    want = nm.evaluate_corpus_arrays(params, arrays, beta, variant, apex, edge)
    assert got.shape == (corpus.n_samples,)
    assert rel_err(got, want) < 1e-12


def test_underflowing_dominance_stays_finite_and_exact() -> None:
    # θ|τ|^c of several hundred: every exp underflows, only the log-sum-exp form survives.
    rng = np.random.default_rng(42)
    arrays = random_corpus_arrays(rng, n_utterances=3, n_phonemes=4)
    params = random_params(rng, 4)
    params[:, 2:4] = 4000.0
    params[:, 4:6] = 1.0
    corpus = _core.Corpus(**arrays)
    got = _core.evaluate(corpus, params, 1.0, _core.ModelOptions("original"))
    want = nm.evaluate_corpus_arrays(params, arrays, 1.0, "original")
    assert np.all(np.isfinite(got))
    assert rel_err(got, want) < 1e-12


def test_modified_without_resistance_and_shape_is_the_original() -> None:
    # MODEL.md §3 must 1: with S ≡ 1 (σ = 0) and R ≡ 1 (β = 0, k_R = 0 and an edge extent longer
    # than the utterance, so no sample reaches an extent) eq. 3 is eq. 1.
    rng = np.random.default_rng(7)
    arrays = random_corpus_arrays(rng, n_utterances=4, n_phonemes=5)
    params = random_params(rng, 5)
    params[:, 6] = 0.0
    params[:, 7] = 0.0
    corpus = _core.Corpus(**arrays)
    modified = _core.evaluate(corpus, params, 0.0, _core.ModelOptions("modified", 0.5, 5.0))
    original = _core.evaluate(corpus, params, 0.0, _core.ModelOptions("original", 0.5, 5.0))
    assert np.array_equal(modified, original) or rel_err(modified, original) < 1e-14


@pytest.mark.parametrize("rate", [1.0, 3.0])
def test_resistant_phoneme_reaches_its_target_at_any_rate(rate: float) -> None:
    # MODEL.md §3 must 3: k_R = 1 and σ = 0 → F(t_i) = T_i exactly, at normal and 3× faster speech.
    rng = np.random.default_rng(int(rate))
    params = random_params(rng, 3)
    params[1, 6] = 1.0  # the consonant
    params[1, 7] = 0.0
    params[:, 9] = 0.0
    dur = np.array([0.15, 0.14 / rate, 0.10 / rate, 0.16 / rate, 0.15])
    ends = np.cumsum(dur)
    starts = ends - dur
    t_c = 0.5 * (starts[2] + ends[2])
    corpus = _core.Corpus(
        np.array([0, 5]), np.array([2, 0, 1, 0, 2]), starts, ends, np.array([0, 1]), np.array([t_c]), 3
    )
    f = _core.evaluate(corpus, params, float(rng.uniform(0.1, 3.0)), _core.ModelOptions("modified"))
    assert f[0] == pytest.approx(params[1, 0], abs=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_continuous_in_resistance(seed: int) -> None:
    # Λ keeps every extent finite, so F moves by O(ε) when any k_R moves by ε, up to k_R = 1.
    rng = np.random.default_rng(20 + seed)
    arrays = random_corpus_arrays(rng, n_utterances=3, n_phonemes=4)
    corpus = _core.Corpus(**arrays)
    opts = _core.ModelOptions()
    for k_r in (0.0, 0.5, 1.0):
        params = random_params(rng, 4)
        params[:, 6] = k_r
        nudged = params.copy()
        nudged[:, 6] += -1e-7 if k_r == 1.0 else 1e-7
        a = _core.evaluate(corpus, params, 1.0, opts)
        b = _core.evaluate(corpus, nudged, 1.0, opts)
        assert np.max(np.abs(a - b)) < 1e-4 * max(1.0, float(np.abs(params[:, 0]).max()))


def test_batch_equals_single_calls() -> None:
    rng = np.random.default_rng(3)
    arrays = random_corpus_arrays(rng, n_utterances=6, n_phonemes=5)
    corpus = _core.Corpus(**arrays)
    opts = _core.ModelOptions()
    walkers = np.stack([random_params(rng, 5) for _ in range(7)])
    betas = rng.uniform(0.0, 2.0, 7)
    batch = _core.evaluate_batch(corpus, walkers, betas, opts)
    assert batch.shape == (7, corpus.n_samples)
    observed = rng.normal(0.0, 5.0, corpus.n_samples)
    weights = rng.uniform(0.0, 2.0, corpus.n_samples)
    weights[::5] = 0.0
    observed[::5] = np.nan  # masked samples may be NaN
    sse = _core.sse_batch(corpus, walkers, betas, opts, observed, weights)
    for w in range(7):
        single = _core.evaluate(corpus, walkers[w], betas[w], opts)
        assert np.array_equal(batch[w], single)
        ok = weights > 0
        want = float(np.sum(weights[ok] * (observed[ok] - single[ok]) ** 2))
        assert sse[w] == pytest.approx(want, rel=1e-12)
        s, _, _ = _core.sse_gradient(corpus, walkers[w], betas[w], opts, observed, weights)
        assert s == pytest.approx(sse[w], rel=1e-12)


def test_invalid_walker_gets_infinite_sse() -> None:
    rng = np.random.default_rng(4)
    arrays = random_corpus_arrays(rng, n_utterances=2, n_phonemes=3)
    corpus = _core.Corpus(**arrays)
    walkers = np.stack([random_params(rng, 3) for _ in range(3)])
    walkers[1, 2, 1] = -1.0  # alpha < 0
    y = np.zeros(corpus.n_samples)
    sse = _core.sse_batch(corpus, walkers, np.ones(3), _core.ModelOptions(), y, np.ones_like(y))
    assert np.isinf(sse[1]) and np.all(np.isfinite(sse[[0, 2]]))


def test_non_contiguous_and_fortran_input_give_the_same_answer() -> None:
    rng = np.random.default_rng(5)
    arrays = random_corpus_arrays(rng, n_utterances=3, n_phonemes=4)
    params = random_params(rng, 4)
    opts = _core.ModelOptions()
    want = _core.evaluate(_core.Corpus(**arrays), params, 1.0, opts)
    strided: dict[str, Any] = {k: (np.repeat(v, 2)[::2] if isinstance(v, np.ndarray) else v) for k, v in arrays.items()}
    assert not strided["sample_times"].flags.c_contiguous
    corpus = _core.Corpus(**strided)
    fortran = np.asfortranarray(params)
    assert not fortran.flags.c_contiguous
    assert np.array_equal(_core.evaluate(corpus, fortran, 1.0, opts), want)
    wide = np.zeros((4, 20))
    wide[:, ::2] = params
    assert np.array_equal(_core.evaluate(corpus, wide[:, ::2], 1.0, opts), want)
    batch = np.stack([params, params]).transpose(0, 2, 1).copy().transpose(0, 2, 1)
    assert not batch.flags.c_contiguous
    out = _core.evaluate_batch(corpus, batch, np.ones(2), opts)
    assert np.array_equal(out[0], want) and np.array_equal(out[1], want)


def test_misaligned_input_is_copied_not_misread() -> None:
    rng = np.random.default_rng(8)
    arrays = random_corpus_arrays(rng, n_utterances=2, n_phonemes=3)
    params = random_params(rng, 3)
    opts = _core.ModelOptions()
    want = _core.evaluate(_core.Corpus(**arrays), params, 1.0, opts)
    raw = bytearray(params.nbytes + 1)
    odd = np.frombuffer(raw, dtype=np.float64, offset=1).reshape(params.shape)
    odd[...] = params
    assert not odd.flags.aligned
    assert np.array_equal(_core.evaluate(_core.Corpus(**arrays), odd, 1.0, opts), want)


def test_outputs_are_owned_writeable_numpy_arrays() -> None:
    rng = np.random.default_rng(6)
    arrays = random_corpus_arrays(rng, n_utterances=2, n_phonemes=3)
    corpus = _core.Corpus(**arrays)
    out = _core.evaluate(corpus, random_params(rng, 3), 1.0, _core.ModelOptions())
    assert out.dtype == np.float64 and out.flags.c_contiguous and out.flags.writeable
    assert (corpus.n_utterances, corpus.n_segments, corpus.n_phonemes) == (
        2,
        len(arrays["seg_phoneme"]),
        3,
    )


@pytest.mark.parametrize(("dominance", "handover"), [("plateau", False), ("centre", True), ("plateau", True)])
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("seed", range(3))
def test_rate_aware_options_match_numpy_reference(dominance: str, handover: bool, variant: str, seed: int) -> None:
    """MODEL.md §2.1: plateau dominance and handover, as tests/python/numpy_model.py has them."""
    rng = np.random.default_rng(100 + seed)
    arrays = random_corpus_arrays(rng, n_utterances=4, n_phonemes=5)
    params = random_params(rng, 5)
    beta, apex, edge, h = (float(rng.uniform(0.0, 3.0)), float(rng.uniform(0.2, 0.8)),
                           float(rng.uniform(0.3, 2.0)), float(rng.uniform(0.1, 1.0)))
    corpus = _core.Corpus(**arrays)
    opts = _core.ModelOptions(variant, apex, edge, dominance=dominance, plateau_fraction=h, handover=handover)
    got = _core.evaluate(corpus, params, beta, opts)
    want = nm.evaluate_corpus_arrays(params, arrays, beta, variant, apex, edge, dominance=dominance,
                                     plateau_fraction=h, handover=handover)
    assert rel_err(got, want) < 1e-12
    # The option changes the model (the test would not notice an option that is ignored).
    plain = _core.evaluate(corpus, params, beta, _core.ModelOptions(variant, apex, edge))
    assert rel_err(got, plain) > 1e-6
    # Jacobian values and the batch path agree with evaluate bit for bit.
    values, *_ = _core.jacobian(corpus, params, beta, opts)
    assert np.array_equal(values, got)
    batch = _core.evaluate_batch(corpus, np.stack([params, params]), np.array([beta, beta]), opts)
    assert np.array_equal(batch[1], got)


def test_default_options_are_todays_model_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    arrays = random_corpus_arrays(rng, n_utterances=4, n_phonemes=5)
    params = random_params(rng, 5)
    corpus = _core.Corpus(**arrays)
    default = _core.evaluate(corpus, params, 1.2, _core.ModelOptions("modified", 0.4, 0.8))
    for opts in (_core.ModelOptions("modified", 0.4, 0.8, dominance="centre", plateau_fraction=0.9),
                 _core.ModelOptions("modified", 0.4, 0.8, dominance="plateau", plateau_fraction=0.0)):
        assert np.array_equal(_core.evaluate(corpus, params, 1.2, opts), default)
    o = _core.ModelOptions("original", dominance="plateau", plateau_fraction=0.25, handover=True)
    assert (o.dominance, o.plateau_fraction, o.handover) == ("plateau", 0.25, True)
    assert repr(o) == ('ModelOptions(variant="original", apex_fraction=0.5, edge_extent=1.0, dominance="plateau", '
                       'plateau_fraction=0.25, handover=True)')
    assert repr(_core.ModelOptions()) == 'ModelOptions(variant="modified", apex_fraction=0.5, edge_extent=1.0)'
    with pytest.raises(_core.CoarticError, match=r"unknown dominance \"segment\""):
        _core.ModelOptions(dominance="segment")
    with pytest.raises(_core.CoarticError, match=r"plateau_fraction = 1.5 is invalid: must be in \[0, 1\]") as e:
        _core.ModelOptions(dominance="plateau", plateau_fraction=1.5)
    assert (e.value.parameter, e.value.value) == ("plateau_fraction", 1.5)
