"""A plain NumPy implementation of MODEL.md (evaluation only), the reference for the Rust core.

Written from the spec, one utterance at a time, for clarity rather than speed: every formula
below is a line of MODEL.md §1–3. The benchmark imports it as the "NumPy reference".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

# Column order of the parameter matrix (docs/ARCHITECTURE.md).
TARGET, ALPHA, THETA_BW, THETA_FW, C_BW, C_FW, K_R, SIGMA, PSI, DELTA = range(10)


def target_times(starts: F64, ends: F64, delta: F64, apex_fraction: float) -> F64:
    """t_i = s_i + a (e_i − s_i) + δ_p(i), clamped into [s_i, e_i] (MODEL.md §1)."""
    t = starts + apex_fraction * (ends - starts) + delta
    return np.clip(t, starts, ends)


def extents(t: F64, k_r: F64, edge_extent: float) -> tuple[F64, F64]:
    """Forward and backward extents Δ⁺, Δ⁻ with the k_R recursion (MODEL.md §3.1)."""
    n = len(t)
    fw = np.empty(n)
    bw = np.empty(n)
    fw[n - 1] = edge_extent
    for i in range(n - 2, -1, -1):
        fw[i] = (t[i + 1] - t[i]) + (1.0 - k_r[i + 1]) * fw[i + 1]
    bw[0] = edge_extent
    for i in range(1, n):
        bw[i] = (t[i] - t[i - 1]) + (1.0 - k_r[i - 1]) * bw[i - 1]
    return fw, bw


def log_rho(u: F64, beta: float) -> F64:
    """log ρ(u): −β u / (1 − u) for 0 ≤ u < 1, −∞ for u ≥ 1."""
    out = np.full(u.shape, -np.inf)
    inside = u < 1.0
    out[inside] = -beta * u[inside] / (1.0 - u[inside])
    return out


def evaluate_utterance(
    params: F64,
    rows: Sequence[int] | npt.NDArray[np.int64],
    starts: F64,
    ends: F64,
    times: F64,
    beta: float = 1.0,
    variant: str = "modified",
    apex_fraction: float = 0.5,
    edge_extent: float = 1.0,
) -> F64:
    """F(t) of eq. 1 (variant "original") or eq. 3 (variant "modified") at ``times``.

    ``params`` is the [n_phonemes, 10] matrix, ``rows[i]`` the phoneme row of segment i.
    """
    p = np.asarray(params, dtype=np.float64)[np.asarray(rows, dtype=np.intp)]
    starts = np.asarray(starts, dtype=np.float64)
    ends = np.asarray(ends, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    n = len(p)
    t_i = target_times(starts, ends, p[:, DELTA], apex_fraction)
    tau = times[None, :] - t_i[:, None]  # [segment, sample]
    before = tau <= 0.0
    abs_tau = np.abs(tau)
    theta = np.where(before, p[:, THETA_BW, None], p[:, THETA_FW, None])
    c = np.where(before, p[:, C_BW, None], p[:, C_FW, None])
    log_w = np.log(p[:, ALPHA, None]) - theta * abs_tau**c  # log D_i(τ)
    numerator_scale = np.ones_like(tau)
    if variant == "modified":
        fw, bw = extents(t_i, p[:, K_R], edge_extent)
        extent = np.where(before, bw[:, None], fw[:, None])
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(abs_tau == 0.0, 0.0, abs_tau / extent)
        log_r = log_rho(u, beta)
        # The forward R of the last segment and the backward R of the first are identically 1.
        log_r[n - 1, ~before[n - 1]] = 0.0
        log_r[0, before[0]] = 0.0
        log_w = log_w + log_r
        numerator_scale = 1.0 + p[:, SIGMA, None] * np.exp(-p[:, PSI, None] * tau**2)  # S_i(τ)
    elif variant != "original":
        raise ValueError(f"unknown variant {variant!r}")
    # Log-sum-exp normalisation: the weights never all underflow to 0/0.
    w = np.exp(log_w - log_w.max(axis=0, keepdims=True))
    return np.sum(p[:, TARGET, None] * numerator_scale * w, axis=0) / np.sum(w, axis=0)


def evaluate_corpus(
    params: F64,
    seg_offsets: npt.NDArray[np.int64],
    seg_phoneme: npt.NDArray[np.int64],
    seg_start: F64,
    seg_end: F64,
    sample_offsets: npt.NDArray[np.int64],
    sample_times: F64,
    beta: float = 1.0,
    variant: str = "modified",
    apex_fraction: float = 0.5,
    edge_extent: float = 1.0,
) -> F64:
    """The whole corpus (CSR layout of docs/ARCHITECTURE.md), utterance by utterance."""
    out = np.empty(len(sample_times))
    for u in range(len(seg_offsets) - 1):
        a, b = seg_offsets[u], seg_offsets[u + 1]
        c, d = sample_offsets[u], sample_offsets[u + 1]
        out[c:d] = evaluate_utterance(
            params,
            seg_phoneme[a:b],
            seg_start[a:b],
            seg_end[a:b],
            sample_times[c:d],
            beta,
            variant,
            apex_fraction,
            edge_extent,
        )
    return out


def evaluate_corpus_arrays(
    params: F64,
    arrays: Mapping[str, Any],
    beta: float = 1.0,
    variant: str = "modified",
    apex_fraction: float = 0.5,
    edge_extent: float = 1.0,
) -> F64:
    """``evaluate_corpus`` on the keyword arrays of ``coartic._core.Corpus`` (as a dict)."""
    return evaluate_corpus(
        params,
        arrays["seg_offsets"],
        arrays["seg_phoneme"],
        arrays["seg_start"],
        arrays["seg_end"],
        arrays["sample_offsets"],
        arrays["sample_times"],
        beta,
        variant,
        apex_fraction,
        edge_extent,
    )
