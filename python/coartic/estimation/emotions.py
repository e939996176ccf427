"""Emotion as a factor of the fit (spec ``[model] emotions = "targets"``, docs/EMOTIONS.md).

Each trial carries an emotion (manifest column ``[model] emotion_column``); the neutral one
(``[model] neutral_emotion``) is the reference. The problem has a row per (phoneme, emotion) that
occurs, as ``[model] speakers = "targets"`` has per speaker (``speakers.expand_speaker_targets``
with ``factor="emotions"``, the same rows and ties): the dynamics are shared, every emotion has its
own targets, and the table's targets are the neutral ones. The deviation of emotion e on phoneme p,
d = T(p|e) − T(p|neutral), has a Gaussian prior N(0, τ_e²) per channel and emotion, as a
``penalties.Shrinkage`` row pair (neutral row, emotion row): the pair's penalty depends on the
difference only, so it shrinks the deviation toward 0 (toward neutral), not the neutral target.

τ_e is estimated from the data, not picked: from the fit without the prior, the method of moments
of random-effects meta-analysis (DerSimonian and Laird 1986): τ̂² = max(0, mean_p(d̂_p² − v_p)),
v_p the sampling variance of d̂_p from the fit's covariance σ̂²(JᵀJ)⁻¹ (σ̂² = SSE / residual
degrees of freedom). The fit is then run again from that point with the prior (``fit.runner``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.errors import SpecError
from coartic.estimation.parameters import psd_pseudo_inverse
from coartic.estimation.penalties import ShrinkGroup
from coartic.estimation.speakers import SpeakerRows, utterance_speakers
from coartic.model import Utterance
from coartic.table import PARAMETERS, ParameterTable, TableError

if TYPE_CHECKING:
    from coartic.estimation.settings import GroupSettings

FloatArray = NDArray[np.float64]
# Ekman's six, in the order the papers list them; other names follow in order of appearance
EKMAN: tuple[str, ...] = ("joy", "surprise", "sadness", "disgust", "anger", "fear")
# the smallest τ (mm): a deviation scale the data put at 0 pools the emotion completely (a prior sd of
# 1 µm, far below any marker system's noise), yet keeps the penalty finite
TAU_FLOOR = 1e-3
SHRINK_KEY = "emotions"  # the key the pair groups are named by in reports
# [model] emotions = "targets+dynamics": the dynamics each emotion has its own of per phoneme (where
# the phoneme's is free), each deviation log(v_e / v_neutral) pooled toward 0 with an sd per parameter
# and emotion that the data estimate (coartic.estimation.pooling: the family "emotion <parameter> <emotion>")
DYNAMICS: tuple[str, ...] = ("alpha", "theta_bw", "theta_fw")


def own_parameters(mode: str) -> tuple[str, ...]:
    """The non-target parameters an emotion's rows have their own of under ``[model] emotions = mode``."""
    return DYNAMICS if mode == "targets+dynamics" else ()


def dynamics_family(parameter: str, emotion: str) -> str:
    return f"emotion {parameter} {emotion}"


def dynamics_groups(rows: SpeakerRows, free: NDArray[np.bool_], start_sd: float) -> list[ShrinkGroup]:
    """The pooling groups of ``targets+dynamics``: per parameter of ``DYNAMICS``, emotion and phoneme,
    the pair (neutral row, emotion row) on the log scale, drawn toward their mean, so the penalty
    depends on the deviation log(v_e / v_n) only; family per parameter and emotion (its τ estimated by
    empirical Bayes: τ → 0 pools the emotion's dynamics into the neutral ones)."""
    labels = rows.labels
    out = []
    for q in DYNAMICS:
        k = PARAMETERS.index(q)
        for n, r, e in pairs(rows):
            if free[r, k]:
                out.append(ShrinkGroup("model.emotions", (labels[n], labels[r]), (n, r), k, start_sd, True,
                                       dynamics_family(q, rows.names[e])))
    return out


def emotion_names(utterances: Sequence[Utterance], column: str, neutral: str) -> tuple[str, ...]:
    """The emotions of the utterances, the neutral one first, then Ekman's six in their order, then
    others in order of appearance; a corpus without a neutral trial is refused (nothing to deviate from)."""
    seen = utterance_speakers(utterances, "targets", column, None, "emotions")
    if neutral not in seen:
        raise SpecError(f"[model] emotions = \"targets\": no trial has {column} = {neutral!r} (the neutral "
                        f"emotion, [model] neutral_emotion); the corpus has {', '.join(seen)}")
    rest = [e for e in EKMAN if e in seen] + [e for e in seen if e != neutral and e not in EKMAN]
    return (neutral, *rest)


@dataclass(frozen=True)
class EmotionPrior:
    """The deviation prior of one channel: τ per emotion (mm) and the residual noise σ̂ (mm) it is
    weighed against (the penalty is σ̂² d² / τ², the negative log prior in SSE units)."""

    tau: Mapping[str, float]
    noise: float

    def as_dict(self) -> dict[str, Any]:
        return {"tau": {e: float(t) for e, t in self.tau.items()}, "noise": float(self.noise)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> EmotionPrior:
        return cls({str(e): float(t) for e, t in d["tau"].items()}, float(d["noise"]))


def pairs(rows: SpeakerRows) -> list[tuple[int, int, int]]:
    """(neutral row, emotion row, emotion index) of every non-neutral row of the problem."""
    out = []
    for r, (p, e) in enumerate(rows.rows):
        if e != 0:
            out.append((rows.leader(p), r, e))
    return out


def shrink_groups(rows: SpeakerRows, prior: EmotionPrior, prior_noise: float) -> list[ShrinkGroup]:
    """The prior as ``Shrinkage`` groups: one pair (neutral row, emotion row) per deviation, on the
    target. A pair's rows are prior_noise·(±d/2)/sd, squares summing to prior_noise²·d²/(2 sd²); with
    sd = (τ/√2)·prior_noise/σ̂ that is σ̂² d² / τ²."""
    k = PARAMETERS.index("target")
    labels = rows.labels
    out = []
    for n, r, e in pairs(rows):
        tau = max(float(prior.tau[rows.names[e]]), TAU_FLOOR)
        sd = tau / math.sqrt(2.0) * prior_noise / prior.noise
        out.append(ShrinkGroup(f"{SHRINK_KEY}.{rows.names[e]}", (labels[n], labels[r]), (n, r), k, sd))
    return out


def target_covariance(problem: Any, x: FloatArray) -> tuple[FloatArray, dict[int, int], float]:
    """σ̂²(JᵀJ)⁻¹ over x at the point x, the x column of each row's free target, and σ̂ (mm). The
    pseudo-inverse: a direction the data do not determine (a dynamics parameter of no influence)
    gets no variance rather than an error."""
    r = problem.residuals(x)
    j = problem.jacobian(x)
    n_data = problem.data.n_valid
    dof = max(n_data - problem.packing.n_free, 1)
    sse = float(np.sum(r[: problem.data.observed.size] ** 2))  # the data's rows, not the prior's
    sigma2 = sse / dof
    jtj = np.asarray((j.T @ j).toarray())
    cov = sigma2 * psd_pseudo_inverse(jtj)[0]
    return cov, row_columns(problem, "target"), math.sqrt(sigma2)


def row_columns(problem: Any, parameter: str) -> dict[int, int]:
    """The x column of each row's free ``parameter`` (x is log v for a log parameter)."""
    k = PARAMETERS.index(parameter)
    col = {int(c): i for i, c in enumerate(problem.packing.free_columns)}
    rows = problem.speaker_rows
    return {r_: col[r_ * len(PARAMETERS) + k] for r_ in range(len(rows.rows)) if r_ * len(PARAMETERS) + k in col}


def deviations(rows: SpeakerRows, params: FloatArray, parameter: str = "target") -> dict[str, dict[str, float]]:
    """emotion -> phoneme -> d = T(p|e) − T(p|neutral) (mm) for a matrix of the problem's rows; for a
    log parameter (``DYNAMICS``) log(v(p|e) / v(p|neutral))."""
    k = PARAMETERS.index(parameter)
    log = parameter != "target"
    out: dict[str, dict[str, float]] = {e: {} for e in rows.names[1:]}
    for n, r, e in pairs(rows):
        a, b = float(params[r, k]), float(params[n, k])
        out[rows.names[e]][rows.base[rows.rows[r][0]]] = math.log(a / b) if log else a - b
    return out


def deviation_sd(rows: SpeakerRows, cov: FloatArray, targets: Mapping[int, int]) -> dict[str, dict[str, float]]:
    """emotion -> phoneme -> sd of d from a covariance over x (a fixed target contributes 0)."""
    out: dict[str, dict[str, float]] = {e: {} for e in rows.names[1:]}
    for n, r, e in pairs(rows):
        cn, cr = targets.get(n), targets.get(r)
        v = ((cov[cr, cr] if cr is not None else 0.0) + (cov[cn, cn] if cn is not None else 0.0)
             - (2.0 * cov[cr, cn] if cr is not None and cn is not None else 0.0))
        out[rows.names[e]][rows.base[rows.rows[r][0]]] = math.sqrt(max(float(v), 0.0))
    return out


def estimate_prior(problem: Any, x: FloatArray) -> EmotionPrior:
    """τ per emotion (method of moments, module docstring) and σ̂ from an unpenalised fit at x."""
    rows: SpeakerRows = problem.speaker_rows
    params, _ = problem.packing.unpack(x)
    cov, targets, sigma = target_covariance(problem, x)
    d = deviations(rows, params)
    sd = deviation_sd(rows, cov, targets)
    tau = {}
    for e in rows.names[1:]:
        moments = [d[e][p] ** 2 - sd[e][p] ** 2 for p in d[e]]
        tau[e] = math.sqrt(max(float(np.mean(moments)), 0.0)) if moments else 0.0
    return EmotionPrior(tau, max(sigma, 1e-9))


def channel_metadata(problem: Any, x: FloatArray) -> dict[str, Any]:
    """This channel's part of a table's ``metadata.emotions``: each emotion's targets, deviations and
    their Laplace sd (the penalised fit's σ̂²(JᵀJ)⁻¹, prior rows included), and the prior."""
    rows: SpeakerRows = problem.speaker_rows
    params, _ = problem.packing.unpack(x)
    cov, targets, _ = target_covariance(problem, x)
    out = {"targets": rows.targets(params), "deviations": deviations(rows, params),
           "deviation_sd": deviation_sd(rows, cov, targets),
           **(problem.emotion_prior.as_dict() if problem.emotion_prior is not None else {})}
    k_free = {q: row_columns(problem, q) for q in DYNAMICS}
    own = [q for q in DYNAMICS if any(r in k_free[q] for _, r, _ in pairs(rows))]
    if own:
        # targets+dynamics: each emotion's own values, their log deviations from neutral and sd
        out["dynamics"] = {q: {"values": rows.values(params, q), "deviations": deviations(rows, params, q),
                               "deviation_sd": deviation_sd(rows, cov, k_free[q])} for q in own}
    return out


def table_emotion_meta(groups: GroupSettings, where: str, table: ParameterTable) -> dict[str, Any]:
    """A fitted table's ``metadata.emotions``, refused (``TableError`` naming the table and ``where``,
    the settings' spec file) unless ``groups`` have the same ``[model] emotions`` and column: a problem
    around the table must be the model it was fitted with. ``{}`` for a table fitted without emotions."""
    raw = (table.metadata or {}).get("emotions")
    meta: dict[str, Any] = raw if isinstance(raw, dict) else {}
    told = meta.get("mode")
    if groups.emotions == "none":
        if told:
            raise TableError(f"{table.source}: fitted with [model] emotions = {told!r}, but {where} has none: "
                             "use the spec the table was fitted with")
        return meta
    if told != groups.emotions or meta.get("column") != groups.emotion_column:
        raise TableError(f"{table.source}: {where} has [model] emotions = {groups.emotions!r} (column "
                         f"{groups.emotion_column!r}), but the table was fitted with "
                         f"{'no emotions' if not told else repr(told) + ' (column ' + repr(meta.get('column')) + ')'}: "
                         "use the spec the table was fitted with")
    return meta


# ----------------------------------------------------------------------------- corner asymmetries

ASYMMETRY: tuple[str, ...] = ("ASYMX", "ASYMY")
# the meta keys a trial's mean corner asymmetry is kept under (fit.data.load_rows, asymmetry=True)
ASYMMETRY_META: dict[str, str] = {"ASYMX": "corner_asymx_mm", "ASYMY": "corner_asymy_mm"}
CORNER_MARKERS: tuple[str, ...] = ("NOSE", "EAR_L", "EAR_R", "LC_L", "LC_R")


def corner_asymmetry(markers: FloatArray, names: Sequence[str]) -> dict[str, float] | None:
    """A trial's mean corner asymmetries (mm) in the head frame of MODEL.md §6 (x towards EAR_L, y
    up): ASYMX the right corner's outward displacement minus the left's, −(x_L + x_R); ASYMY the right
    corner's height minus the left's (the two asymmetry parameters of Magno Caldognetto et al.).
    None when the trial lacks a corner or a head marker (EMA: no corners)."""
    from coartic import _core

    if any(n not in names for n in CORNER_MARKERS):
        return None
    i = {n: list(names).index(n) for n in CORNER_MARKERS}
    head = np.asarray(_core.head_frame(np.ascontiguousarray(markers, dtype=np.float64), i["NOSE"], i["EAR_L"],
                                       i["EAR_R"]))
    left, right = head[:, i["LC_L"]], head[:, i["LC_R"]]
    ax, ay = -(left[:, 0] + right[:, 0]), right[:, 1] - left[:, 1]
    if not (np.isfinite(ax).any() and np.isfinite(ay).any()):
        return None
    return {"ASYMX": float(np.nanmean(ax)), "ASYMY": float(np.nanmean(ay))}


def asymmetry_metadata(utterances: Sequence[Utterance], column: str, neutral: str) -> dict[str, Any]:
    """Each emotion's corner asymmetries relative to the neutral trials' (mm): the difference of the
    trial means, with a Welch 95 % interval (scipy.stats). {} when the trials carry none."""
    from scipy import stats

    per: dict[str, dict[str, list[float]]] = {}
    for u in utterances:
        if not all(k in u.meta for k in ASYMMETRY_META.values()):
            continue
        e = str(u.meta.get(column, ""))
        for a, key in ASYMMETRY_META.items():
            per.setdefault(e, {}).setdefault(a, []).append(float(u.meta[key]))
    if neutral not in per:
        return {}
    out: dict[str, Any] = {}
    for e, vals in per.items():
        if e == neutral:
            continue
        out[e] = {}
        for a in ASYMMETRY:
            x, y = np.asarray(vals[a]), np.asarray(per[neutral][a])
            d = float(x.mean() - y.mean())
            if x.size > 1 and y.size > 1:
                vx, vy = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
                se = math.sqrt(vx + vy)
                dof = (vx + vy) ** 2 / max(vx**2 / (x.size - 1) + vy**2 / (y.size - 1), 1e-300)
                h = float(stats.t.ppf(0.975, dof)) * se
            else:
                h = math.inf
            out[e][a] = {"value": d, "q2.5": d - h, "q97.5": d + h}
    return out
