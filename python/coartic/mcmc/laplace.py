"""The Laplace approximation of a posterior as an independence proposal (the "de+laplace" moves).

Built once, before the first step, from the log-posterior alone: each coordinate with finite
bounds is mapped to z = logit((x - lo)/(hi - lo)) (unbounded ones stay as they are), the
log-density in z (the posterior's plus log |dx/dz|) is maximised by Newton steps from the start
point, and the proposal is a multivariate Student t (``NU`` degrees of freedom) in z centred at
that mode with the inverse of the negated Hessian there (central finite differences, batched into
one log-posterior call per Newton step) as its scale matrix.

Why z and t: on the posteriors of a channel several coordinates sit at or near a bound (k_R = 1,
an offset sd near 0) where the posterior in x is cut off; in z those coordinates have tails, not
edges, and every proposal is inside the support. The t's polynomial tails are heavier than the
posterior's in z (Gaussian inside, at most exponential towards a bound), so the ratio
posterior/proposal is bounded and the independence sampler is uniformly ergodic where the
approximation is poor, only slower.

The move (``sampler._Ensemble``): every walker proposes x' ~ q independently of where it is and
accepts with probability min(1, π(x') q(x) / (π(x) q(x'))): Metropolis–Hastings with a fixed
proposal, so each walker's kernel satisfies detailed balance with π, and the product of the walkers'
targets (the ensemble's stationary distribution) is left invariant. The sampler chooses this move
or emcee's differential-evolution move at random with fixed weights each step; a mixture of
π-invariant kernels with state-independent weights is π-invariant. Proposals whose z lies beyond
``Z_LIMIT`` (where 1/(1 + e^z) rounds x onto its bound) are rejected without evaluating them: a
valid MH step with the target's density treated as zero there, where it is below 1e-13 of the
bound's neighbourhood.

The proposal depends only on the posterior and the start point, and is saved with the chains
(``proposal.npz``), so a resumed run uses the very same proposal.
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from coartic.mcmc.errors import ChainError, McmcError
from coartic.outputs import atomic_path

FloatArray = NDArray[np.float64]
LogProb = Callable[[FloatArray], FloatArray]

NU = 4.0  # degrees of freedom of the t: heavy tails (a Gaussian posterior accepts ~43 % in 26 dimensions)
Z_LIMIT = 30.0
NEWTON_STEPS = 8
EDGE = 1e-3  # the start is moved at least this fraction of the width inside a finite bound
FILE = "proposal.npz"


class ProposalError(McmcError):
    """The Laplace approximation could not be built (the log-posterior not finite around the mode)."""


@dataclass
class LaplaceProposal:
    """A multivariate t in z (module docstring): mode ``mu``, Cholesky factor ``chol`` of its
    scale matrix, the bounds that define z (``bounded`` coordinates only) and ``nu``."""

    mu: FloatArray
    chol: FloatArray
    lower: FloatArray
    upper: FloatArray
    bounded: NDArray[np.bool_]
    nu: float = NU

    def __post_init__(self) -> None:
        self._inv = np.linalg.inv(self.chol)
        self._width = np.where(self.bounded, self.upper - self.lower, 1.0)
        self._lo = np.where(self.bounded, self.lower, 0.0)
        self._log_norm = float(np.sum(np.log(np.diag(self.chol))))

    @property
    def dim(self) -> int:
        return int(self.mu.size)

    # --- the map between x and z --------------------------------------------------------------
    def to_z(self, x: FloatArray) -> FloatArray:
        p = np.clip((x - self._lo) / self._width, 1e-300, 1.0 - 1e-16)
        return np.where(self.bounded, np.log(p) - np.log1p(-p), x)

    def to_x(self, z: FloatArray) -> FloatArray:
        return np.where(self.bounded, self._lo + self._width * 0.5 * (1.0 + np.tanh(0.5 * z)), z)

    def log_jacobian(self, z: FloatArray) -> FloatArray:
        """log |dx/dz| summed over coordinates, per row of z."""
        per = np.log(self._width) - np.logaddexp(0.0, z) - np.logaddexp(0.0, -z)
        return np.asarray(np.sum(np.where(self.bounded, per, 0.0), axis=-1), dtype=np.float64)

    # --- the proposal -------------------------------------------------------------------------
    def draw(self, random: np.random.RandomState, n: int) -> tuple[FloatArray, NDArray[np.bool_]]:
        """``n`` proposals in x and which of them lie inside ``Z_LIMIT`` (the others are rejected),
        from ``random`` (the ensemble's generator: n x dim normals, then n chi-squares)."""
        normal = random.standard_normal((n, self.dim))
        scale = np.sqrt(random.chisquare(self.nu, n) / self.nu)
        z = self.mu + (normal @ self.chol.T) / scale[:, None]
        inside = np.all(np.abs(np.where(self.bounded, z, 0.0)) <= Z_LIMIT, axis=1)
        return self.to_x(np.where(inside[:, None], z, self.mu)), inside

    def log_density(self, x: FloatArray) -> FloatArray:
        """log q(x) up to a constant (the t's density in z times |dz/dx|)."""
        z = self.to_z(np.atleast_2d(x))
        y = (z - self.mu) @ self._inv.T
        t = -0.5 * (self.nu + self.dim) * np.log1p(np.sum(y * y, axis=1) / self.nu)
        return np.asarray(t - self.log_jacobian(z) - self._log_norm, dtype=np.float64)

    # --- storage ------------------------------------------------------------------------------
    def save(self, directory: Path) -> Path:
        path = directory / FILE
        with atomic_path(path) as tmp:
            np.savez(tmp, mu=self.mu, chol=self.chol, lower=self.lower, upper=self.upper, bounded=self.bounded,
                     nu=np.array([self.nu]))
        return path

    @classmethod
    def load(cls, directory: Path, dim: int) -> LaplaceProposal | None:
        """The proposal saved with the chains in ``directory``; None if it could not be built then
        (``save_failure``: those chains take DE steps alone, and so does their continuation)."""
        path = directory / FILE
        try:
            with np.load(path) as f:
                if "reason" in f:
                    return None
                p = cls(f["mu"], f["chol"], f["lower"], f["upper"], f["bounded"].astype(bool), float(f["nu"][0]))
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ChainError(f"{path}: the saved Laplace proposal of these chains is missing or damaged "
                             f"({type(exc).__name__}: {exc}); delete {directory} to start over") from exc
        if p.mu.shape != (dim,) or p.chol.shape != (dim, dim):
            raise ChainError(f"{path}: a proposal in {p.mu.size} dimensions, the chains have {dim}; "
                             f"delete {directory} to start over")
        return p


def save_failure(directory: Path, reason: str) -> Path:
    """Record that no proposal could be built (why, in the file), so that a resumed run does not
    try again and mix moves the chains began without."""
    path = directory / FILE
    with atomic_path(path) as tmp:
        np.savez(tmp, reason=np.array(reason))
    return path


def build(log_prob: LogProb, start: FloatArray, lower: FloatArray | None = None, upper: FloatArray | None = None,
          nu: float = NU) -> LaplaceProposal:
    """The proposal of the module docstring for ``log_prob`` (vectorised: (n, dim) -> (n,)), from
    ``start`` (the least-squares optimum). ``lower``/``upper``: the support's bounds (infinite or
    None: that coordinate is not transformed). Raises ProposalError when the log-posterior is not
    finite where the finite differences need it."""
    start = np.asarray(start, dtype=np.float64)
    d = start.size
    lower = np.full(d, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    upper = np.full(d, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    bounded = np.isfinite(lower) & np.isfinite(upper)
    shape = LaplaceProposal(np.zeros(d), np.eye(d), lower, upper, bounded, nu)
    width = np.where(bounded, upper - lower, 1.0)
    x0 = np.where(bounded, np.clip(start, lower + EDGE * width, upper - EDGE * width), start)
    z = shape.to_z(x0)

    def g(zs: FloatArray) -> FloatArray:
        zs = np.atleast_2d(zs)
        return np.asarray(log_prob(shape.to_x(zs)), dtype=np.float64) + shape.log_jacobian(zs)

    f0 = float(g(z)[0])
    if not math.isfinite(f0):
        raise ProposalError("the log-posterior is not finite at the start point")
    for _ in range(NEWTON_STEPS):
        grad, hess, f0 = _derivatives(g, z)
        step = _solve(hess, grad)
        t, f1 = 1.0, -math.inf
        while t > 1e-3:  # backtracking: never downhill
            f1 = float(g(z + t * step)[0])
            if f1 >= f0:
                break
            t /= 2
        if not f1 >= f0:
            break
        z = z + t * step
        if f1 - f0 < 1e-3:
            break
    _, hess, _ = _derivatives(g, z)
    values, vectors = _concave(hess)
    cov = (vectors / values) @ vectors.T
    chol = np.asarray(np.linalg.cholesky(0.5 * (cov + cov.T)), dtype=np.float64)
    return LaplaceProposal(z, chol, lower, upper, bounded, nu)


def _concave(hess: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eigenvalues (floored at 1e-6 of the largest, so the scale matrix is positive definite) and
    eigenvectors of the negated Hessian."""
    values, vectors = np.linalg.eigh(-0.5 * (hess + hess.T))
    if not values[-1] > 0:
        raise ProposalError("the log-posterior is not concave in any direction at its mode")
    return np.maximum(values, 1e-6 * values[-1]), vectors


def _solve(hess: FloatArray, grad: FloatArray) -> FloatArray:
    values, vectors = _concave(hess)
    return np.asarray(vectors @ ((vectors.T @ grad) / values), dtype=np.float64)


def _derivatives(g: Callable[[FloatArray], FloatArray], z: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Gradient, Hessian and value of g at z by central differences, the steps a fifth of each
    coordinate's curvature scale (found from the diagonal first), every point of a pass in one call."""
    d = z.size
    h = np.full(d, 1e-3)
    eye = np.eye(d)
    for _ in range(3):
        v = g(np.vstack([z, z + eye * h, z - eye * h]))
        if not np.all(np.isfinite(v)):
            bad = int(np.flatnonzero(~np.isfinite(v[1:]))[0]) % d
            raise ProposalError(f"the log-posterior is not finite {h[bad]:.3g} from the mode along coordinate {bad}")
        f0, fp, fm = float(v[0]), v[1:d + 1], v[d + 1:]
        diag = (fp + fm - 2 * f0) / h**2
        grad = (fp - fm) / (2 * h)
        h_new = np.clip(0.2 / np.sqrt(np.maximum(-diag, 1e-300)), 1e-6, 0.5)
        if np.allclose(h_new, h, rtol=0.5):
            break
        h = h_new
    i, j = np.triu_indices(d, 1)
    signs = np.array([(1, 1), (1, -1), (-1, 1), (-1, -1)], dtype=np.float64)
    points = z + (signs[:, 0, None, None] * eye[i] * h[i, None] + signs[:, 1, None, None] * eye[j] * h[j, None])
    v = g(points.reshape(-1, d)).reshape(4, -1)
    if not np.all(np.isfinite(v)):
        raise ProposalError("the log-posterior is not finite at a finite-difference point near the mode")
    hess = np.diag(diag)
    hess[i, j] = hess[j, i] = (v[0] - v[1] - v[2] + v[3]) / (4 * h[i] * h[j])
    return grad, hess, f0
