"""statsmodels' binomial GLMM (BinomialBayesMixedGLM, variational Bayes) for random intercepts only,
its random-effect sums taken from the level codes instead of scipy.sparse products.

The perceive analysis fits it once per study and once per jackknife group (coartic.perceive.analysis).
Its random-effect design has exactly one 1 per row and grouping (participant, item): statsmodels
multiplies it as a sparse matrix, 30 products per gradient, whose set-up costs far more than the
few hundred additions each does (two thirds of an analysis' CPU). Here the same sums are formed
by indexing and np.bincount in the order scipy's kernels add them (each row's groupings left to
right; each column's rows top to bottom; the same products), so the fit is statsmodels' bit for bit
(tests/python/test_perceive_analysis.py compares the two), about three times faster.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import sparse
from statsmodels.genmod.bayes_mixed_glm import BinomialBayesMixedGLM, glw

from coartic.errors import UsageError

F64 = npt.NDArray[np.float64]


class InterceptsBinomialGLMM(BinomialBayesMixedGLM):  # type: ignore[misc]  # statsmodels ships no types
    """BinomialBayesMixedGLM whose `exog_vc` holds indicator columns only: each row a single 1 in
    each grouping's block of columns (the blocks in column order). Anything else is refused."""

    def __init__(self, endog: Any, exog: Any, exog_vc: Any, ident: Any, **kwargs: Any) -> None:
        super().__init__(endog, exog, exog_vc, ident, **kwargs)
        vc = sparse.csr_array(self.exog_vc, copy=True)
        vc.sort_indices()
        n_obs, n_blocks = vc.shape[0], int(np.max(ident)) + 1
        if not (np.all(np.diff(vc.indptr) == n_blocks) and np.all(vc.data == 1.0)
                and np.all(np.asarray(ident)[vc.indices.reshape(n_obs, n_blocks)] == np.arange(n_blocks))):
            raise UsageError("exog_vc must hold one indicator column per level of each grouping, a single 1 per row "
                             "and grouping")
        self._cols = vc.indices.reshape(n_obs, n_blocks).astype(np.intp)  # row i's column in each grouping
        self._flat = self._cols.ravel()

    def _row_sums(self, v: F64) -> F64:
        """exog_vc @ v: each row's entries added left to right (scipy's CSR product, from 0)."""
        out: F64 = 0.0 + v[self._cols[:, 0]]
        for b in range(1, self._cols.shape[1]):
            out += v[self._cols[:, b]]
        return out

    def _column_sums(self, w: F64, scale: F64 | None = None) -> F64:
        """exog_vc.T @ w (or, with `scale`, exog_vc2.multiply(scale).T @ w): each column's rows added
        top to bottom, from 0 (scipy's CSC product; np.bincount adds in index order)."""
        weights = np.repeat(w, self._cols.shape[1])
        if scale is not None:
            weights = scale[self._flat] * weights
        return np.bincount(self._flat, weights=weights, minlength=self.k_vc).astype(np.float64, copy=False)

    def _lp_stats(self, fep_mean: F64, fep_sd: F64, vc_mean: F64, vc_sd: F64) -> tuple[F64, F64]:
        tm = np.dot(self.exog, fep_mean)
        tv = np.dot(self.exog**2, fep_sd**2)
        tm += self._row_sums(vc_mean)
        tv += self._row_sums(vc_sd**2)
        return tm, tv

    def vb_elbo_grad_base(self, h: Any, tm: F64, tv: F64, fep_mean: F64, vcp_mean: F64, vc_mean: F64,
                          fep_sd: F64, vcp_sd: F64, vc_sd: F64) -> tuple[F64, F64]:
        """statsmodels 0.14-0.15's _VariationalBayesMixedGLM.vb_elbo_grad_base, line for line, with
        its sparse products replaced by _column_sums."""
        fep_mean_grad: Any = 0.0
        fep_sd_grad: Any = 0.0
        vc_mean_grad: Any = 0.0
        vc_sd_grad: Any = 0.0

        # p(y | vc) contributions
        for w in glw:
            z = self.rng * w[1]
            u = h(z) * np.exp(-(z**2) / 2) / np.sqrt(2 * np.pi)
            r = u / np.sqrt(tv)
            fep_mean_grad += w[0] * np.dot(u, self.exog)
            vc_mean_grad += w[0] * self._column_sums(u)
            fep_sd_grad += w[0] * z * np.dot(r, self.exog**2 * fep_sd)
            vc_sd_grad += w[0] * z * self._column_sums(r, vc_sd)

        fep_mean_grad *= self.rng
        vc_mean_grad *= self.rng
        fep_sd_grad *= self.rng
        vc_sd_grad *= self.rng
        fep_mean_grad += np.dot(self.endog, self.exog)
        vc_mean_grad += self._column_sums(np.asarray(self.endog, dtype=float))

        fm, fs, vm, vs, cm, cs = self._elbo_grad_common(fep_mean, fep_sd, vcp_mean, vcp_sd, vc_mean, vc_sd)
        fep_mean_grad += fm
        fep_sd_grad += fs
        vcp_mean_grad = 0.0 + vm  # statsmodels adds to 0.0 too
        vcp_sd_grad = 0.0 + vs
        vc_mean_grad += cm
        vc_sd_grad += cs

        fep_sd_grad += 1 / fep_sd
        vcp_sd_grad += 1 / vcp_sd
        vc_sd_grad += 1 / vc_sd

        mean_grad = np.concatenate((fep_mean_grad, vcp_mean_grad, vc_mean_grad))
        sd_grad = np.concatenate((fep_sd_grad, vcp_sd_grad, vc_sd_grad))
        return mean_grad, sd_grad
