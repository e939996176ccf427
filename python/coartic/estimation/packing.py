"""Which entries of a channel's parameter matrix are free, their boxes, and the transform to the
vector x the engines see (``Packing``); a Gaussian prior on one entry (``Prior``); which entries
move with x (``moving``).

The packing is below both the spec's numbers (``coartic.estimation.parameters.ParameterSet`` builds
one) and the least-squares problem (``coartic.estimation.problem``, which evaluates through one).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from coartic.errors import UsageError
from coartic.table import N_PARAMS, PARAMETERS

# Columns fitted on a log scale (MODEL.md §1: "fit log α", "fit log θ"; ψ > 0 likewise).
LOG_PARAMETERS: frozenset[str] = frozenset({"alpha", "theta_bw", "theta_fw", "psi"})
LOG_COLUMNS: NDArray[np.bool_] = np.array([p in LOG_PARAMETERS for p in PARAMETERS])

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass
class Packing:
    """Free entries of (params[n_phonemes, 10], beta), their bounds, and the transform to x.

    ``base`` holds every value (fixed ones and the current/start value of free ones). ``x`` lists
    the free entries in row-major order (phoneme by phoneme, parameters in PARAMETERS order), then
    beta if free. Internal x is log(value) for LOG_PARAMETERS and beta, the value otherwise.
    """

    phonemes: tuple[str, ...]
    free: BoolArray  # [n_phonemes, 10]
    beta_free: bool
    lower: FloatArray  # [n_phonemes, 10] natural units
    upper: FloatArray
    beta_bounds: tuple[float, float]
    base: FloatArray  # [n_phonemes, 10]
    base_beta: float
    # [n_phonemes, 10]: the spec key each base value came from ("parameters.start.alpha",
    # "override #2.fixed.k_r"; "" for defaults, data and start tables): ParameterSet.origins.
    origins: NDArray[np.object_] | None = None
    # (follower, leader) flat indices into params.ravel(): a tied entry ([[tie]] in the spec) is not
    # free itself but always takes its leader's value; the leader's Jacobian column is the sum.
    ties: tuple[tuple[int, int], ...] = ()
    # "phoneme.parameter" (and "beta") -> the spec key or default its box came from, so that a
    # parameter at a bound is explained by where the bound comes from (coartic.estimation.bounds).
    bound_sources: Mapping[str, str] | None = None
    # (follower, ((source, weight), ...)) flat indices: an entry that is a fixed linear combination of
    # others, Σ weight·source (a trial's target at an emotion's intensity s, (1 − s)·neutral + s·emotion:
    # coartic.estimation.emotions.intensity_rows). Natural-scale columns only (the target), where the
    # combination is linear in x; the sources are free or fixed entries, not followers of a tie.
    mixes: tuple[tuple[int, tuple[tuple[int, float], ...]], ...] = ()

    def __post_init__(self) -> None:
        self._idx = np.flatnonzero(self.free.ravel())
        self._log = np.tile(LOG_COLUMNS, len(self.phonemes))[self._idx]
        self._followers = np.array([f for f, _ in self.ties], dtype=np.int64)
        self._leaders = np.array([ld for _, ld in self.ties], dtype=np.int64)
        if any(LOG_COLUMNS[f % N_PARAMS] for f, _ in self.mixes):
            raise UsageError("Packing.mixes: a mixed entry must be on a natural-scale column (the target)")
        n_flat = len(self.phonemes) * N_PARAMS
        # the mixes as one sparse matrix over the flat parameters: flat[mixed] = M @ flat
        self._mixed = np.array([f for f, _ in self.mixes], dtype=np.int64)
        self._mix = sp.csr_matrix(
            ([w for _, src in self.mixes for _, w in src],
             ([i for i, (_, src) in enumerate(self.mixes) for _ in src], [s for _, src in self.mixes for s, _ in src])),
            shape=(len(self.mixes), n_flat))
        self._tmap = self._column_map() if self.ties or self.mixes else None

    def column_map(self) -> sp.csr_matrix | None:
        """With ties (or mixes), the (n_phonemes*10 + 1, n_free) matrix taking the core's full Jacobian
        (or gradient) to x's: each free column plus the columns of the entries tied to it (weight 1)
        and of the mixed entries it is a source of (their weight); None without."""
        return self._tmap

    def _column_map(self) -> sp.csr_matrix:
        col_of = {int(c): j for j, c in enumerate(self.free_columns)}
        rows = list(col_of)
        cols = list(col_of.values())
        vals = [1.0] * len(rows)
        for f, ld in self.ties:
            if ld in col_of:  # a leader held fixed in this stage: its followers follow a constant
                rows.append(f)
                cols.append(col_of[ld])
                vals.append(1.0)
        for f, src in self.mixes:
            for s, w in src:
                if s in col_of:
                    rows.append(f)
                    cols.append(col_of[s])
                    vals.append(float(w))
        n_full = len(self.phonemes) * N_PARAMS + 1
        return sp.csr_matrix((vals, (rows, cols)), shape=(n_full, self.n_free))

    @property
    def n_free(self) -> int:
        return int(self._idx.size) + int(self.beta_free)

    @property
    def free_columns(self) -> NDArray[np.int64]:
        """Columns of the core's full Jacobian (n_phonemes*10 + 1) that x maps to."""
        cols = self._idx
        if self.beta_free:
            cols = np.append(cols, len(self.phonemes) * N_PARAMS)
        return cols.astype(np.int64)

    @property
    def log_mask(self) -> BoolArray:
        return np.append(self._log, True) if self.beta_free else self._log.copy()

    def names(self) -> list[str]:
        """'phoneme.parameter' for each entry of x (and 'beta')."""
        out = [f"{self.phonemes[i // N_PARAMS]}.{PARAMETERS[i % N_PARAMS]}" for i in self._idx]
        return out + (["beta"] if self.beta_free else [])

    def entries(self) -> list[tuple[str, str]]:
        """(phoneme, parameter) for each entry of x; beta is ('*', 'beta')."""
        out = [(self.phonemes[i // N_PARAMS], PARAMETERS[i % N_PARAMS]) for i in self._idx]
        return out + ([("*", "beta")] if self.beta_free else [])

    def natural(self, x: FloatArray) -> FloatArray:
        """The free values in natural units for an internal x."""
        x = np.asarray(x, dtype=np.float64)
        lm = self.log_mask
        return np.where(lm, np.exp(np.where(lm, x, 0.0)), x)

    def pack(self, params: FloatArray | None = None, beta: float | None = None) -> FloatArray:
        params = self.base if params is None else np.asarray(params, dtype=np.float64)
        beta = self.base_beta if beta is None else float(beta)
        v = params.ravel()[self._idx]
        if self.beta_free:
            v = np.append(v, beta)
        lm = self.log_mask
        return np.where(lm, np.log(np.where(lm, np.maximum(v, 1e-300), 1.0)), v)

    def unpack(self, x: FloatArray) -> tuple[FloatArray, float]:
        v = self.natural(x)
        params = self.base.copy()
        flat = params.reshape(-1)
        flat[self._idx] = v[: self._idx.size]
        if self.ties:
            flat[self._followers] = flat[self._leaders]
        if self.mixes:
            flat[self._mixed] = self._mix @ flat
        beta = float(v[-1]) if self.beta_free else self.base_beta
        return params, beta

    def unpack_batch(self, xs: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Many x at once (rows) -> params [W, n_phonemes, 10], betas [W] (for _core.sse_batch)."""
        xs = np.atleast_2d(np.asarray(xs, dtype=np.float64))
        lm = self.log_mask
        v = np.where(lm, np.exp(np.where(lm, xs, 0.0)), xs)
        params = np.broadcast_to(self.base, (xs.shape[0],) + self.base.shape).copy()
        flat = params.reshape(xs.shape[0], -1)
        flat[:, self._idx] = v[:, : self._idx.size]
        if self.ties:
            flat[:, self._followers] = flat[:, self._leaders]
        if self.mixes:
            flat[:, self._mixed] = (self._mix @ flat.T).T
        betas = v[:, -1].copy() if self.beta_free else np.full(xs.shape[0], self.base_beta)
        return params, betas

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        """Bounds of x (internal units)."""
        lo = self.lower.ravel()[self._idx]
        hi = self.upper.ravel()[self._idx]
        if self.beta_free:
            lo, hi = np.append(lo, self.beta_bounds[0]), np.append(hi, self.beta_bounds[1])
        lm = self.log_mask
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(lm, np.log(lo), lo), np.where(lm, np.log(hi), hi)

    def dvalue_dx(self, x: FloatArray) -> FloatArray:
        """d(natural value)/dx per entry of x: the chain-rule factor of each Jacobian column."""
        return np.where(self.log_mask, self.natural(x), 1.0)

    def clip(self, x: FloatArray) -> FloatArray:
        lo, hi = self.bounds()
        return np.clip(x, lo, hi)

    def with_free(self, free: BoolArray, beta_free: bool, base: FloatArray | None = None,
                  base_beta: float | None = None) -> Packing:
        """The same bounds with another free set (and optionally other current values)."""
        return replace(self, free=free.copy(), beta_free=beta_free,
                       base=(self.base if base is None else base).copy(),
                       base_beta=self.base_beta if base_beta is None else float(base_beta))


@dataclass(frozen=True)
class Prior:
    """A Gaussian prior on one parameter: on its natural value, or (``log``) on its logarithm
    (``mean`` is then still given in natural units: the prior's median)."""

    mean: float
    sd: float
    log: bool = False


def tie_group(phonemes: Sequence[str], ties: Sequence[tuple[int, int]], phoneme: str, parameter: str) -> tuple[str, ...]:
    """The phonemes whose ``parameter`` takes one value with ``phoneme``'s ([[tie]] or [parameters]
    shared), its carrier (the leader) first; () when it is its own."""
    if phoneme not in phonemes or parameter not in PARAMETERS:
        return ()
    k = PARAMETERS.index(parameter)
    leaders = dict(ties)
    me = phonemes.index(phoneme) * N_PARAMS + k
    lead = leaders.get(me, me)
    group = [lead] + [f for f, ld in ties if ld == lead]
    return tuple(phonemes[j // N_PARAMS] for j in group) if len(group) > 1 else ()


def shared_words(group: Sequence[str], phonemes: Sequence[str], parameter: str) -> str:
    """Who a shared or tied value belongs to, for a sentence ("every phoneme (one theta_bw shared by
    all 25)", "/a/, /e/ (one alpha tied across them)"): a report must not call it its carrier's."""
    if set(group) >= set(phonemes):
        return f"every phoneme (one {parameter} shared by all {len(phonemes)})"
    return f"{', '.join(f'/{p}/' for p in group)} (one {parameter} tied across them)"


def moving(free: BoolArray, ties: Sequence[tuple[int, int]]) -> BoolArray:
    """Entries that move with x: the free ones and those tied to a free one."""
    out = free.copy()
    flat = out.reshape(-1)
    for f, ld in ties:
        flat[f] = flat[f] or free.reshape(-1)[ld]
    return out
