"""A plain NumPy implementation of MODEL.md (evaluation only), the reference for the Rust core.

Written from the spec, one utterance at a time, for clarity rather than speed: every formula
below is a line of MODEL.md §1–3. The benchmark imports it as the "NumPy reference".

``dominance`` selects the time scale of D (docs/VARIANTS.md); "centre" is MODEL.md §2 exactly and
runs the same operations as before the option existed. The other variants replace |τ| inside D by
an effective distance that follows the segment durations d_i = e_i − s_i:

- "segment":  |τ| · d_ref / d_i          (D's reach is measured in units of its own segment)
- "interval": |τ| · d_ref / (t_{i±1} − t_i)  (in units of the distance to the neighbouring target
  on that side; the outer side of the first and last segment uses d_i)
- "plateau":  max(|τ| − h d_i, 0)        (D is flat at α over the middle 2h of its segment and
  decays at a rate fixed in seconds outside it)

d_ref is ``reference_duration`` (s), h is ``plateau_fraction``. R and S are unchanged.

``handover=True`` takes the forward side of D_i (τ > 0) from the *next* segment's phoneme: its
(θ_fw, c_fw) say how fast a phoneme takes over from the one before it (the last segment keeps its
own), as in a gesture model where the incoming gesture's stiffness sets the transition.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

# Column order of the parameter matrix (docs/ARCHITECTURE.md).
TARGET, ALPHA, THETA_BW, THETA_FW, C_BW, C_FW, K_R, SIGMA, PSI, DELTA = range(10)

DOMINANCES = ("centre", "segment", "interval", "plateau")


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


def dominance_distance(
    abs_tau: F64,
    before: npt.NDArray[np.bool_],
    starts: F64,
    ends: F64,
    t_i: F64,
    dominance: str,
    reference_duration: float,
    plateau_fraction: float,
) -> F64:
    """The effective |τ| inside D_i for a rate-following ``dominance`` ([segment, sample])."""
    d = ends - starts
    if dominance == "segment":
        return abs_tau * (reference_duration / d)[:, None]
    if dominance == "interval":
        gap = np.diff(t_i)
        fw = np.append(gap, d[-1])  # t_{i+1} − t_i; the last segment's own duration
        bw = np.insert(gap, 0, d[0])  # t_i − t_{i−1}; the first segment's own duration
        # Coinciding targets (δ clamped both to one boundary) fall back to the own duration.
        fw = np.where(fw > 0.0, fw, d)
        bw = np.where(bw > 0.0, bw, d)
        return abs_tau * reference_duration / np.where(before, bw[:, None], fw[:, None])
    if dominance == "plateau":
        return np.maximum(abs_tau - plateau_fraction * d[:, None], 0.0)
    raise ValueError(f"unknown dominance {dominance!r} (one of {', '.join(DOMINANCES)})")


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
    dominance: str = "centre",
    reference_duration: float = 0.1,
    plateau_fraction: float = 0.5,
    handover: bool = False,
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
    reach = abs_tau if dominance == "centre" else dominance_distance(
        abs_tau, before, starts, ends, t_i, dominance, reference_duration, plateau_fraction)
    fw_rows = np.append(p[1:], p[-1:], axis=0) if handover else p  # (θ_fw, c_fw) of the next segment
    theta = np.where(before, p[:, THETA_BW, None], fw_rows[:, THETA_FW, None])
    c = np.where(before, p[:, C_BW, None], fw_rows[:, C_FW, None])
    log_w = np.log(p[:, ALPHA, None]) - theta * reach**c  # log D_i(τ)
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
    dominance: str = "centre",
    reference_duration: float = 0.1,
    plateau_fraction: float = 0.5,
    handover: bool = False,
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
            dominance,
            reference_duration,
            plateau_fraction,
            handover,
        )
    return out


def evaluate_corpus_arrays(
    params: F64,
    arrays: Mapping[str, Any],
    beta: float = 1.0,
    variant: str = "modified",
    apex_fraction: float = 0.5,
    edge_extent: float = 1.0,
    dominance: str = "centre",
    reference_duration: float = 0.1,
    plateau_fraction: float = 0.5,
    handover: bool = False,
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
        dominance,
        reference_duration,
        plateau_fraction,
        handover,
    )


def evaluate_batch(
    params: F64,
    rows: npt.NDArray[np.int64],
    starts: F64,
    ends: F64,
    times: F64,
    beta: float = 1.0,
    variant: str = "modified",
    apex_fraction: float = 0.5,
    edge_extent: float = 1.0,
    dominance: str = "centre",
    reference_duration: float = 0.1,
    plateau_fraction: float = 0.5,
    handover: bool = False,
) -> F64:
    """``evaluate_utterance`` for B utterances with the same segment count at once.

    ``rows``, ``starts``, ``ends`` are [B, N], ``times`` [B, S] (pad short utterances by repeating a
    time and ignore those samples). The same formulas vectorised over the first axis, for fitting
    variants in NumPy (bench/variants_numpy.py); tested against ``evaluate_utterance``.
    """
    p = np.asarray(params, dtype=np.float64)[np.asarray(rows, dtype=np.intp)]  # [B, N, 10]
    n = p.shape[1]
    t_i = np.clip(starts + apex_fraction * (ends - starts) + p[..., DELTA], starts, ends)
    tau = times[:, None, :] - t_i[:, :, None]  # [B, N, S]
    before = tau <= 0.0
    abs_tau = np.abs(tau)
    d = ends - starts
    if dominance == "centre":
        reach = abs_tau
    elif dominance == "segment":
        reach = abs_tau * (reference_duration / d)[:, :, None]
    elif dominance == "interval":
        gap = np.diff(t_i, axis=1)
        fw = np.concatenate([gap, d[:, -1:]], axis=1)
        bw = np.concatenate([d[:, :1], gap], axis=1)
        fw = np.where(fw > 0.0, fw, d)
        bw = np.where(bw > 0.0, bw, d)
        reach = abs_tau * reference_duration / np.where(before, bw[:, :, None], fw[:, :, None])
    elif dominance == "plateau":
        reach = np.maximum(abs_tau - plateau_fraction * d[:, :, None], 0.0)
    else:
        raise ValueError(f"unknown dominance {dominance!r} (one of {', '.join(DOMINANCES)})")
    fw_rows = np.concatenate([p[:, 1:], p[:, -1:]], axis=1) if handover else p
    theta = np.where(before, p[..., THETA_BW, None], fw_rows[..., THETA_FW, None])
    c = np.where(before, p[..., C_BW, None], fw_rows[..., C_FW, None])
    log_w = np.log(p[..., ALPHA, None]) - theta * reach**c
    numerator_scale: F64 | float = 1.0
    if variant == "modified":
        k_r = p[..., K_R]
        fw_e = np.empty_like(t_i)
        bw_e = np.empty_like(t_i)
        fw_e[:, n - 1] = edge_extent
        for i in range(n - 2, -1, -1):
            fw_e[:, i] = (t_i[:, i + 1] - t_i[:, i]) + (1.0 - k_r[:, i + 1]) * fw_e[:, i + 1]
        bw_e[:, 0] = edge_extent
        for i in range(1, n):
            bw_e[:, i] = (t_i[:, i] - t_i[:, i - 1]) + (1.0 - k_r[:, i - 1]) * bw_e[:, i - 1]
        extent = np.where(before, bw_e[:, :, None], fw_e[:, :, None])
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(abs_tau == 0.0, 0.0, abs_tau / extent)
            log_r = np.where(u < 1.0, -beta * u / (1.0 - u), -np.inf)
        log_r[:, n - 1] = np.where(before[:, n - 1], log_r[:, n - 1], 0.0)
        log_r[:, 0] = np.where(before[:, 0], 0.0, log_r[:, 0])
        log_w = log_w + log_r
        numerator_scale = 1.0 + p[..., SIGMA, None] * np.exp(-p[..., PSI, None] * tau**2)
    elif variant != "original":
        raise ValueError(f"unknown variant {variant!r}")
    w = np.exp(log_w - log_w.max(axis=1, keepdims=True))
    return np.sum(p[..., TARGET, None] * numerator_scale * w, axis=1) / np.sum(w, axis=1)  # type: ignore[no-any-return]
