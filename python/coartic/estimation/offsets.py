"""Per-utterance offsets (spec ``[model] offsets``), profiled out of least squares (``Offsets``)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from coartic.estimation.data import ChannelData

FloatArray = NDArray[np.float64]


class Offsets:
    """Per-utterance offsets b_u (a constant added to the model over utterance u), profiled out of
    least squares: for given model parameters each b_u has a closed form, so the engines see the
    same parameters as without offsets and the offsets cost no extra variables.

    With r = sqrt(w)(F − y), S_u = Σ_u sqrt(w) r, W_u = Σ_u w and a Gaussian random effect
    b_u ~ N(0, τ²) (``lam`` = noise²/τ²; 0 for free offsets), the minimiser is b_u = −S_u/(W_u + lam),
    the residuals become r + sqrt(w) b_u, plus one row sqrt(lam) b_u per utterance. All of it is
    linear in r, so the exact Jacobian is J + sqrt(w)·db/dx with db/dx = −A J
    (A[u, i] = sqrt(w_i)/(W_u + lam) on utterance u's samples), and the profiled SSE is
    SSE − Σ_u S_u²/(W_u + lam) (what the MCMC likelihood integrates, MODEL.md §5 / docs/MCMC.md).
    """

    def __init__(self, data: ChannelData, lam: float) -> None:
        n_utt = len(data.utterances)
        self.n_utt = n_utt
        self.utt = np.repeat(np.arange(n_utt), np.diff(data.sample_offsets)).astype(np.int64)
        self.sqrt_w = np.sqrt(data.weights)
        self.weight = np.bincount(self.utt, weights=data.weights, minlength=n_utt)
        self.lam = float(lam)
        denom = self.weight + self.lam
        self.inv = np.where(denom > 0, 1.0 / np.where(denom > 0, denom, 1.0), 0.0)
        n = self.utt.size
        self.A = sp.csr_matrix((self.sqrt_w * self.inv[self.utt], (self.utt, np.arange(n))), shape=(n_utt, n))
        self.S = sp.csr_matrix((self.sqrt_w, (np.arange(n), self.utt)), shape=(n, n_utt))

    @property
    def extra_rows(self) -> int:
        return self.n_utt if self.lam > 0 else 0

    def offsets(self, r: FloatArray) -> FloatArray:
        """b_u for the weighted residuals r = sqrt(w)(F − y)."""
        sums = np.bincount(self.utt, weights=self.sqrt_w * r, minlength=self.n_utt).astype(np.float64)
        return -sums * self.inv

    def residuals(self, r: FloatArray) -> FloatArray:
        b = self.offsets(r)
        out = r + self.sqrt_w * b[self.utt]
        return np.concatenate([out, np.sqrt(self.lam) * b]) if self.lam > 0 else out

    def jacobian(self, j: sp.csr_matrix) -> sp.csr_matrix:
        db = -(self.A @ j)
        out = j + self.S @ db
        if self.lam > 0:
            out = sp.vstack([out, np.sqrt(self.lam) * db])
        return sp.csr_matrix(out)

    def profiled_sse(self, sse: FloatArray, sums: FloatArray) -> FloatArray:
        """From the core's SSE [W] and Σ_u w (y − F) [W, n_utt]: the SSE with the offsets profiled out."""
        return np.asarray(sse - np.sum(sums**2 * self.inv[None, :], axis=1), dtype=np.float64)
