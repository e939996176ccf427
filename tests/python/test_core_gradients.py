"""The core's Jacobian and SSE gradient against central finite differences taken from Python."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp  # type: ignore[import-untyped]
from conftest import random_corpus_arrays, random_params

from coartic import _core

N_PARAMS = 10


def jacobian_matrix(corpus: _core.Corpus, params: np.ndarray, beta: float, opts: _core.ModelOptions) -> tuple[np.ndarray, np.ndarray]:
    values, indptr, indices, data = _core.jacobian(corpus, params, beta, opts)
    jac = sp.csr_matrix((data, indices, indptr), shape=(corpus.n_samples, params.size + 1))
    return values, jac.toarray()


def finite_difference_jacobian(corpus: _core.Corpus, params: np.ndarray, beta: float, opts: _core.ModelOptions) -> np.ndarray:
    cols = []
    for k in range(params.size + 1):
        h = 1e-6 * max(1.0, abs(params.flat[k]) if k < params.size else abs(beta))
        up, down = params.copy(), params.copy()
        if k < params.size:
            up.flat[k] += h
            down.flat[k] -= h
            f_up = _core.evaluate(corpus, up, beta, opts)
            f_down = _core.evaluate(corpus, down, beta, opts)
        else:
            f_up = _core.evaluate(corpus, params, beta + h, opts)
            f_down = _core.evaluate(corpus, params, beta - h, opts)
        cols.append((f_up - f_down) / (2 * h))
    return np.column_stack(cols)


def interior_params(rng: np.random.Generator, n: int) -> np.ndarray:
    p = random_params(rng, n)
    p[:, 6] = rng.uniform(0.05, 0.95, n)  # finite differences need room on both sides of k_R
    return p


@pytest.mark.parametrize("variant", ["modified", "original"])
@pytest.mark.parametrize("seed", range(4))
def test_jacobian_matches_finite_differences(variant: str, seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    arrays = random_corpus_arrays(rng, n_utterances=3, n_phonemes=4, segments=(3, 6), samples=40)
    corpus = _core.Corpus(**arrays)
    params = interior_params(rng, 4)
    beta = float(rng.uniform(0.2, 2.0))
    opts = _core.ModelOptions(variant)
    values, jac = jacobian_matrix(corpus, params, beta, opts)
    assert np.allclose(values, _core.evaluate(corpus, params, beta, opts), rtol=1e-13, atol=1e-13)
    fd = finite_difference_jacobian(corpus, params, beta, opts)
    # Central differences have an O(h²) truncation error that is largest where |τ|^c with c < 1
    # bends sharply next to a target time; 1e-5 relative is far above it and far below any bug.
    err = np.abs(jac - fd) / np.maximum(1.0, np.abs(fd))
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() < 1e-5, f"sample {worst[0]}, column {worst[1]}: {jac[worst]} vs FD {fd[worst]}"
    if variant == "original":
        # k_R, σ, ψ and β are not part of eq. 1: their columns are zero.
        for k in (6, 7, 8):
            assert not np.any(jac[:, k : params.size : N_PARAMS])
        assert not np.any(jac[:, -1])


def test_jacobian_sums_a_phoneme_that_occurs_twice() -> None:
    # /# a p a #/ : both /a/ segments feed the same columns.
    rng = np.random.default_rng(9)
    params = interior_params(rng, 3)
    starts = np.array([0.0, 0.1, 0.25, 0.33, 0.5])
    ends = np.array([0.1, 0.25, 0.33, 0.5, 0.6])
    t = np.linspace(0.0, 0.6, 50)
    corpus = _core.Corpus(np.array([0, 5]), np.array([2, 0, 1, 0, 2]), starts, ends, np.array([0, 50]), t, 3)
    _, jac = jacobian_matrix(corpus, params, 1.0, _core.ModelOptions())
    fd = finite_difference_jacobian(corpus, params, 1.0, _core.ModelOptions())
    assert np.max(np.abs(jac - fd) / np.maximum(1.0, np.abs(fd))) < 1e-5
    # With S ≡ 1 the target weights of all segments sum to one (F is a weighted mean).
    p0 = params.copy()
    p0[:, 7] = 0.0
    _, j0 = jacobian_matrix(corpus, p0, 1.0, _core.ModelOptions())
    assert np.allclose(j0[:, 0 : 3 * N_PARAMS : N_PARAMS].sum(axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("variant", ["modified", "original"])
def test_sse_gradient_matches_jacobian_and_finite_differences(variant: str) -> None:
    rng = np.random.default_rng(11)
    arrays = random_corpus_arrays(rng, n_utterances=4, n_phonemes=4, samples=30)
    corpus = _core.Corpus(**arrays)
    params = interior_params(rng, 4)
    beta = 0.8
    opts = _core.ModelOptions(variant)
    observed = rng.normal(5.0, 5.0, corpus.n_samples)
    weights = rng.uniform(0.5, 1.5, corpus.n_samples)
    weights[::7] = 0.0
    observed[::7] = np.nan
    sse, grad, dbeta = _core.sse_gradient(corpus, params, beta, opts, observed, weights)
    values, jac = jacobian_matrix(corpus, params, beta, opts)
    ok = weights > 0
    resid = np.where(ok, values - np.nan_to_num(observed), 0.0)
    assert sse == pytest.approx(float(np.sum(weights * resid**2)), rel=1e-12)
    want = 2.0 * (weights * resid) @ jac
    assert grad.shape == (params.size,)
    assert np.allclose(grad, want[:-1], rtol=1e-10, atol=1e-10 * np.abs(want).max())
    assert dbeta == pytest.approx(want[-1], rel=1e-10, abs=1e-10 * np.abs(want).max())
    # and one direction by finite differences of the SSE itself
    direction = rng.normal(size=params.shape)
    h = 1e-6
    up = _core.sse_gradient(corpus, params + h * direction, beta, opts, observed, weights)[0]
    down = _core.sse_gradient(corpus, params - h * direction, beta, opts, observed, weights)[0]
    assert (up - down) / (2 * h) == pytest.approx(float(grad @ direction.ravel()), rel=1e-5)


def test_gradient_is_finite_at_a_target_time_with_c_below_one() -> None:
    # MODEL.md §4: |τ|^c at τ = 0 with c < 1; ∂/∂c has ln|τ| — the term is 0 there, never NaN.
    params = np.tile(np.array([5.0, 1.0, 30.0, 30.0, 0.6, 0.7, 0.5, 0.1, 50.0, 0.0]), (2, 1))
    params[1, 0] = -3.0
    starts, ends = np.array([0.0, 0.2]), np.array([0.2, 0.4])
    t = np.array([0.1, 0.3, 0.25])  # the first two are exactly the target times
    corpus = _core.Corpus(np.array([0, 2]), np.array([0, 1]), starts, ends, np.array([0, 3]), t, 2)
    for variant in ("modified", "original"):
        _, jac = jacobian_matrix(corpus, params, 1.0, _core.ModelOptions(variant))
        assert np.all(np.isfinite(jac))
