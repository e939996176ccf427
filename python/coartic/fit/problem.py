"""The least-squares problem of one channel: data, free-parameter packing, transforms, residuals.

This module is the contract that the engines, the staged fit, the result statistics and the MCMC
sampler (``coartic.mcmc``) share. Its pieces:

``Utterance`` (``coartic.model.Utterance``, the one utterance type of the package)
    one recorded utterance: model-phoneme segments, sample times, the observed channels and their
    validity masks, and metadata (stimulus, vowel, consonant, repetition, rate).
``ChannelData``
    every utterance of one channel packed into a ``coartic._core.Corpus`` (CSR), with the observed
    values (NaN replaced by 0) and weights (1 valid, 0 masked). MODEL.md §5: all utterances
    jointly, so a phoneme's parameters are shared by every context it occurs in.
``Packing`` (``coartic.fit.packing``, below this module and ``coartic.fit.parameters``)
    which entries of the parameter matrix ``params[n_phonemes, 10]`` (and ``beta``) are free, their
    bounds, and the transform to the internal vector ``x`` the engines see: ``log`` for the
    positive scale parameters (alpha, theta_bw, theta_fw, psi, and beta), identity for the others,
    whose boxes are passed to the engine as bounds (so k_R = 1 is reachable, which a logistic
    transform would put at infinity). ``pack``/``unpack`` map between ``x`` and the matrix.
``ChannelProblem``
    residuals ``r = sqrt(w) (F(x) - y)``, their sparse Jacobian with respect to ``x`` (the Rust
    core's exact derivatives, free columns only, chain rule through the transform), the SSE and its
    gradient, and a tracker of the best point seen (so Ctrl-C can keep it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from coartic import _core
from coartic.fit.packing import LOG_COLUMNS, LOG_PARAMETERS, Packing, Prior
from coartic.fit.parameters import ParameterSet, data_targets
from coartic.fit.spec import FitSpec, SpecError
from coartic.io.errors import DataError
from coartic.jacobian import JacobianBuffer
from coartic.model import Utterance, build_corpus, channel_options, core_error
from coartic.table import N_PARAMS, PARAMETERS, PAUSE

__all__ = ["Utterance", "ChannelData", "Packing", "Prior", "LOG_COLUMNS", "LOG_PARAMETERS", "ChannelProblem",
           "build_problem", "build_packing",
           "phoneme_inventory", "Shrinkage", "ShrinkGroup", "shrink_groups", "Speakers", "affine_coefficients"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def phoneme_inventory(utterances: Sequence[Utterance]) -> tuple[str, ...]:
    """Phonemes present, pause first, then in order of first appearance (stable across channels)."""
    seen: dict[str, None] = {}
    for u in utterances:
        for lab in u.labels:
            seen.setdefault(lab, None)
    names = list(seen)
    if PAUSE in seen:
        names.remove(PAUSE)
        names.insert(0, PAUSE)
    return tuple(names)


@dataclass
class ChannelData:
    """All utterances of one channel in the Rust core's corpus form, with observations and weights."""

    channel: str
    phonemes: tuple[str, ...]
    utterances: list[Utterance]
    corpus: _core.Corpus
    observed: FloatArray  # NaN replaced by 0 (weight 0 there)
    weights: FloatArray  # 1 valid, 0 masked
    sample_offsets: NDArray[np.int64]

    @classmethod
    def build(cls, utterances: Sequence[Utterance], channel: str,
              phonemes: Sequence[str] | None = None) -> ChannelData:
        utts = [u for u in utterances if channel in u.observed and np.any(u.valid[channel])]
        if not utts:
            raise DataError(f"channel {channel}: no utterance has a valid sample")
        phon = tuple(phonemes) if phonemes is not None else phoneme_inventory(utts)
        y = np.concatenate([u.observed[channel] for u in utts]).astype(np.float64)
        valid = np.concatenate([u.valid[channel] for u in utts]) & np.isfinite(y)
        offsets = np.cumsum([0] + [len(u.times) for u in utts]).astype(np.int64)
        return cls(channel, phon, utts, build_corpus(utts, phon),
                   np.where(valid, y, 0.0), valid.astype(np.float64), offsets)

    def utterance_samples(self, u: int) -> slice:
        return slice(int(self.sample_offsets[u]), int(self.sample_offsets[u + 1]))

    @property
    def n_valid(self) -> int:
        return int(self.weights.sum())


def build_packing(spec: FitSpec, data: ChannelData, start: tuple[FloatArray, float] | None = None) -> Packing:
    """Free set, bounds and starting values of one channel from the spec (and an optional start):
    ``coartic.fit.parameters.ParameterSet.from_spec`` as the engines see it."""

    return ParameterSet.from_spec(spec, data, start).packing()


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
        return sp.csr_matrix((d, (np.arange(self.size), self.idx)), shape=(self.size, self.packing.n_free))



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

    def z(self, params: FloatArray) -> FloatArray:
        """Standardised deviations (u_i − ū)/sd for parameter matrices [..., n_phonemes, 10]."""
        out = []
        for g in self.groups:
            v = params[..., list(g.rows), g.column]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = np.log(v) if g.log else v
            out.append((u - u.mean(axis=-1, keepdims=True)) / g.sd)
        if not out:
            return np.zeros(params.shape[:-2] + (0,))
        return np.concatenate(out, axis=-1)

    def residuals(self, x: FloatArray) -> FloatArray:
        params, _ = self.packing.unpack(x)
        return self.noise * self.z(params)

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        params, _ = self.packing.unpack(x)
        dv = self.packing.dvalue_dx(x)
        rows: list[NDArray[np.int64]] = []
        cols: list[NDArray[np.int64]] = []
        vals: list[FloatArray] = []
        r0 = 0
        for g, xc in zip(self.groups, self._xcol):
            n = len(g.rows)
            live = np.flatnonzero(xc >= 0)
            if live.size:
                v = params[list(g.rows), g.column][live]
                du = dv[xc[live]] / v if g.log else dv[xc[live]]
                # d row_i / d x_(member j) = noise (δ_ij − 1/n) du_j / sd, for every row i
                d = self.noise * ((np.eye(n)[:, live] - 1.0 / n) * du[None, :]) / g.sd
                ii, jj = np.meshgrid(np.arange(n), live, indexing="ij")
                rows.append(r0 + ii.ravel())
                cols.append(xc[jj.ravel()])
                vals.append(d.ravel())
            r0 += n
        if not rows:
            return sp.csr_matrix((self.size, self.packing.n_free))
        # duplicates (two tied members carried by one x entry) are summed by the COO -> CSR step
        return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(self.size, self.packing.n_free)).tocsr()


    def with_packing(self, packing: Packing) -> Shrinkage:
        return Shrinkage(packing, self.groups, self.noise)


def shrink_groups(spec: FitSpec, channel: str, phonemes: Sequence[str], free: BoolArray) -> list[ShrinkGroup]:
    """The spec's ``[[shrink]]`` tables as groups of one channel: members present in its data; a
    class with two members or more present but the parameter free for none of them is refused (a
    shrinkage of fixed values would do nothing), one with fewer than two present applies to nothing."""
    out = []
    for s in spec.shrinks:
        if s.channels is not None and channel not in s.channels:
            continue
        rows = tuple(phonemes.index(p) for p in s.phonemes if p in phonemes)
        if len(rows) < 2:
            continue
        for name in s.parameters:
            k = PARAMETERS.index(name)
            if not free[list(rows), k].any():
                raise SpecError.at(spec.path, s.key, f"{name} is free for none of {list(s.phonemes)} on {channel}: "
                                   "nothing to shrink")
            members = tuple(phonemes[i] for i in rows)
            out.append(ShrinkGroup(s.key, members, rows, k, s.sd, s.log))
    return out


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


def utterance_speakers(utterances: Sequence[Utterance], mode: str, column: str,
                       names: Sequence[str] | None = None) -> tuple[str, ...]:
    """The speakers of the utterances in order of first appearance (the first is the reference), or
    ``names`` checked to cover them; an utterance without a speaker is an error naming it."""
    seen: dict[str, None] = {}
    for u in utterances:
        if column not in u.meta or not str(u.meta[column]):
            raise SpecError(f"[model] speakers = {mode!r}: utterance {u.name!r} has no {column!r} "
                             f"(manifest column named by [model] speaker_column)")
        seen.setdefault(str(u.meta[column]), None)
    if names is None:
        return tuple(seen)
    extra = [s for s in seen if s not in names]
    if extra:
        raise SpecError(f"[model] speakers: speaker(s) {', '.join(extra)} not among {', '.join(names)}")
    return tuple(names)


def affine_coefficients(group: NDArray[np.int64], k: int, w: FloatArray, f: FloatArray, y: FloatArray,
                        scale: bool = True) -> tuple[FloatArray, FloatArray]:
    """Per group g < k, the weighted least-squares (a_g, b_g) of y ≈ a + b·f (``scale`` False: b = 1):
    the closed form behind the speakers' offset/scale and score's speaker calibration. A group
    without data (or with constant f, when scaling) keeps a = 0, b = 1."""
    sums = [np.bincount(group, weights=v, minlength=k) for v in (w, w * f, w * f * f, w * y, w * f * y)]
    W, SF, SFF, Sy, SFy = sums
    a, b = np.zeros(k), np.ones(k)
    if not scale:
        a = np.where(W > 0, (Sy - SF) / np.where(W > 0, W, 1.0), 0.0)
    else:
        det = W * SFF - SF * SF
        ok = det > 1e-12 * np.maximum(W * SFF, 1e-300)
        d = np.where(ok, det, 1.0)
        a = np.where(ok, (SFF * Sy - SF * SFy) / d, 0.0)
        b = np.where(ok, (W * SFy - SF * Sy) / d, 1.0)
    return a, b


class Speakers:
    """Speaker-specific target offset and scale (spec ``[model] speakers``), profiled out of least
    squares like ``Offsets``: utterances of speaker s are predicted as a_s + b_s·F, F the shared model
    (shared dynamics and targets), and (a_s, b_s) have a closed form for given model parameters (a
    weighted linear regression of y on F over that speaker's samples). The reference speaker (the
    first in utterance order) keeps a = 0, b = 1, so the shared targets are its targets. Mode
    ``"offset"`` fits a_s only (b_s = 1).

    Exact Jacobian: with e_i = a + b F_i − y_i, differentiating the normal equations
    M [a, b]ᵀ = [Σw y, Σw F y]ᵀ (M = [[Σw, Σw F], [Σw F, Σw F²]]) gives
    [∂a/∂F_i, ∂b/∂F_i]ᵀ = −w_i M⁻¹ [b, e_i + b F_i]ᵀ; the residuals sqrt(w)(a + b F − y) then have
    d r = sqrt(w)(b dF + da + F db), all linear in the core's Jacobian dF/dx.
    """

    def __init__(self, data: ChannelData, mode: str, column: str, names: Sequence[str] | None = None) -> None:
        if mode not in ("offset", "offset_scale"):
            raise SpecError(f"[model] speakers = {mode!r}: expected \"none\", \"offset\" or \"offset_scale\"")
        self.mode = mode
        # ``names`` fixes the order (the reference speaker first) when ``data`` is a subset of the
        # fit's utterances (an MCMC per-phoneme posterior): the reference must stay the fit's.
        self.names: tuple[str, ...] = utterance_speakers(data.utterances, mode, column, names)
        per_utt = np.array([self.names.index(str(u.meta[column])) for u in data.utterances], dtype=np.int64)
        self.spk = np.repeat(per_utt, np.diff(data.sample_offsets)).astype(np.int64)
        self.w = np.asarray(data.weights, dtype=np.float64)
        self.sqrt_w = np.sqrt(self.w)
        self.y = np.asarray(data.observed, dtype=np.float64)
        n = self.spk.size
        self.S = sp.csr_matrix((np.ones(n), (np.arange(n), self.spk)), shape=(n, len(self.names)))

    def coefficients(self, f: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(a_s, b_s) per speaker for model values f (reference speaker 0 → a = 0, b = 1)."""
        a, b = affine_coefficients(self.spk, len(self.names), self.w, f, self.y, self.mode == "offset_scale")
        a[0], b[0] = 0.0, 1.0
        return a, b

    def predict(self, f: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
        """Each sample's speaker prediction a_s + b_s·F; ``f`` (..., n) with ``a``, ``b`` (..., n_speakers)
        (one row per MCMC walker, or one vector): the one place the mapping is applied."""
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        return a[..., self.spk] + b[..., self.spk] * f

    def residuals(self, f: FloatArray) -> FloatArray:
        return self.sqrt_w * (self.predict(f, *self.coefficients(f)) - self.y)

    def jacobian(self, f: FloatArray, j: sp.csr_matrix) -> sp.csr_matrix:
        """From j = sqrt(w)·dF/dx to the Jacobian of ``residuals``."""
        a, b = self.coefficients(f)
        k, n = len(self.names), self.spk.size
        i = np.arange(n)
        free = self.spk != 0  # the reference speaker's a, b are fixed
        if self.mode == "offset":
            W = np.bincount(self.spk, weights=self.w, minlength=k)
            ga = np.where(free, -self.sqrt_w / np.where(W > 0, W, 1.0)[self.spk], 0.0)  # (∂a/∂F_i)/sqrt(w_i)
            gb = np.zeros(n)
        else:
            W, SF, SFF = (np.bincount(self.spk, weights=v, minlength=k) for v in (self.w, self.w * f, self.w * f * f))
            det = W * SFF - SF * SF
            inv_det = np.where(det > 0, 1.0 / np.where(det > 0, det, 1.0), 0.0)
            e = a[self.spk] + b[self.spk] * f - self.y
            u, v = b[self.spk], e + b[self.spk] * f
            s = self.spk
            # M⁻¹ = [[SFF, −SF], [−SF, W]] / det; ∂(a, b)/∂F_i = −w_i M⁻¹ [u, v]ᵀ (divided by sqrt(w_i)).
            ga = np.where(free, -self.sqrt_w * inv_det[s] * (SFF[s] * u - SF[s] * v), 0.0)
            gb = np.where(free, -self.sqrt_w * inv_det[s] * (-SF[s] * u + W[s] * v), 0.0)
        Ga = sp.csr_matrix((ga, (self.spk, i)), shape=(k, n))
        Gb = sp.csr_matrix((gb, (self.spk, i)), shape=(k, n))
        da, db = Ga @ j, Gb @ j
        out = (sp.diags(b[self.spk]) @ j + sp.diags(self.sqrt_w) @ (self.S @ da)
               + sp.diags(self.sqrt_w * f) @ (self.S @ db))
        return sp.csr_matrix(out)


class ChannelProblem:
    """Residuals, Jacobian and SSE of one channel as functions of the internal vector x.

    Every evaluation updates ``best_x`` / ``best_sse`` (the lowest finite SSE seen), so an
    interrupted or failed engine can still return the best point. Invalid parameters (the core
    raises ValueError) give non-finite residuals, which the engines treat as a rejected step.
    """

    def __init__(self, data: ChannelData, packing: Packing, options: _core.ModelOptions,
                 priors: Mapping[str, Prior] | None = None, prior_noise: float = 1.0,
                 offset_sd: float | None = None, speakers: str = "none",
                 speaker_column: str = "speaker", shrink: Sequence[ShrinkGroup] = (),
                 speaker_rows: SpeakerRows | None = None) -> None:
        self.data = data
        # Speaker-specific target offset/scale (spec [model] speakers), profiled out like offsets.
        self.speaker_mode, self.speaker_column = speakers, speaker_column
        self.speakers = None if speakers in ("none", "targets") else Speakers(data, speakers, speaker_column)
        # [model] speakers = "targets": the rows of the (expanded) matrix per speaker (expand_speaker_targets)
        self.speaker_rows = speaker_rows
        if (speakers == "targets") != (speaker_rows is not None):
            raise SpecError("[model] speakers = \"targets\" needs the per-speaker rows (build_problem makes them)")
        if self.speakers is not None and offset_sd is not None:
            raise SpecError("[model] speakers and [model] offsets cannot be combined yet: choose one")
        self.packing = packing
        self.options = options
        # Per-utterance offsets (spec [model] offsets): None none, inf free, else their sd τ (mm).
        self.offset_sd = offset_sd
        self.offsets = None if offset_sd is None else Offsets(
            data, 0.0 if np.isinf(offset_sd) else (prior_noise / offset_sd) ** 2)
        # Gaussian priors (spec [parameters.prior]) on free entries, as extra residual rows.
        self.priors: dict[str, Prior] = dict(priors or {})
        self.prior_noise = float(prior_noise)
        self.penalty = Penalty(packing, self.priors, self.prior_noise)
        # Shrinkage toward class means (spec [[shrink]]), likewise extra rows after the priors'.
        self.shrink_groups = list(shrink)
        self.shrinkage = Shrinkage(packing, self.shrink_groups, self.prior_noise)
        self.sqrt_w = np.sqrt(data.weights)
        self.nfev = 0
        self.njev = 0
        self.best_x: FloatArray = packing.pack()
        self.best_sse = np.inf
        self.last_error: str | None = None
        self.monitor: Callable[[int, float], None] | None = None  # (evaluations, best SSE) hook
        # One set of Jacobian arrays, refilled at every step: a fit allocates nothing per step.
        self._jacobian = JacobianBuffer(data.corpus)

    # --- natural-unit evaluation -------------------------------------------------------------
    def evaluate(self, params: FloatArray, beta: float) -> FloatArray:
        return np.asarray(_core.evaluate(self.data.corpus, params, beta, self.options))

    def full_jacobian(self, params: FloatArray, beta: float) -> tuple[FloatArray, sp.csr_matrix]:
        """Model values and the core's CSR Jacobian over every column (n_phonemes*10 + 1); both are
        overwritten by the next call, so copy what you keep."""
        return self._jacobian.compute(params, beta, self.options)

    def explain(self, err: ValueError, params: FloatArray) -> str:
        """A model error at ``params`` for people: the phoneme by name and, when the refused value
        is the one the spec gave (not an engine's step), the spec key it came from, e.g.
        ``[parameters.start] alpha = nan for phoneme 'a' on channel LLO: the value is not finite``."""
        e = core_error(err, self.data.channel, self.packing.phonemes)
        pk = self.packing
        if (pk.origins is None or not isinstance(e.phoneme, str) or e.parameter not in PARAMETERS
                or e.phoneme not in pk.phonemes):
            return str(e)
        i, k = pk.phonemes.index(e.phoneme), PARAMETERS.index(str(e.parameter))
        v, b = float(params[i, k]), float(pk.base[i, k])
        if not pk.origins[i, k] or not (v == b or (np.isnan(v) and np.isnan(b))):
            return str(e)
        section, _, name = str(pk.origins[i, k]).rpartition(".")
        return (f"[{section}] {name} = {v!r} for phoneme {e.phoneme!r} on channel {self.data.channel}: "
                f"the value {e.reason}")

    # --- internal-x interface for engines ----------------------------------------------------
    def _track(self, x: FloatArray, sse: float) -> None:
        if np.isfinite(sse) and sse < self.best_sse:
            self.best_sse = float(sse)
            self.best_x = np.array(x, dtype=np.float64)
        if self.monitor is not None:
            self.monitor(self.nfev, self.best_sse)

    def residuals(self, x: FloatArray) -> FloatArray:
        self.nfev += 1
        params, beta = self.packing.unpack(x)
        try:
            f = self.evaluate(params, beta)
        except ValueError as e:
            self.last_error = self.explain(e, params)
            return np.full(self.n_residuals, np.nan)
        r = (self.sqrt_w * (f - self.data.observed) if self.speakers is None
             else self.speakers.residuals(f))
        if self.offsets is not None:
            r = self.offsets.residuals(r)
        if self.penalty.size:
            r = np.concatenate([r, self.penalty.residuals(x)])
        if self.shrinkage.size:
            r = np.concatenate([r, self.shrinkage.residuals(x)])
        self._track(x, float(r @ r))
        return r

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """d r / d x: the core's Jacobian, free columns only, scaled by the transform and sqrt(w)."""
        self.njev += 1
        params, beta = self.packing.unpack(x)
        try:
            f, jac = self.full_jacobian(params, beta)
        except ValueError as e:
            self.last_error = self.explain(e, params)
            return sp.csr_matrix((self.n_residuals, self.packing.n_free))
        tmap = self.packing.column_map()
        j = jac[:, self.packing.free_columns].tocsr() if tmap is None else sp.csr_matrix(jac @ tmap)
        # Row scale sqrt(w) and column scale d(value)/dx applied to the stored entries in place.
        rows = np.repeat(np.arange(j.shape[0]), np.diff(j.indptr))
        j.data *= self.sqrt_w[rows] * self.packing.dvalue_dx(x)[j.indices]
        if self.speakers is not None:
            j = self.speakers.jacobian(np.asarray(f, dtype=np.float64), j)
        if self.offsets is not None:
            j = self.offsets.jacobian(j)
        if self.penalty.size:
            j = sp.vstack([j, self.penalty.jacobian(x)], format="csr")
        if self.shrinkage.size:
            j = sp.vstack([j, self.shrinkage.jacobian(x)], format="csr")
        return j

    def sse(self, x: FloatArray) -> float:
        r = self.residuals(x)
        return float(r @ r) if np.all(np.isfinite(r)) else np.inf

    @property
    def n_residuals(self) -> int:
        """Rows of the residual vector: samples, then offset rows (random effects), then priors, then
        shrinkage."""
        return (self.data.corpus.n_samples + (self.offsets.extra_rows if self.offsets else 0) + self.penalty.size
                + self.shrinkage.size)

    def utterance_offsets(self, x: FloatArray) -> FloatArray:
        """The fitted per-utterance offsets b_u (mm) at x (zeros without offsets)."""
        if self.offsets is None:
            return np.zeros(len(self.data.utterances))
        params, beta = self.packing.unpack(x)
        return self.offsets.offsets(self.sqrt_w * (self.evaluate(params, beta) - self.data.observed))

    @property
    def n_profiled(self) -> int:
        """Parameters profiled out of x that still cost degrees of freedom: each non-reference
        speaker's a_s (and b_s with offset_scale). AIC/BIC and the residual dof count them."""
        if self.speakers is None:
            return 0
        return (len(self.speakers.names) - 1) * (2 if self.speakers.mode == "offset_scale" else 1)

    @property
    def phonemes(self) -> tuple[str, ...]:
        """The channel's phonemes as the table has them (the data's rows, or with per-speaker
        targets the phonemes those rows expand)."""
        return self.data.phonemes if self.speaker_rows is None else self.speaker_rows.base

    def table_matrix(self, params: FloatArray) -> FloatArray:
        """The table's matrix (rows ``phonemes``) for a matrix of the problem's rows: itself, or with
        per-speaker targets the shared values and the population targets (mean over the speakers)."""
        return params if self.speaker_rows is None else self.speaker_rows.collapse(params)

    def speaker_metadata(self, x: FloatArray) -> dict[str, Any]:
        """This channel's part of a table's ``metadata.speakers``: each speaker's (a_s, b_s) and, with
        per-speaker targets, its own targets ({} without [model] speakers)."""
        if self.speaker_mode == "none":
            return {}
        if self.speaker_rows is None:
            return {"coefficients": {n: {"offset_mm": a, "scale": b} for n, (a, b) in self.speaker_coefficients(x).items()}}
        params, _ = self.packing.unpack(x)
        return {"coefficients": {n: {"offset_mm": 0.0, "scale": 1.0} for n in self.speaker_rows.names},
                "targets": self.speaker_rows.targets(params)}

    def speaker_coefficients(self, x: FloatArray) -> dict[str, tuple[float, float]]:
        """The fitted (a_s offset mm, b_s scale) per speaker at x ({} without [model] speakers or with
        per-speaker targets)."""
        if self.speakers is None:
            return {}
        params, beta = self.packing.unpack(x)
        a, b = self.speakers.coefficients(self.evaluate(params, beta))
        return {n: (float(a[i]), float(b[i])) for i, n in enumerate(self.speakers.names)}

    def sse_gradient(self, x: FloatArray) -> tuple[float, FloatArray]:
        """SSE and its gradient in x, from the core's fused SSE+gradient (no Jacobian formed); with
        offsets or speakers, 2 Jᵀr from the profiled residuals and their exact Jacobian."""
        if self.offsets is not None or self.speakers is not None:
            r = self.residuals(x)
            if not np.all(np.isfinite(r)):
                return np.inf, np.zeros(self.packing.n_free)
            return float(r @ r), 2.0 * np.asarray(self.jacobian(x).T @ r).ravel()
        self.nfev += 1
        params, beta = self.packing.unpack(x)
        try:
            sse, grad, dbeta = _core.sse_gradient(self.data.corpus, params, beta, self.options,
                                                  self.data.observed, self.data.weights)
        except ValueError as e:
            self.last_error = self.explain(e, params)
            return np.inf, np.zeros(self.packing.n_free)
        full = np.append(np.asarray(grad), dbeta)
        tmap = self.packing.column_map()
        g = (full[self.packing.free_columns] if tmap is None else tmap.T @ full) * self.packing.dvalue_dx(x)
        for pen in (self.penalty, self.shrinkage):
            if pen.size:
                ps, pg = pen.gradient(x)
                sse, g = sse + ps, g + pg
        if np.isfinite(sse):
            self._track(x, float(sse))
        return float(sse), g

    def sse_batch(self, xs: FloatArray) -> FloatArray:
        """SSE for many x at once (rows), through the core's parallel batch path; +inf if invalid."""
        if self.speakers is not None:  # profiled per speaker: through the residuals, point by point
            return np.array([self.sse(x) for x in np.atleast_2d(xs)])
        params, betas = self.packing.unpack_batch(xs)
        if self.offsets is not None:
            sse, sums = _core.residual_sums_batch(self.data.corpus, params, betas, self.options,
                                                  self.data.observed, self.data.weights)
            out = self.offsets.profiled_sse(np.asarray(sse), np.asarray(sums))
        else:
            out = np.asarray(_core.sse_batch(self.data.corpus, params, betas, self.options,
                                             self.data.observed, self.data.weights))
        if self.penalty.size:
            out = out + np.array([float(r @ r) for r in map(self.penalty.residuals, np.atleast_2d(xs))])
        if self.shrinkage.size:
            out = out + np.sum((self.shrinkage.noise * self.shrinkage.z(params)) ** 2, axis=-1)
        return out

    def with_packing(self, packing: Packing) -> ChannelProblem:
        """A problem on the same data with another free set (staged fits); best point carried."""
        p = ChannelProblem(self.data, packing, self.options, self.priors, self.prior_noise, self.offset_sd,
                           self.speaker_mode, self.speaker_column, self.shrink_groups, self.speaker_rows)
        p.nfev, p.njev, p.monitor = self.nfev, self.njev, self.monitor
        return p


def build_problem(spec: FitSpec, utterances: Sequence[Utterance], channel: str,
                  start: tuple[FloatArray, float] | None = None,
                  phonemes: Sequence[str] | None = None) -> ChannelProblem:
    """The channel's problem from a spec and loaded utterances (the one entry point others use)."""
    data = ChannelData.build(utterances, channel, phonemes)
    # Options from the settings the fitted table will record (spec.channel_settings): one source.
    options = channel_options(spec.variant, spec.channel_settings(channel))

    ps = ParameterSet.from_spec(spec, data, start)
    offset_sd = {"none": None, "free": np.inf}.get(str(spec.offsets), spec.offsets)
    shrink = shrink_groups(spec, channel, data.phonemes, moving(ps.free, ps.ties))
    rows = None
    if spec.speakers == "targets":
        data, ps, rows = expand_speaker_targets(spec, data, ps, data_start=start is None and
                                                "target" not in spec.start_given)
        shrink = rows.shrink_groups(spec, shrink)
    return ChannelProblem(data, ps.packing(), options, ps.priors, spec.prior_noise,
                          None if offset_sd is None else float(offset_sd), spec.speakers, spec.speaker_column,
                          shrink, rows)


SPEAKER_SEP = "|"  # row label of phoneme p for speaker s: "p|s"


@dataclass(frozen=True)
class SpeakerRows:
    """``[model] speakers = "targets"``: every speaker has its own target per phoneme, every other
    parameter is shared. The core sees one row per (phoneme, speaker) that occurs, labelled
    ``"p|s"`` (each utterance's labels relabelled with its speaker), and the Packing ties every
    non-target entry of a phoneme's rows to its first row (``Packing.ties``: the leader's Jacobian
    column sums its followers', so the gradients stay the core's exact ones); the targets of the
    rows are free on their own. F is linear in the targets, so each speaker's targets are what a
    speaker-specific table holds."""

    names: tuple[str, ...]  # speakers, reference (first in utterance order) first
    base: tuple[str, ...]  # the phonemes (the table's rows)
    rows: tuple[tuple[int, int], ...]  # per row of the problem: (base phoneme index, speaker index)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(f"{self.base[p]}{SPEAKER_SEP}{self.names[s]}" for p, s in self.rows)

    def leader(self, p: int) -> int:
        """The first row of base phoneme p (which holds its shared values)."""
        return next(r for r, (q, _) in enumerate(self.rows) if q == p)

    def collapse(self, params: FloatArray) -> FloatArray:
        """The table's matrix: each phoneme's shared values (its leader row) and as target the mean
        of its speakers' targets (the population)."""
        out = np.array([params[self.leader(p)] for p in range(len(self.base))], dtype=np.float64)
        k = PARAMETERS.index("target")
        for p in range(len(self.base)):
            out[p, k] = float(np.mean([params[r, k] for r, (q, _) in enumerate(self.rows) if q == p]))
        return out

    def targets(self, params: FloatArray) -> dict[str, dict[str, float]]:
        """Each speaker's own targets: speaker -> phoneme -> target (the phonemes it spoke)."""
        k = PARAMETERS.index("target")
        out: dict[str, dict[str, float]] = {n: {} for n in self.names}
        for r, (p, s) in enumerate(self.rows):
            out[self.names[s]][self.base[p]] = float(params[r, k])
        return out

    def shrink_groups(self, spec: FitSpec, groups: Sequence[ShrinkGroup]) -> list[ShrinkGroup]:
        """The base phonemes' [[shrink]] groups on the leader rows (targets are per speaker: refused)."""
        out = []
        for g in groups:
            if g.parameter == "target":
                raise SpecError.at(spec.path, g.key, f"shrinks target, but [model] speakers = \"targets\" gives "
                                   "every speaker its own targets: shrink the dynamics only")
            out.append(replace(g, rows=tuple(self.leader(i) for i in g.rows)))
        return out


def expand_speaker_targets(spec: FitSpec, data: ChannelData, ps: ParameterSet, data_start: bool = True,
                           names: Sequence[str] | None = None,
                           start_targets: Mapping[str, Mapping[str, float]] | None = None,
                           ) -> tuple[ChannelData, ParameterSet, SpeakerRows]:
    """The per-speaker problem of ``[model] speakers = "targets"`` from the base one: data relabelled
    ``p|s``, the parameter set with a row per (phoneme, speaker), shared entries tied to the first
    row, targets per row. Targets start at each speaker's own data targets (``data_start``), at
    ``start_targets`` (speaker -> phoneme -> target: a fitted table's, for MCMC), or at the base
    start. ``names`` fixes the speakers' order (the reference first)."""
    column = spec.speaker_column
    spk = utterance_speakers(data.utterances, "targets", column, names)
    bad = [n for n in spk if SPEAKER_SEP in n]
    if bad:
        raise SpecError.at(spec.path, "model", f"speakers = \"targets\": speaker name {bad[0]!r} contains "
                           f"{SPEAKER_SEP!r}")
    kt = PARAMETERS.index("target")
    for f, ld in ps.ties:
        if f % N_PARAMS == kt:
            raise SpecError(f"{spec.path}: [[tie]] of target cannot be combined with [model] speakers = \"targets\" "
                            "(every speaker has its own targets)")
    base = tuple(data.phonemes)
    occurs = {(base.index(lab), spk.index(str(u.meta[column]))) for u in data.utterances for lab in u.labels}
    rows = tuple((p, s) for s in range(len(spk)) for p in range(len(base)) if (p, s) in occurs)
    sr = SpeakerRows(spk, base, rows)
    labels = sr.labels
    utts = [Utterance([f"{lab}{SPEAKER_SEP}{u.meta[column]}" for lab in u.labels], u.starts, u.ends, u.times,
                      u.name, u.observed, u.valid, u.meta) for u in data.utterances]
    data_x = ChannelData.build(utts, data.channel, labels)
    idx = [p for p, _ in rows]
    matrix, lower, upper = ps.matrix[idx].copy(), ps.lower[idx].copy(), ps.upper[idx].copy()
    free = ps.free[idx].copy()
    origins = None if ps.origins is None else ps.origins[idx].copy()
    # a base entry tied to another phoneme's ([[tie]]) follows that phoneme's leader row directly
    ultimate = {f: ld for f, ld in ps.ties}
    base_free = moving(ps.free, ps.ties)
    ties: list[tuple[int, int]] = []
    for r, (p, s) in enumerate(rows):
        for k in range(N_PARAMS):
            if k == kt:
                continue
            src = ultimate.get(p * N_PARAMS + k, p * N_PARAMS + k)
            lead = sr.leader(src // N_PARAMS) * N_PARAMS + k
            if lead != r * N_PARAMS + k and base_free[p, k]:
                free[r, k] = False
                ties.append((r * N_PARAMS + k, lead))
    if start_targets is not None:
        for r, (p, s) in enumerate(rows):
            v = start_targets.get(spk[s], {}).get(base[p])
            if v is not None:
                matrix[r, kt] = float(v)
    elif data_start:
        matrix[:, kt] = data_targets(data_x)
    matrix[:, kt] = np.where(free[:, kt], np.clip(matrix[:, kt], lower[:, kt], upper[:, kt]), matrix[:, kt])
    priors: dict[str, Prior] = {}
    for key, pr in ps.priors.items():
        phoneme, _, name = key.rpartition(".")
        if not phoneme:  # beta
            priors[key] = pr
        elif name == "target":
            for r, (p, _) in enumerate(rows):
                if base[p] == phoneme:
                    priors[f"{labels[r]}.{name}"] = pr
        else:
            priors[f"{labels[sr.leader(base.index(phoneme))]}.{name}"] = pr
    out = ParameterSet(ps.channel, labels, matrix, free, lower, upper, ps.beta, ps.beta_free, ps.beta_bounds,
                       priors=priors, origins=origins)
    out.ties = tuple(ties)
    return data_x, out, sr


def moving(free: BoolArray, ties: Sequence[tuple[int, int]]) -> BoolArray:
    """Entries that move with x: the free ones and those tied to a free one."""
    out = free.copy()
    flat = out.reshape(-1)
    for f, ld in ties:
        flat[f] = flat[f] or free.reshape(-1)[ld]
    return out


def describe(packing: Packing) -> dict[str, Any]:
    """A small summary (counts per parameter) for progress output and reports."""
    return {p: int(packing.free[:, k].sum()) for k, p in enumerate(PARAMETERS)} | {"beta": int(packing.beta_free)}
