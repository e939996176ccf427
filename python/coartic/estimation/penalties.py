"""Extra least-squares residual rows on the packed vector x: Gaussian priors (``Penalty``, spec
``[parameters] prior``) and shrinkage of a class of phonemes toward its class mean (``Shrinkage``,
spec ``[[shrink]]``), each with its exact Jacobian."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from coartic.estimation.packing import Packing, Prior
from coartic.errors import SpecError
from coartic.table import N_PARAMS, PARAMETERS

if TYPE_CHECKING:
    from coartic.estimation.settings import Shrink

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


class PenaltyRows:
    """Extra least-squares residual rows on the packed vector x (priors, shrinkage): the residuals
    and their exact Jacobian come from the subclass; Σ rows² and its gradient, for the engines that
    take a fused SSE and gradient (nlopt, CasADi), are computed from them here, once."""

    packing: Packing
    size: int

    def residuals(self, x: FloatArray) -> FloatArray:
        raise NotImplementedError

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        raise NotImplementedError

    def squares_batch(self, xs: FloatArray, params: FloatArray) -> FloatArray:
        """Σ rows² for many x at once (rows of ``xs``; ``params`` their unpacked matrices)."""
        return np.array([float(r @ r) for r in map(self.residuals, np.atleast_2d(xs))])

    def gradient(self, x: FloatArray) -> tuple[float, FloatArray]:
        """Σ rows² and its gradient in x."""
        r = self.residuals(x)
        g = np.zeros(self.packing.n_free)
        if self.size:
            g += 2.0 * (self.jacobian(x).T @ r)
        return float(r @ r), g


class Penalty(PenaltyRows):
    """Gaussian priors as extra least-squares residuals ``noise · (value − mean) / sd`` (or on log
    values), one row per prior on a free entry: minimising SSE + Σ rows² is the MAP estimate when
    the measurement noise has sd ``noise`` (mm). Exact derivatives: d row / dx = noise ·
    d(value)/dx / sd (natural) or noise / sd (log prior on a log-fitted parameter)."""

    def __init__(self, packing: Packing, priors: Mapping[str, Prior], noise: float) -> None:
        names = packing.names()
        keys = [k for k in priors if k in names]
        self.names = keys
        self.idx = np.array([names.index(k) for k in keys], dtype=np.int64)
        self.mean = np.array([priors[k].mean for k in keys], dtype=np.float64)
        self.sd = np.array([priors[k].sd for k in keys], dtype=np.float64)
        self.log = np.array([priors[k].log for k in keys], dtype=bool)
        self.noise = float(noise)
        self.packing = packing
        self.size = int(self.idx.size)
        # one entry a row, in the prior's column: the CSR pattern is fixed, only the values change
        self._indptr = np.arange(self.size + 1, dtype=np.int64)

    def residuals(self, x: FloatArray) -> FloatArray:
        v = self.packing.natural(x)[self.idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(self.log, (np.log(np.where(self.log, v, 1.0)) - np.log(np.where(self.log, self.mean, 1.0))),
                         v - self.mean) / self.sd
        return self.noise * z

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        v = self.packing.natural(x)[self.idx]
        dv = self.packing.dvalue_dx(x)[self.idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            d = self.noise * np.where(self.log, dv / v, dv) / self.sd
        return sp.csr_matrix((d, self.idx.copy(), self._indptr.copy()), shape=(self.size, self.packing.n_free))



@dataclass(frozen=True)
class ShrinkGroup:
    """One class and parameter of a ``[[shrink]]``: member rows (phonemes present in the channel's
    data), the parameter's column, its scale and sd, and the spec key (for reports)."""

    key: str
    phonemes: tuple[str, ...]  # the members present, in the channel's phoneme order
    rows: tuple[int, ...]
    column: int
    sd: float
    log: bool = False
    # the family whose estimated sd this group takes (coartic.estimation.pooling); None: sd as given
    family: str | None = None

    @property
    def parameter(self) -> str:
        return PARAMETERS[self.column]


class Shrinkage(PenaltyRows):
    """Shrinkage toward class means as extra least-squares residuals: for each group (a class of
    phonemes and one parameter), one row per member ``noise · (u_i − ū) / sd`` with u the value
    (or its logarithm) and ū the class mean over every member present, fixed ones included.
    Minimising SSE + Σ rows² is the MAP estimate under a Gaussian prior on the members' deviations
    from their common mean (the class mean itself is not penalised).

    Each row depends on every member: d row_i / d u_j = noise (δ_ij − 1/n) / sd, and d u_j / dx
    comes from the packing (d value/dx of the free entry carrying it, through a [[tie]] leader when
    tied, times 1/v on the log scale; nothing for a fixed member). Rows are computed from the
    unpacked parameter matrix, so the same groups serve any packing (a stage's, MCMC's per-phoneme
    one)."""

    def __init__(self, packing: Packing, groups: Sequence[ShrinkGroup], noise: float) -> None:
        self.packing = packing
        self.groups = [g for g in groups if len(g.rows) >= 2]
        self.noise = float(noise)
        self.size = sum(len(g.rows) for g in self.groups)
        # the x index carrying each member entry (free itself, or its tie leader free), else -1
        col_of = {int(c): j for j, c in enumerate(packing.free_columns)}
        leader = dict(packing.ties)
        self._xcol = []
        for g in self.groups:
            cols = []
            for i in g.rows:
                e = i * N_PARAMS + g.column
                cols.append(col_of.get(e, col_of.get(leader.get(e, -1), -1)))
            self._xcol.append(np.array(cols, dtype=np.int64))
        self._blocks = _blocks(self.groups)
        self._entries = _entries(self.groups, self._xcol)
        self._csr = self._csr_order()

    def _csr_order(self) -> tuple[NDArray[np.int64] | None, NDArray[np.int64]]:
        """The order that sorts the Jacobian's entries (``_entries``) by row then column, with the row
        pointers: the CSR arrays the COO -> CSR step made of them, value for value, worked out once (a
        pooled fit evaluates thousands of Jacobians per packing). The order is None where two entries
        share a place (two tied members carried by one x entry): their sum is left to that step. With
        ``stack_rows`` (coartic.estimation.problem) the pool's rows cost 0.3 ms a Jacobian instead of
        1.1 (German EMA 0024, LA, the default spec), beside the data's 0.8 and an SVD's 4."""
        e = self._entries
        row = e.rows if e is not None else np.zeros(0, dtype=np.int64)
        col = e.cols if e is not None else np.zeros(0, dtype=np.int64)
        order: NDArray[np.int64] | None = np.lexsort((col, row))
        assert order is not None
        place = row[order] * max(self.packing.n_free, 1) + col[order]
        if np.any(place[1:] == place[:-1]):
            order = None
        indptr = np.zeros(self.size + 1, dtype=np.int64)
        np.cumsum(np.bincount(row, minlength=self.size), out=indptr[1:])
        return order, indptr

    def z(self, params: FloatArray) -> FloatArray:
        """Standardised deviations (u_i − ū)/sd for parameter matrices [..., n_phonemes, 10]: the
        groups of one size and scale at once (``_blocks``), each group's rows where the groups'
        order puts them; the same values as group by group (the emotions' 65 pair groups took 1.5
        CPU-s of a 26 CPU-s fit one by one)."""
        # the rows axis outermost in memory, as NumPy's fancy indexing and concatenation laid it out
        # group by group: sums over it (``squares_batch``) add in the same order
        out = np.moveaxis(np.empty((self.size,) + params.shape[:-2]), 0, -1)
        for rows, cols, log, sd, at in self._blocks:
            v = params[..., rows, cols]  # [..., groups, members]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = np.log(v) if log else v
            out[..., at] = ((u - u.mean(axis=-1, keepdims=True)) / sd).reshape(*params.shape[:-2], -1)
        return out

    def residuals(self, x: FloatArray) -> FloatArray:
        params, _ = self.packing.unpack(x)
        return self.noise * self.z(params)

    def squares_batch(self, xs: FloatArray, params: FloatArray) -> FloatArray:
        out: FloatArray = np.sum((self.noise * self.z(params)) ** 2, axis=-1)
        return out

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """d row_i / d x_(member j) = noise (δ_ij − 1/n) du_j / sd for every row i of a group and every
        member j carried by an x entry, all groups at once (``_entries``: the pattern is the packing's,
        worked out once): the values, their order and so the matrix are those of a loop over the
        groups, which took 4.6 CPU-s of a 26 CPU-s fit (65 pair groups, 1500 Jacobians)."""
        e = self._entries
        if e is None:
            return sp.csr_matrix((self.size, self.packing.n_free))
        params, _ = self.packing.unpack(x)
        du = self.packing.dvalue_dx(x)[e.member_x]
        du[e.member_log] = du[e.member_log] / params[e.member_row[e.member_log], e.member_column[e.member_log]]
        vals = self.noise * (e.coef * du[e.member]) / e.sd
        shape = (self.size, self.packing.n_free)
        order, indptr = self._csr
        if order is None:  # duplicates (two tied members carried by one x entry) are summed by the COO -> CSR step
            return sp.coo_matrix((vals, (e.rows, e.cols)), shape=shape).tocsr()
        return sp.csr_matrix((vals[order], e.cols[order], indptr.copy()), shape=shape)

    def with_packing(self, packing: Packing) -> Shrinkage:
        return Shrinkage(packing, self.groups, self.noise)


Block = tuple[NDArray[np.int64], NDArray[np.int64], bool, FloatArray, NDArray[np.int64]]


def _blocks(groups: Sequence[ShrinkGroup]) -> list[Block]:
    """The groups by (members, log scale): their member rows [k, n], columns [k, 1], sds [k, 1] and
    where their rows sit among every group's [k * n] (the groups' order)."""
    starts = np.cumsum([0] + [len(g.rows) for g in groups])
    by: dict[tuple[int, bool], list[int]] = {}
    for i, g in enumerate(groups):
        by.setdefault((len(g.rows), g.log), []).append(i)
    out: list[Block] = []
    for (n, log), idx in by.items():
        out.append((np.array([groups[i].rows for i in idx], dtype=np.int64),
                    np.array([[groups[i].column] for i in idx], dtype=np.int64), log,
                    np.array([[groups[i].sd] for i in idx], dtype=np.float64),
                    (starts[idx][:, None] + np.arange(n)[None, :]).ravel()))
    return out


@dataclass(frozen=True)
class _Entries:
    """The Shrinkage Jacobian's stored entries, in the order a loop over the groups makes them (per
    group its rows i, per row the members j carried by an x entry): row, x column, δ_ij − 1/n, sd,
    and which carried member (index into the ``member_*`` arrays: its x entry, parameter row and
    column, whether on the log scale)."""

    rows: NDArray[np.int64]
    cols: NDArray[np.int64]
    coef: FloatArray
    sd: FloatArray
    member: NDArray[np.int64]
    member_x: NDArray[np.int64]
    member_row: NDArray[np.int64]
    member_column: NDArray[np.int64]
    member_log: BoolArray


def _entries(groups: Sequence[ShrinkGroup], xcols: Sequence[NDArray[np.int64]]) -> _Entries | None:
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    coef: list[FloatArray] = []
    sd: list[FloatArray] = []
    member: list[NDArray[np.int64]] = []
    mx: list[NDArray[np.int64]] = []
    mrow: list[NDArray[np.int64]] = []
    mcol: list[NDArray[np.int64]] = []
    mlog: list[BoolArray] = []
    r0 = m0 = 0
    for g, xc in zip(groups, xcols):
        n = len(g.rows)
        live = np.flatnonzero(xc >= 0)
        if live.size:
            ii, jj = np.meshgrid(np.arange(n), np.arange(live.size), indexing="ij")
            rows.append(r0 + ii.ravel())
            cols.append(xc[live][jj.ravel()])
            coef.append((np.eye(n)[:, live] - 1.0 / n).ravel())
            sd.append(np.full(ii.size, g.sd))
            member.append(m0 + jj.ravel())
            mx.append(xc[live])
            mrow.append(np.asarray(g.rows, dtype=np.int64)[live])
            mcol.append(np.full(live.size, g.column, dtype=np.int64))
            mlog.append(np.full(live.size, g.log))
            m0 += live.size
        r0 += n
    if not rows:
        return None
    return _Entries(np.concatenate(rows), np.concatenate(cols), np.concatenate(coef), np.concatenate(sd),
                    np.concatenate(member), np.concatenate(mx), np.concatenate(mrow), np.concatenate(mcol),
                    np.concatenate(mlog))


def shrink_groups(shrinks: Sequence[Shrink], source: Path | str | None, channel: str, phonemes: Sequence[str],
                  free: BoolArray) -> list[ShrinkGroup]:
    """The ``[[shrink]]`` tables (``source``: the spec file its errors name) as groups of one channel:
    members present in its data; a class with two members or more present but the parameter free for
    none of them is refused (a shrinkage of fixed values would do nothing), one with fewer than two
    present applies to nothing."""
    out = []
    for s in shrinks:
        if s.channels is not None and channel not in s.channels:
            continue
        rows = tuple(phonemes.index(p) for p in s.phonemes if p in phonemes)
        if len(rows) < 2:
            continue
        for name in s.parameters:
            k = PARAMETERS.index(name)
            if not free[list(rows), k].any():
                raise SpecError.at(source, s.key, f"{name} is free for none of {list(s.phonemes)} on {channel}: "
                                   "nothing to shrink")
            members = tuple(phonemes[i] for i in rows)
            out.append(ShrinkGroup(s.key, members, rows, k, s.sd, s.log))
    return out

