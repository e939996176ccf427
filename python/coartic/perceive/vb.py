"""statsmodels' binomial GLMM (BinomialBayesMixedGLM, variational Bayes) for random intercepts only,
its random-effect sums taken from the level codes instead of scipy.sparse products.

The perceive analysis fits it once per study and once per jackknife group (coartic.perceive.analysis).
Its random-effect design has exactly one 1 per row and grouping (participant, item): statsmodels
multiplies it as a sparse matrix, 30 products per gradient, whose set-up costs far more than the
few hundred additions each does (two thirds of an analysis' CPU). Here the same sums are formed
by indexing and np.bincount in the order scipy's kernels add them (each row's groupings left to
right; each column's rows top to bottom; the same products), so the fit is statsmodels' bit for bit
(tests/python/test_perceive_analysis.py compares the two), about three times faster.

The ELBO and its gradient integrate over the linear predictor at the ten Gauss-Legendre points
(`glw`): statsmodels computes each point's values and sums one point after the other, a dozen small
NumPy calls each. Here every point's elementwise values are computed in one call on a (points, rows)
array (the same operations on the same numbers, so the same bits) and only the sums over the
points, whose order sets the bits, run one point after the other as statsmodels adds them: the 14
analyses of test_perceive_analysis' calibration and planted-effect sizes 10.2 -> 7.7 CPU-s, every
estimate and interval the same to the bit.
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
        """exog_vc.T @ w (or, with `scale`, exog_vc2.multiply(scale).T @ w) for each row of `w`
        (points, rows), or for a 1-D `w`: each column's rows added top to bottom, from 0 (scipy's
        CSC product; np.bincount adds in index order, and row k's columns are its bins k * k_vc ...)."""
        rows = np.atleast_2d(w)
        n = rows.shape[0]
        weights = np.repeat(rows, self._cols.shape[1], axis=1)
        if scale is not None:
            weights = scale[self._flat] * weights
        bins = (self._flat + self.k_vc * np.arange(n)[:, None]).ravel()
        sums = np.bincount(bins, weights=weights.ravel(), minlength=n * self.k_vc).astype(np.float64, copy=False)
        return sums.reshape(n, self.k_vc)[0] if w.ndim == 1 else sums.reshape(n, self.k_vc)

    def _points(self) -> tuple[list[float], F64]:
        """Each Gauss-Legendre point's z = rng * node and its exp(-z²/2), computed as statsmodels
        does (Python floats; NumPy's exp of each), and those factors as a column."""
        z = [self.rng * w[1] for w in glw]
        return z, np.array([np.exp(-(zk**2) / 2) for zk in z])[:, None]

    def _predictor(self, tm: F64, tv: F64, z: list[float]) -> F64:
        """tm + sqrt(tv) * z at every point `z`, a (points, rows) array: statsmodels' h(z) computes
        its rows."""
        u: F64 = tm + np.sqrt(tv) * np.array(z)[:, None]
        return u

    def vb_elbo(self, vb_mean: F64, vb_sd: F64) -> Any:
        """statsmodels' BinomialBayesMixedGLM.vb_elbo with vb_elbo_base's sum over the points
        (below), h(z) = -log(1 + exp(tm + sqrt(tv) z)) computed at every point at once."""
        fep_mean, vcp_mean, vc_mean = self._unpack(vb_mean)
        fep_sd, vcp_sd, vc_sd = self._unpack(vb_sd)
        tm, tv = self._lp_stats(fep_mean, fep_sd, vc_mean, vc_sd)
        z, gauss = self._points()
        hz = -np.log(1 + np.exp(self._predictor(tm, tv, z)))

        # statsmodels 0.14-0.15's _VariationalBayesMixedGLM.vb_elbo_base, line for line, h(z) from hz
        iv: Any = 0
        for k, w in enumerate(glw):
            iv += w[0] * hz[k] * gauss[k, 0]
        iv /= np.sqrt(2 * np.pi)
        iv *= self.rng
        iv += self.endog * tm
        iv = iv.sum()
        iv += self._elbo_common(fep_mean, fep_sd, vcp_mean, vcp_sd, vc_mean, vc_sd)
        return iv + np.sum(np.log(fep_sd)) + np.sum(np.log(vcp_sd)) + np.sum(np.log(vc_sd))

    def vb_elbo_grad(self, vb_mean: F64, vb_sd: F64) -> tuple[F64, F64]:
        """statsmodels' BinomialBayesMixedGLM.vb_elbo_grad: its h(z), the negated logistic of
        tm + sqrt(tv) z (each sign's formula where statsmodels uses it), at every point at once."""
        fep_mean, vcp_mean, vc_mean = self._unpack(vb_mean)
        fep_sd, vcp_sd, vc_sd = self._unpack(vb_sd)
        tm, tv = self._lp_stats(fep_mean, fep_sd, vc_mean, vc_sd)
        u = self._predictor(tm, tv, self._points()[0])
        x = np.zeros_like(u)
        pos = u > 0
        uu = u[pos]
        x[pos] = 1 / (1 + np.exp(-uu))
        neg = u <= 0
        uu = u[neg]
        x[neg] = np.exp(uu) / (1 + np.exp(uu))
        return self.vb_elbo_grad_base(-x, tm, tv, fep_mean, vcp_mean, vc_mean, fep_sd, vcp_sd, vc_sd)

    def _lp_stats(self, fep_mean: F64, fep_sd: F64, vc_mean: F64, vc_sd: F64) -> tuple[F64, F64]:
        tm = np.dot(self.exog, fep_mean)
        tv = np.dot(self.exog**2, fep_sd**2)
        tm += self._row_sums(vc_mean)
        tv += self._row_sums(vc_sd**2)
        return tm, tv

    def vb_elbo_grad_base(self, hz: F64, tm: F64, tv: F64, fep_mean: F64, vcp_mean: F64, vc_mean: F64,
                          fep_sd: F64, vcp_sd: F64, vc_sd: F64) -> tuple[F64, F64]:
        """statsmodels 0.14-0.15's _VariationalBayesMixedGLM.vb_elbo_grad_base, line for line, with
        its sparse products replaced by _column_sums, h(z) given at every point (`hz`, a row per
        point of `glw`) and each point's elementwise values and column sums computed for all points
        at once; the points' contributions are added one after the other, as statsmodels does."""
        fep_mean_grad: Any = 0.0
        fep_sd_grad: Any = 0.0
        vc_mean_grad: Any = 0.0
        vc_sd_grad: Any = 0.0

        # p(y | vc) contributions
        z, gauss = self._points()
        u = hz * gauss / np.sqrt(2 * np.pi)
        r = u / np.sqrt(tv)
        u_sums = self._column_sums(u)
        r_sums = self._column_sums(r, vc_sd)
        x2_sd = self.exog**2 * fep_sd
        for k, w in enumerate(glw):
            fep_mean_grad += w[0] * np.dot(u[k], self.exog)
            vc_mean_grad += w[0] * u_sums[k]
            fep_sd_grad += w[0] * z[k] * np.dot(r[k], x2_sd)
            vc_sd_grad += w[0] * z[k] * r_sums[k]

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
