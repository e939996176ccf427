"""The Jacobian's pattern/values split: ``Corpus.jacobian_pattern`` once, ``jacobian_values`` into
the caller's buffers, and ``coartic.jacobian.JacobianBuffer`` on top. Equal bit for bit to ``jacobian``;
buffers really filled in place; every unusable buffer refused with a message naming it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import scipy.sparse as sp  # type: ignore[import-untyped]
from conftest import random_corpus_arrays, random_params

from coartic import _core
from coartic.jacobian import JacobianBuffer

OPTS = _core.ModelOptions()


def address(a: np.ndarray) -> int:
    return int(a.__array_interface__["data"][0])


def small() -> tuple[_core.Corpus, np.ndarray]:
    rng = np.random.default_rng(7)
    corpus = _core.Corpus(**random_corpus_arrays(rng, n_utterances=3, n_phonemes=4, samples=30))
    return corpus, random_params(rng, 4)


@pytest.mark.parametrize("variant", ["modified", "original"])
@pytest.mark.parametrize("seed", range(3))
def test_values_and_pattern_equal_the_full_jacobian_bit_for_bit(variant: str, seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    # Few phonemes, many segments: phonemes repeat within utterances (summed columns).
    corpus = _core.Corpus(**random_corpus_arrays(rng, n_utterances=5, n_phonemes=3, segments=(2, 9), samples=50))
    params = random_params(rng, 3)
    beta = float(rng.uniform(0.2, 2.0))
    opts = _core.ModelOptions(variant)
    values, indptr, indices, data = _core.jacobian(corpus, params, beta, opts)
    p_indptr, p_indices = corpus.jacobian_pattern()
    assert p_indptr.dtype == p_indices.dtype == np.int64
    assert np.array_equal(p_indptr, indptr) and np.array_equal(p_indices, indices)
    assert corpus.jacobian_nnz == data.size == indptr[-1]
    v, d = _core.jacobian_values(corpus, params, beta, opts)
    assert v.tobytes() == values.tobytes() and d.tobytes() == data.tobytes()
    v_buf, d_buf = np.full(corpus.n_samples, np.nan), np.full(corpus.jacobian_nnz, np.nan)
    _core.jacobian_values(corpus, params, beta, opts, v_buf, d_buf)
    assert v_buf.tobytes() == values.tobytes() and d_buf.tobytes() == data.tobytes()


def test_buffers_are_filled_in_place_and_returned_as_given() -> None:
    corpus, params = small()
    v_buf, d_buf = np.empty(corpus.n_samples), np.empty(corpus.jacobian_nnz)
    addresses = (address(v_buf), address(d_buf))
    for beta in (0.5, 1.5):  # a second call with other values: same memory, new contents
        v, d = _core.jacobian_values(corpus, params, beta, OPTS, v_buf, d_buf)
        assert v is v_buf and d is d_buf
        assert (address(v_buf), address(d_buf)) == addresses
        want_v, _, _, want_d = _core.jacobian(corpus, params, beta, OPTS)
        assert np.array_equal(v_buf, want_v) and np.array_equal(d_buf, want_d)
    # One buffer given, the other allocated.
    v, d = _core.jacobian_values(corpus, params, 1.0, OPTS, data_out=d_buf)
    assert d is d_buf and v is not v_buf and v.shape == (corpus.n_samples,)


def test_pattern_is_built_once_and_read_only() -> None:
    corpus, _ = small()
    indptr, indices = corpus.jacobian_pattern()
    again = corpus.jacobian_pattern()
    assert again[0] is indptr and again[1] is indices
    for a in (indptr, indices):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 1


def test_empty_corpus() -> None:
    empty = _core.Corpus(np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0),
                         np.zeros(1, dtype=np.int64), np.zeros(0), 2)
    indptr, indices = empty.jacobian_pattern()
    assert indptr.tolist() == [0] and indices.size == 0 and empty.jacobian_nnz == 0
    v, d = _core.jacobian_values(empty, random_params(np.random.default_rng(0), 2), 1.0, OPTS)
    assert v.shape == d.shape == (0,)


def strided(n: int) -> np.ndarray:
    return np.empty(2 * n)[::2]


def read_only(n: int) -> np.ndarray:
    a = np.empty(n)
    a.setflags(write=False)
    return a


def misaligned(n: int) -> np.ndarray:
    return np.frombuffer(bytearray(8 * n + 1), dtype=np.float64, count=n, offset=1)


# (argument, buffer from its required length, exception, message)
BAD: list[tuple[str, Callable[[int], Any], type[Exception], str]] = [
    ("values_out", lambda n: np.empty(n, dtype=np.float32), TypeError,
     r"'values_out' must be a numpy.ndarray of dtype float64 to fill in place, got an array of dtype float32"),
    ("data_out", lambda n: [0.0] * n, TypeError, r"'data_out' must be a numpy.ndarray .* got list; pass numpy.empty"),
    ("data_out", lambda n: np.empty(n - 1), ValueError, r"'data_out' has shape \(\d+,\), expected \(\d+,\) = \[corpus.jacobian_nnz\]"),
    ("values_out", lambda n: np.empty((n, 1)), ValueError, r"'values_out' has shape \(\d+, 1\), expected \(\d+,\) = \[n_samples"),
    ("data_out", strided, ValueError, r"'data_out' is not C-contiguous"),
    ("values_out", read_only, ValueError, r"'values_out' is read-only"),
    ("data_out", misaligned, ValueError, r"'data_out' is not aligned to 8 bytes"),
]


@pytest.mark.parametrize(("name", "make", "exc", "pattern"), BAD)
def test_unusable_buffer_is_refused_naming_it(name: str, make: Callable[[int], Any], exc: type[Exception], pattern: str) -> None:
    corpus, params = small()
    length = {"values_out": corpus.n_samples, "data_out": corpus.jacobian_nnz}[name]
    # The other buffer is given too: a refusal must leave it untouched.
    other = "data_out" if name == "values_out" else "values_out"
    other_buf = np.full({"values_out": corpus.n_samples, "data_out": corpus.jacobian_nnz}[other], 7.0)
    with pytest.raises(exc, match=pattern):
        _core.jacobian_values(corpus, params, 1.0, OPTS, **{name: make(length), other: other_buf})
    assert np.all(other_buf == 7.0)


def test_buffers_sharing_memory_are_refused() -> None:
    corpus, params = small()
    n, nnz = corpus.n_samples, corpus.jacobian_nnz
    block = np.zeros(params.size + n + nnz)
    block[: params.size] = params.ravel()
    p_view = block[: params.size].reshape(params.shape)
    # Disjoint views of one block are fine...
    v, d = _core.jacobian_values(corpus, p_view, 1.0, OPTS, block[params.size : params.size + n], block[params.size + n :])
    assert np.array_equal(d, _core.jacobian(corpus, params, 1.0, OPTS)[3])
    # ...overlapping ones are not: the core would read params while writing over them.
    with pytest.raises(ValueError, match=r"'values_out' shares memory with another argument"):
        _core.jacobian_values(corpus, p_view, 1.0, OPTS, block[params.size - 1 : params.size - 1 + n], block[params.size + n :])
    with pytest.raises(ValueError, match=r"'data_out' shares memory with another argument"):
        _core.jacobian_values(corpus, p_view, 1.0, OPTS, block[params.size : params.size + n], block[params.size + n - 1 : -1])


def test_invalid_parameters_name_the_parameter() -> None:
    corpus, params = small()
    params[1, 2] = -1.0  # theta_bw must be > 0
    with pytest.raises(ValueError, match=r"phoneme 1.*theta_bw"):
        _core.jacobian_values(corpus, params, 1.0, OPTS, np.empty(corpus.n_samples), np.empty(corpus.jacobian_nnz))
    with pytest.raises(ValueError, match=r"'params' has shape \(3, 10\)"):
        _core.jacobian_values(corpus, params[:3], 1.0, OPTS)


def test_jacobian_buffer_refills_one_matrix() -> None:
    corpus, params = small()
    buf = JacobianBuffer(corpus)
    first_values, first = buf.compute(params, 1.0, OPTS)
    assert first.data is buf.data and first_values is buf.values
    before = first.toarray()
    values, indptr, indices, data = _core.jacobian(corpus, params, 1.0, OPTS)
    want = sp.csr_matrix((data, indices, indptr), shape=first.shape)
    assert np.array_equal(before, want.toarray()) and np.array_equal(first_values, values)
    other = params.copy()
    other[:, 0] += 3.0  # targets enter linearly: the target columns keep their values, F moves
    other[:, 1] *= 1.5
    values2, second = buf.compute(other, 0.7, OPTS)
    assert second is first and values2 is first_values and address(second.data) == address(buf.data)
    want2 = _core.jacobian(corpus, other, 0.7, OPTS)
    assert np.array_equal(second.toarray(), sp.csr_matrix((want2[3], want2[2], want2[1]), shape=first.shape).toarray())
    assert not np.array_equal(second.toarray(), before)
