"""Several speakers in one fit (spec ``[model] speakers``): each speaker's offset and scale profiled
out of least squares (``Speakers``), or every speaker's own targets as rows of the problem
(``SpeakerRows``, ``expand_speaker_targets``). A fitted table's speakers, as the runtime and
``coartic score`` apply them, are ``coartic.speakers`` (below this package: it needs only the table)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from coartic.emotions import INTENSITY_COLUMN, trial_intensity
from coartic.estimation.data import ChannelData
from coartic.estimation.packing import Prior, moving
from coartic.estimation.parameters import ParameterSet, data_targets
from coartic.estimation.penalties import ShrinkGroup
from coartic.errors import SpecError
from coartic.model import Utterance
from coartic.table import N_PARAMS, PARAMETERS, ParameterTable, TableError

if TYPE_CHECKING:
    from coartic.estimation.settings import EstimationSettings, GroupSettings

FloatArray = NDArray[np.float64]


def utterance_speakers(utterances: Sequence[Utterance], mode: str, column: str,
                       names: Sequence[str] | None = None, factor: str = "speakers") -> tuple[str, ...]:
    """The speakers (or, ``factor`` "emotions", the emotions) of the utterances in order of first
    appearance (the first is the reference), or ``names`` checked to cover them; an utterance without
    one is an error naming it."""
    seen: dict[str, None] = {}
    for u in utterances:
        if column not in u.meta or not str(u.meta[column]):
            raise SpecError(f"[model] {factor} = {mode!r}: utterance {u.name!r} has no {column!r} "
                             f"(manifest column named by [model] {factor[:-1]}_column)")
        seen.setdefault(str(u.meta[column]), None)
    if names is None:
        return tuple(seen)
    extra = [s for s in seen if s not in names]
    if extra:
        raise SpecError(f"[model] {factor}: {factor[:-1]}(s) {', '.join(extra)} not among {', '.join(names)}")
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


SPEAKER_SEP = "|"  # row label of phoneme p for speaker s: "p|s"
INTENSITY_SEP = "*"  # row label of phoneme p for emotion e at intensity s (not 1): "p|e*s"


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
    # "speakers", or "emotions" ([model] emotions = "targets", coartic.estimation.emotions): the
    # same rows per emotion, the reference (first name) the neutral one, whose targets the table holds
    factor: str = "speakers"

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(f"{self.base[p]}{SPEAKER_SEP}{self.names[s]}" for p, s in self.rows)

    def leader(self, p: int) -> int:
        """The first row of base phoneme p (which holds its shared values)."""
        return next(r for r, (q, _) in enumerate(self.rows) if q == p)

    def collapse(self, params: FloatArray) -> FloatArray:
        """The table's matrix: each phoneme's shared values (its leader row) and as target the mean
        of its speakers' targets (the population); for emotions the leader's (the neutral) target."""
        out = np.array([params[self.leader(p)] for p in range(len(self.base))], dtype=np.float64)
        if self.factor == "emotions":
            return out
        k = PARAMETERS.index("target")
        for p in range(len(self.base)):
            out[p, k] = float(np.mean([params[r, k] for r, (q, _) in enumerate(self.rows) if q == p]))
        return out

    def targets(self, params: FloatArray) -> dict[str, dict[str, float]]:
        """Each speaker's own targets: speaker -> phoneme -> target (the phonemes it spoke)."""
        return self.values(params, "target")

    def values(self, params: FloatArray, parameter: str) -> dict[str, dict[str, float]]:
        """Each speaker's (emotion's) value of ``parameter``: name -> phoneme -> value."""
        k = PARAMETERS.index(parameter)
        out: dict[str, dict[str, float]] = {n: {} for n in self.names}
        for r, (p, s) in enumerate(self.rows):
            out[self.names[s]][self.base[p]] = float(params[r, k])
        return out

    def shrink_groups(self, source: Path | str | None, groups: Sequence[ShrinkGroup]) -> list[ShrinkGroup]:
        """The base phonemes' [[shrink]] groups on the leader rows (targets are per speaker: refused)."""
        out = []
        for g in groups:
            if g.parameter == "target":
                raise SpecError.at(source, g.key, f"shrinks target, but [model] {self.factor} = \"targets\" gives "
                                   f"every {self.factor[:-1]} its own targets: shrink the dynamics only")
            out.append(replace(g, rows=tuple(self.leader(i) for i in g.rows)))
        return out


def expand_speaker_targets(settings: EstimationSettings, data: ChannelData, ps: ParameterSet, data_start: bool = True,
                           names: Sequence[str] | None = None,
                           start_targets: Mapping[str, Mapping[str, float]] | None = None,
                           factor: str = "speakers", own: Sequence[str] = (),
                           start_own: Mapping[str, Mapping[str, Mapping[str, float]]] | None = None,
                           ) -> tuple[ChannelData, ParameterSet, SpeakerRows]:
    """The per-speaker problem of ``[model] speakers = "targets"`` from the base one: data relabelled
    ``p|s``, the parameter set with a row per (phoneme, speaker), shared entries tied to the first
    row, targets per row. Targets start at each speaker's own data targets (``data_start``), at
    ``start_targets`` (speaker -> phoneme -> target: a fitted table's, for MCMC), or at the base
    start. ``names`` fixes the speakers' order (the reference first).

    ``factor`` "emotions" makes the same rows per emotion (``[model] emotions = "targets"``, column
    ``[model] emotion_column``; ``names`` then starts with the neutral emotion, whose rows lead, so
    every phoneme must occur in a neutral trial). ``own``: other parameters every row has its own of
    where the phoneme's is free (not tied to its first row: ``[model] emotions = "targets+dynamics"``'s
    alpha, theta_bw, theta_fw), started at the first row's or at ``start_own`` (parameter -> name ->
    phoneme -> value: a fitted table's)."""
    column = settings.groups.speaker_column if factor == "speakers" else settings.groups.emotion_column
    where = settings.source
    spk = utterance_speakers(data.utterances, "targets", column, names, factor)
    bad = [n for n in spk if SPEAKER_SEP in n]
    if bad:
        raise SpecError.at(where, "model", f"{factor} = \"targets\": {factor[:-1]} name {bad[0]!r} contains "
                           f"{SPEAKER_SEP!r}")
    kt = PARAMETERS.index("target")
    for f, ld in ps.ties:
        if f % N_PARAMS == kt:
            tie = next((f"tie #{i + 1}.parameters" for i, t in enumerate(settings.parameters.ties) if "target" in t.parameters), "tie")
            raise SpecError.at(where, tie, "a tie of target cannot be combined with "
                               f"[model] {factor} = \"targets\" (every {factor[:-1]} has its own targets)",
                               parameter="target")
    base = tuple(data.phonemes)
    occurs = {(base.index(lab), spk.index(str(u.meta[column]))) for u in data.utterances for lab in u.labels}
    rows = tuple((p, s) for s in range(len(spk)) for p in range(len(base)) if (p, s) in occurs)
    if factor == "emotions":
        alone = [base[p] for p in range(len(base)) if (p, 0) not in occurs]
        if alone:
            raise SpecError.at(where, "model", f"emotions = \"targets\": phoneme(s) {', '.join(alone)} occur in "
                               f"no {spk[0]!r} trial: each emotion is fitted as a deviation from the neutral "
                               f"target, so record them neutrally too (or drop them with [corpus] select)")
    sr = SpeakerRows(spk, base, rows, factor)
    labels = sr.labels
    # an emotion's trials at a known intensity s other than 1 (coartic.emotions.trial_intensity): their
    # segments use rows of their own, after the others, whose target is (1 − s)·neutral + s·emotion
    # (Packing.mixes), so each such trial sees its emotion's deviation scaled by s
    scale = [1.0 if factor != "emotions" or str(u.meta[column]) == spk[0] else trial_intensity(u)
             for u in data.utterances]
    scaled = sorted({(base.index(lab), spk.index(str(u.meta[column])), s_u)
                     for u, s_u in zip(data.utterances, scale) if s_u != 1.0 for lab in u.labels})
    if scaled and own:
        raise SpecError.at(where, "model", f"{factor} = \"targets+dynamics\" with trials at an intensity other "
                           f"than 1 (manifest column {INTENSITY_COLUMN!r}): an intensity scales the target "
                           "deviations only; fit them with emotions = \"targets\" (or leave the column empty)")
    own_cols = {PARAMETERS.index(q) for q in own}

    def at(s_u: float) -> str:
        return "" if s_u == 1.0 else f"{INTENSITY_SEP}{s_u!r}"

    mixed_labels = tuple(f"{labels[rows.index((p, e))]}{at(s_u)}" for p, e, s_u in scaled)
    utts = [Utterance([f"{lab}{SPEAKER_SEP}{u.meta[column]}{at(s_u)}" for lab in u.labels], u.starts, u.ends, u.times,
                      u.name, u.observed, u.valid, u.meta) for u, s_u in zip(data.utterances, scale)]
    data_x = ChannelData.build(utts, data.channel, labels + mixed_labels)
    all_rows = rows + tuple((p, e) for p, e, _ in scaled)
    idx = [p for p, _ in all_rows]
    matrix, lower, upper = ps.matrix[idx].copy(), ps.lower[idx].copy(), ps.upper[idx].copy()
    free = ps.free[idx].copy()
    origins = None if ps.origins is None else ps.origins[idx].copy()
    # a base entry tied to another phoneme's ([[tie]]) follows that phoneme's leader row directly
    ultimate = {f: ld for f, ld in ps.ties}
    base_free = moving(ps.free, ps.ties)
    ties: list[tuple[int, int]] = []
    for r, (p, s) in enumerate(all_rows):
        for k in range(N_PARAMS):
            if k == kt:
                continue
            src = ultimate.get(p * N_PARAMS + k, p * N_PARAMS + k)
            lead = sr.leader(src // N_PARAMS) * N_PARAMS + k
            if k in own_cols and src == p * N_PARAMS + k and ps.free[p, k]:
                v = (start_own or {}).get(PARAMETERS[k], {}).get(spk[s], {}).get(base[p])
                if v is not None:
                    matrix[r, k] = float(v)
                continue  # this row's own value, free
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
    mixes = []
    for i, (p, e, s_u) in enumerate(scaled):
        r, lead, row_e = len(rows) + i, sr.leader(p), rows.index((p, e))
        free[r, kt] = False  # follows its neutral and emotion rows
        mixes.append((r * N_PARAMS + kt, ((lead * N_PARAMS + kt, 1.0 - s_u), (row_e * N_PARAMS + kt, s_u))))
        matrix[r, kt] = (1.0 - s_u) * matrix[lead, kt] + s_u * matrix[row_e, kt]
    out = ParameterSet(ps.channel, labels + mixed_labels, matrix, free, lower, upper, ps.beta, ps.beta_free,
                       ps.beta_bounds, priors=priors, origins=origins)
    out.ties = tuple(ties)
    out.mixes = tuple(mixes)
    return data_x, out, sr


def table_speaker_meta(groups: GroupSettings, where: str, table: ParameterTable) -> dict[str, Any]:
    """A fitted table's ``metadata.speakers``, refused (``TableError`` naming the table and ``where``,
    the settings' spec file) unless ``groups`` have the same ``[model] speakers`` and column: a problem
    around the table must be the model it was fitted with. ``{}`` for a table fitted without speakers."""
    raw = (table.metadata or {}).get("speakers")
    meta: dict[str, Any] = raw if isinstance(raw, dict) else {}
    mode, told = groups.speakers, meta.get("mode")
    if mode == "none":
        if told:
            raise TableError(f"{table.source}: fitted with [model] speakers = {told!r}, but {where} has none: "
                             "use the spec the table was fitted with")
        return meta
    if told != mode or meta.get("column") != groups.speaker_column:
        raise TableError(f"{table.source}: {where} has [model] speakers = {mode!r} (column "
                         f"{groups.speaker_column!r}), but the table was fitted with "
                         f"{'no speakers' if not told else repr(told) + ' (column ' + repr(meta.get('column')) + ')'}: "
                         "use the spec the table was fitted with")
    return meta
