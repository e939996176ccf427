"""Partial pooling with an estimated strength: hierarchical priors whose sd τ the data choose
(empirical Bayes), ``[parameters] pooled`` and ``[parameters] target_prior = "estimated"``.

The general piece is a *family*: a set of least-squares prior rows that share one sd τ, which is
estimated, not given. Two kinds of rows exist today:

- **groups** (``coartic.estimation.penalties.ShrinkGroup`` with ``family`` set): the members of a
  group (rows of the parameter matrix, one column) drawn toward the group's own mean, one row
  ``σ (u_i − ū) / τ`` per member (u the value or its log). ``[parameters] pooled = ["theta_bw"]``
  makes one group per channel, every phoneme of the channel, family ``"pooled theta_bw"``: each
  phoneme's log θ_bw drawn toward the channel's shared value. τ → 0 is one shared value
  (``[parameters] shared``), τ → ∞ a free value per phoneme. Any other grouping is the same
  machinery: a factor such as emotion is one group per phoneme (its rows for each emotion, as
  ``coartic.estimation.speakers.SpeakerRows`` makes per-speaker target rows) in one family per
  parameter, drawn toward the phoneme's value with an estimated τ;
- **means** (the target prior): every free target drawn toward its phoneme's mean over its segments
  (the step model's value, ``coartic.estimation.target_prior``), rows ``σ (T_i − m_i) / √(τ² + v_i)``.
  m_i is itself an estimate, the mean of n_i noisy samples: v_i = σ²/(w n_i) its variance (``w``
  below), so the prior is no tighter than its centre is known (``Pool.centre_variance``). Without v_i
  the evidence drives τ to its floor wherever the data are few: m_i was computed from the same data,
  so the data always agree with it and every τ > 0 only costs (in a step model exactly: the evidence
  then falls monotonically in τ), and a table pinned to the segment means is a smoothed step model
  (on the German EMA's one-utterance splits, the target sd at its floor in 4 of 6 fits;
  docs/REAL_DATA.md).

``Pool`` holds the rows of one channel, each family's current τ and the noise sd σ the rows are
weighed against (minimising SSE + Σ rows² is then the MAP of y ~ N(F, σ²), u ~ N(ū, τ²)).

**Estimating τ** (``estimate``): the Laplace approximation of the marginal likelihood p(y | σ, τ),
at the current optimum x̂, linearised with the core's exact Jacobian J (rows of the data) and the
prior rows' Jacobians K_f (unit sd):

    A = JᵀJ / σ² + Σ_f K_fᵀK_f / τ_f²,   g = Jᵀr / σ² + Σ_f K_fᵀz_f / τ_f²
    −log p(y | σ, τ) ≈ |r|²/2σ² + Σ_f |z_f|²/2τ_f² − ½ gᵀA⁻¹g + n log σ + Σ_f rank_f log τ_f + ½ log det A

(rank_f: the prior's rank, Σ (members − 1) over a family's groups, one per target prior row;
constants dropped; the target prior's rows each weighed by 1/(τ² + v_i) instead of 1/τ², and its
rank_f log τ_f is ½ Σ_i log(τ² + v_i)). The Gaussian likelihood counts every sample as independent; articulatory
residuals are not (a model error lasts many samples), and counted as n independent samples they
would swamp every prior (τ → ∞, per-phoneme fits, on any real recording). So the data are weighed
as n_eff = w n samples, w = 1/τ_int from the residuals' integrated autocorrelation time (Geyer's
initial positive sequence, as MCMC's effective sample size; ``residual_weight``): J, r and n above
are scaled by √w, √w and w, and the MAP's prior rows by σ/√w. White residuals have w ≈ 1,
the synthetic sessions fitted with the rate-aware model 1/4-1/6, the German EMA at 200 Hz about 1/20 (computed once, at the first optimum, so that a pooled fit's smoother misfit does not feed back into w). It is minimised over log σ and every log τ_f within ``TAU_BOUNDS``; the fit
then re-solves the MAP at the new τ and the two alternate until τ settles (``coartic.fit.staged.
fit_pooled``). The effective number of parameters is the trace of the hat matrix,
tr(A⁻¹ JᵀJ/σ²), and each family's γ_f = rank_f − tr(A⁻¹K_fᵀK_f)/τ_f² (0: pooled into one value,
rank_f: every member its own).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.optimize as so
from numpy.typing import NDArray

from coartic.estimation.packing import LOG_PARAMETERS, Packing, Prior
from coartic.estimation.penalties import Penalty, PenaltyRows, ShrinkGroup, Shrinkage
from coartic.errors import SpecError
from coartic.table import PARAMETERS

if TYPE_CHECKING:
    from coartic.estimation.settings import EstimationSettings

FloatArray = NDArray[np.float64]

TARGET_FAMILY = "target prior"
# τ's search box, in the family's units (log units for α, θ; mm for targets and c, k_R natural):
# 1e-3 is one shared value for any practical purpose, 1e3 a free one.
TAU_BOUNDS: tuple[float, float] = (1e-3, 1e3)
# Where τ starts: a moderate pull (a factor of e^0.3 ≈ 1.35 between phonemes' rates, 0.3 mm for a
# target: the fixed default of earlier versions); the estimate does not depend on it beyond the
# local optimum the first fit finds.
TAU_START = 0.3
# τ (and σ) are settled when no log changes by more than this between two rounds
SETTLED = 0.02


def family_of(parameter: str) -> str:
    return f"pooled {parameter}"


@dataclass(frozen=True)
class Pool:
    """The estimated prior families of one channel: groups toward their means, targets toward
    their segment means, each family's τ and the noise σ (mm) the rows are weighed against."""

    groups: tuple[ShrinkGroup, ...] = ()  # each with its family set
    target_means: Mapping[str, float] = field(default_factory=dict)  # "phoneme.target" -> mean (mm)
    tau: Mapping[str, float] = field(default_factory=dict)  # family -> τ
    sigma: float = 1.0
    # the weight w = n_eff / n of the data against the priors (autocorrelated residuals carry fewer
    # independent samples than there are samples: ``temper``); the rows' noise is σ / √w
    temper: float = 1.0
    # "phoneme.target" -> the samples its mean averages: the mean's own variance is noise² / n
    # (``centre_variance``); absent (a pool holding only scales): treated as known exactly
    target_counts: Mapping[str, float] = field(default_factory=dict)
    # whether the centres' variance is counted: not in the fit at the starting τ (the fixed start
    # prior of before, so the multi-start's optima and the data weight w do not move: the start
    # prior only picks the basin), from the first estimate on (``counting``) and in a fitted table's
    counted: bool = False

    @property
    def families(self) -> tuple[str, ...]:
        out = list(dict.fromkeys(str(g.family) for g in self.groups))
        return tuple(out + ([TARGET_FAMILY] if self.target_means else []))

    def rank(self, family: str) -> int:
        if family == TARGET_FAMILY:
            return len(self.target_means)
        return sum(len(g.rows) - 1 for g in self.groups if g.family == family)

    def rows(self, packing: Packing, unit: bool = False) -> list[PenaltyRows]:
        """The least-squares rows: the targets' then the groups' (``unit``: sd 1, noise 1, per family:
        z_f and K_f of the evidence)."""
        out: list[PenaltyRows] = []
        fams = self.families if unit else ((TARGET_FAMILY,) if self.target_means else ()) + ("*",)
        for fam in fams:
            if fam == TARGET_FAMILY:
                var = self.centre_variance(self.noise ** 2)
                sd = {k: 1.0 if unit else float(np.sqrt(self.tau[TARGET_FAMILY] ** 2 + var[k]))
                      for k in self.target_means}
                out.append(Penalty(packing, {k: Prior(m, sd[k]) for k, m in self.target_means.items()},
                                   1.0 if unit else self.noise))
            else:
                groups = [replace(g, sd=1.0 if unit else self.tau[str(g.family)]) for g in self.groups
                          if unit is False or g.family == fam]
                out.append(Shrinkage(packing, groups, 1.0 if unit else self.noise))
        return out

    def deviations(self, params: FloatArray, phonemes: Sequence[str]) -> list[FloatArray]:
        """Per family (``families`` order), the unit-sd deviations [..., rows] of parameter matrices
        ``params`` [..., n_phonemes, 10]: a group's members from their mean (on the log scale for log
        parameters), each target from its segment mean. The prior is −½ Σ_f |dev_f|² / τ_f² − rank_f log τ_f."""
        out = []
        for fam in self.families:
            if fam == TARGET_FAMILY:
                rows = [phonemes.index(k.rpartition(".")[0]) for k in self.target_means]
                out.append(params[..., rows, 0] - np.array(list(self.target_means.values())))
                continue
            parts = []
            for g in self.groups:
                if g.family != fam:
                    continue
                v = params[..., list(g.rows), g.column]
                with np.errstate(divide="ignore", invalid="ignore"):
                    u = np.log(v) if g.log else v
                parts.append(u - u.mean(axis=-1, keepdims=True))
            out.append(np.concatenate(parts, axis=-1))
        return out

    def centre_variance(self, noise2: float) -> dict[str, float]:
        """Per target prior, the variance of its centre (a segment mean of the noisy data, noise
        variance ``noise2`` per sample as the rows weigh it): noise2 / n. The prior T ~ N(mean, τ²)
        is centred on that estimate, so T ~ N(estimate, τ² + noise2 / n): a prior can be no tighter
        than its own centre is known. Without it the evidence finds τ → 0 wherever the data are few
        (the centre fits the data it was computed from: every τ > 0 only costs)."""
        return {k: noise2 / self.target_counts[k] if self.counted and self.target_counts.get(k) else 0.0
                for k in self.target_means}

    def counting(self) -> Pool:
        """This pool with its centres' variance counted (``counted``)."""
        return replace(self, counted=True)

    @property
    def noise(self) -> float:
        """The noise the rows are weighed against: σ / √w."""
        return float(self.sigma / np.sqrt(self.temper))

    def with_scales(self, tau: Mapping[str, float], sigma: float, temper: float | None = None) -> Pool:
        return replace(self, tau=dict(tau), sigma=float(sigma),
                       temper=self.temper if temper is None else float(temper))


def pool_from_settings(settings: EstimationSettings, channel: str, phonemes: Sequence[str], moving: NDArray[np.bool_],
                   priors: Mapping[str, Prior], start: Pool | None = None,
                   followers: frozenset[int] = frozenset(), counts: Mapping[str, float] | None = None) -> Pool | None:
    """The channel's pool from ``[parameters] pooled`` (one group of every phoneme per parameter)
    and ``target_prior = "estimated"`` (the target priors ``priors`` holds, taken out of the fixed
    ones by the caller); None when the settings estimate nothing. ``start``: τ and σ to start from
    (a fitted table's). ``followers``: flat entries tied to another (a [[tie]], a speaker's or
    emotion's row of a phoneme): not members of their own, each distinct value counts once."""
    groups = []
    pri = settings.priors
    for name in pri.pooled:
        k = PARAMETERS.index(name)
        if not moving[:, k].any():
            raise SpecError.at(settings.source, "parameters.pooled", f"{name} is free for no phoneme on {channel}: "
                               "nothing to pool")
        rows = tuple(i for i in range(len(phonemes)) if i * len(PARAMETERS) + k not in followers)
        if len(rows) >= 2:
            groups.append(ShrinkGroup("parameters.pooled", tuple(phonemes[i] for i in rows), rows, k,
                                      TAU_START, name in LOG_PARAMETERS, family_of(name)))
    means = {k: p.mean for k, p in priors.items()} if pri.target_prior == "estimated" else {}
    if not groups and not means:
        return None
    # a fitted table's τ were estimated with the centres' variance counted: so are they here (MCMC)
    pool = Pool(tuple(groups), means, {}, pri.prior_noise,
                target_counts={k: float(n) for k, n in (counts or {}).items() if k in means}, counted=start is not None)
    tau = {f: TAU_START for f in pool.families}
    sigma = pri.prior_noise
    if start is not None:
        tau.update({f: t for f, t in start.tau.items() if f in tau})
        sigma = start.sigma
    return pool.with_scales(tau, sigma, 1.0 if start is None else start.temper)


def with_groups(pool: Pool | None, groups: Sequence[ShrinkGroup], noise: float, start: Pool | None = None) -> Pool:
    """``pool`` (or an empty one weighed against ``noise``) with more estimated groups (each with its
    family set: an emotion's dynamics toward neutral, coartic.estimation.emotions.dynamics_groups),
    their τ from ``start`` (a fitted table's) where it has them, else ``TAU_START``."""
    base = pool if pool is not None else Pool((), {}, {}, noise)
    out = replace(base, groups=base.groups + tuple(groups))
    tau = {f: TAU_START for f in out.families} | dict(base.tau)
    if start is not None:
        tau.update({f: t for f, t in start.tau.items() if f in tau})
    sigma = base.sigma if pool is not None or start is None else start.sigma
    temper = base.temper if pool is not None or start is None else start.temper
    return out.with_scales(tau, sigma, temper)


@dataclass(frozen=True)
class PoolEstimate:
    """τ and σ that maximise the Laplace evidence at one optimum, and what they amount to."""

    tau: dict[str, float]
    sigma: float
    log_evidence: float  # at the estimate (constants dropped: compare within one channel only)
    effective: float  # tr(A⁻¹ JᵀJ/σ²): the effective number of parameters of the fit
    family_effective: dict[str, float]  # γ_f per family
    rank: dict[str, int]  # the prior rank of each family (its γ_f when τ → ∞)
    n_free: int
    at_bound: dict[str, str] = field(default_factory=dict)  # family -> "lower" (shared) / "upper" (free)
    rounds: int = 0  # MAP re-solves until τ settled (set by the fit)
    settled: bool = True
    cycle: int = 0  # not settled: the alternation went round a cycle of this many rounds (fit_pooled)
    temper: float = 1.0  # w = n_eff / n (residual_weight): 1 / the residuals' autocorrelation time
    n_valid: int = 0  # the samples n
    # empirical Bayes run from several optima (a multi-start's; coartic.fit.staged.fit_pooled_best):
    # each one's objective at the starting τ, settled log evidence, data RMSE and effective
    # parameters, and the index of the one kept (the highest evidence)
    candidates: tuple[dict[str, float], ...] = ()
    chosen: int = 0
    # the re-solves another local method finished (nlopt's failed L-BFGS polished by scipy), as
    # "re-solve k: the engine's message" (set by the fit; FitResult.polished reports them with the stages')
    polished: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, object]:
        return {"sigma_mm": self.sigma, "effective_parameters": self.effective, "free_parameters": self.n_free,
                "rounds": self.rounds, "settled": bool(self.settled), "cycle": self.cycle, "data_weight": self.temper,
                "polished": list(self.polished),
                "samples": self.n_valid, "log_evidence": self.log_evidence,
                "candidates": [dict(c) for c in self.candidates], "chosen": self.chosen,
                "families": {f: {"sd": t, "effective_parameters": self.family_effective[f], "rank": self.rank[f],
                                 "at_bound": self.at_bound.get(f, "")} for f, t in self.tau.items()}}

    def line(self, family: str) -> str:
        b = self.at_bound.get(family)
        where = {"lower": " (at its lower bound: one shared value)", "upper": " (at its upper bound: free per member)"}
        return (f"{family}: sd {self.tau[family]:.4g}{where.get(b or '', '')}, "
                f"{self.family_effective[family]:.2f} effective of {self.rank[family]}")


class Evidence:
    """The linearised Laplace evidence of one channel's problem at x̂, as a function of (σ, τ)."""

    def __init__(self, data_r: FloatArray, data_j: FloatArray, pool: Pool, packing: Packing, x: FloatArray,
                 n: float) -> None:
        self.families = pool.families
        self.rank = {f: pool.rank(f) for f in self.families}
        self.n = float(n)
        self.temper = 1.0  # w: the data weighed as n_eff = w n samples (``estimate`` sets it)
        self.gd = data_j.T @ data_j
        self.bd = data_j.T @ data_r
        self.sd = float(data_r @ data_r)
        self.gf, self.bf, self.sf = [], [], []
        # each family's K_fᵀK_f on the columns its rows touch (the rest of it is 0): ``_a`` adds that
        # block alone, the same sums as the whole d x d matrix (18 families of the emotions' dynamics:
        # the whole matrices took 2.5 of a 26 CPU-s fit)
        self.support: list[tuple[NDArray[np.signedinteger[Any]], ...]] = []
        self.block: list[FloatArray] = []
        # the target prior's rows one by one (each its own centre variance): K, z and n_eff per row
        self.tk: FloatArray | None = None
        self.tz = self.tn = np.zeros(0)
        for fam, rows in zip(self.families, pool.rows(packing, unit=True)):
            z = rows.residuals(x)
            k = rows.jacobian(x).toarray()
            if fam == TARGET_FAMILY:
                assert isinstance(rows, Penalty)
                cv = pool.centre_variance(1.0)  # 1 / n per row (0: a centre known exactly)
                self.tk, self.tz, self.tn = k, z, np.array([cv[key] for key in rows.names])
            self.gf.append(k.T @ k)
            on = np.flatnonzero(np.any(k != 0.0, axis=0))
            self.support.append(np.ix_(on, on))
            self.block.append(self.gf[-1][self.support[-1]])
            self.bf.append(k.T @ z)
            self.sf.append(float(z @ z))
        d = self.gd.shape[0]
        scale = max(float(np.max(np.diag(self.gd), initial=0.0)), 1e-300)
        # a direction neither the data nor a prior determine: a tiny ridge keeps log det finite (a
        # constant in σ, τ, so the estimate does not depend on it)
        self.ridge = 1e-10 * scale * np.eye(d)

    def prior_variances(self, s: FloatArray) -> list[FloatArray]:
        """Per family, its rows' prior variances at s: τ², plus (target prior) each centre's
        variance σ² / n_eff, σ the evidence's noise against the data weighed as n_eff = w n samples."""
        sig2 = np.exp(2 * s[0])
        return [np.exp(2 * t) + (sig2 * self.tn / self.temper if f == TARGET_FAMILY else 0.0)
                for f, t in zip(self.families, s[1:])]

    def _a(self, s: FloatArray) -> tuple[FloatArray, FloatArray, float, float]:
        """A, g, the quadratic constant and Σ_f ½ log det(prior covariance_f)."""
        sig2 = np.exp(2 * s[0])
        a = self.gd / sig2 + self.ridge
        g = self.bd / sig2
        l0 = self.sd / (2 * sig2)
        half_logdet = 0.0
        for f, v, on, gf, bf, sf in zip(self.families, self.prior_variances(s), self.support, self.block, self.bf,
                                        self.sf):
            if f == TARGET_FAMILY and self.tk is not None:
                p = 1.0 / v
                a = a + (self.tk.T * p) @ self.tk
                g = g + self.tk.T @ (p * self.tz)
                l0 += float(np.sum(p * self.tz ** 2)) / 2
                half_logdet += 0.5 * float(np.sum(np.log(v)))
                continue
            w = 1.0 / float(v)
            a[on] += gf * w
            g = g + bf * w
            l0 += sf * w / 2
            half_logdet += 0.5 * self.rank[f] * float(np.log(v))
        return a, g, l0, half_logdet

    def __call__(self, s: FloatArray) -> float:
        """−log evidence at s = (log σ, log τ_f...)."""
        a, g, l0, prior_logdet = self._a(s)
        try:
            c = sla.cho_factor(a)
        except np.linalg.LinAlgError:
            return np.inf
        quad = float(g @ sla.cho_solve(c, g))
        logdet = 2.0 * float(np.sum(np.log(np.diag(c[0]))))
        return float(l0 - 0.5 * quad + self.n * s[0] + prior_logdet + 0.5 * logdet)

    def value_and_gradient(self, s: FloatArray) -> tuple[float, FloatArray]:
        """−log evidence at s and its exact gradient in s, for the estimate's L-BFGS-B (by finite
        differences it took 7 evaluations a gradient, about 170 an estimate, a third of a pooled
        fit's CPU on the German EMA). With u = A⁻¹g and any one coordinate's derivatives dA, dg,
        dl0 and d(½ log det prior): d(−log p) = dl0 − uᵀdg + ½ uᵀdA u + d(½ log det prior)
        + ½ tr(A⁻¹ dA) (+ n for log σ)."""
        a, g, l0, prior_logdet = self._a(s)
        try:
            c = sla.cho_factor(a)
        except np.linalg.LinAlgError:
            return np.inf, np.zeros_like(s)
        u = sla.cho_solve(c, g)
        inv = sla.cho_solve(c, np.eye(a.shape[0]))
        value = float(l0 - 0.5 * float(g @ u) + self.n * s[0] + prior_logdet + np.sum(np.log(np.diag(c[0]))))
        grad = np.zeros_like(s, dtype=np.float64)
        sig2 = np.exp(2 * s[0])
        # log σ through the data's rows (weights 1/σ²: d/ds0 = −2 × the row's term)
        grad[0] = self.n - self.sd / sig2 + 2 * float(u @ self.bd) / sig2 - float(u @ self.gd @ u) / sig2 \
            - float(np.sum(inv * self.gd)) / sig2
        for i, (f, v, gf, bf, sf) in enumerate(zip(self.families, self.prior_variances(s), self.gf, self.bf, self.sf)):
            if f == TARGET_FAMILY and self.tk is not None:
                # each row's precision p_i = 1/v_i, v_i = τ² + σ² c_i: dp = −p² dv, dv/dlog τ = 2τ², dv/dlog σ
                # = 2σ² c_i. Per unit dp_i: dl0 = z_i²/2, dg = k_i z_i, dA = k_i k_iᵀ (k_i the row of K);
                # per unit dv_i the prior's ½ log v_i gives ½ / v_i
                p = 1.0 / v
                ku = self.tk @ u
                per_p = self.tz ** 2 / 2 - self.tz * ku + ku ** 2 / 2 + 0.5 * np.einsum("ij,jk,ik->i", self.tk, inv, self.tk)
                dv_tau = 2 * np.exp(2 * s[1 + i]) * np.ones_like(v)
                dv_sig = 2 * sig2 * self.tn / self.temper
                grad[1 + i] += float(np.sum(-p ** 2 * dv_tau * per_p + 0.5 * dv_tau / v))
                grad[0] += float(np.sum(-p ** 2 * dv_sig * per_p + 0.5 * dv_sig / v))
                continue
            w = 1.0 / float(v)  # d w / d log τ = −2 w
            grad[1 + i] = -2 * w * (sf / 2 - float(u @ bf) + float(u @ gf @ u) / 2 + float(np.sum(inv * gf)) / 2) \
                + self.rank[f]
        return value, grad

    def effective(self, s: FloatArray) -> tuple[float, dict[str, float]]:
        a = self._a(s)[0]
        inv = np.linalg.pinv(a, hermitian=True)
        total = float(np.sum(inv * self.gd.T) / np.exp(2 * s[0]))
        fam = {}
        for f, v, gf in zip(self.families, self.prior_variances(s), self.gf):
            if f == TARGET_FAMILY and self.tk is not None:
                fam[f] = float(self.rank[f] - np.sum(inv * ((self.tk.T / v) @ self.tk).T))
            else:
                fam[f] = float(self.rank[f] - np.sum(inv * gf.T) / float(v))
        return total, fam


def residual_weight(r: FloatArray, offsets: NDArray[np.int64], weights: FloatArray) -> tuple[float, float]:
    """w = n_eff / n of the residuals ``r`` (one per sample; ``offsets`` the utterances' sample
    offsets) and their integrated autocorrelation time τ_int = 1/w: the autocorrelation ρ_k over
    pairs of valid samples k apart within one utterance, summed by Geyer's initial positive
    sequence (τ_int = −1 + 2 Σ_m (ρ_2m + ρ_2m+1) while the pair sums stay positive, made
    non-increasing: Geyer's initial monotone sequence, 1992; the
    estimator of MCMC's effective sample size). White residuals give w ≈ 1; a model error that lasts
    many samples (articulatory recordings sampled at 100-400 Hz) as few independent samples as it holds.
    w is kept within [1/n, 1]."""
    r = np.where(weights > 0, r, 0.0)
    n = int(np.count_nonzero(weights > 0))
    den = float(r @ r)
    if n < 2 or den <= 0:
        return 1.0, 1.0
    utt = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))

    def rho(k: int) -> float:
        if k == 0:
            return 1.0
        same = utt[:-k] == utt[k:]
        return float(np.sum((r[:-k] * r[k:])[same]) / den)

    tau, m, last = -1.0, 0, np.inf
    longest = int(np.max(np.diff(offsets)))
    while 2 * m + 1 < longest:
        pair = min(rho(2 * m) + rho(2 * m + 1), last)  # Geyer's initial monotone sequence
        if pair <= 0:
            break
        tau += 2.0 * pair
        last = pair
        m += 1
    tau = max(tau, 1.0)
    return float(np.clip(1.0 / tau, 1.0 / n, 1.0)), tau


def estimate(data_r: FloatArray, data_j: FloatArray, pool: Pool, packing: Packing, x: FloatArray,
             n: int, w: float = 1.0) -> PoolEstimate:
    """σ and each family's τ maximising the linearised Laplace evidence at x (the current MAP);
    ``data_r``, ``data_j``: the problem's residual rows and Jacobian without the pool's rows; ``w``:
    n_eff / n of the residuals (``residual_weight``), the data weighed as n_eff samples (the
    likelihood tempered by w)."""
    ev = Evidence(np.sqrt(w) * data_r, np.sqrt(w) * np.asarray(data_j, dtype=np.float64), pool, packing, x, n)
    ev.n = w * n
    ev.temper = w
    fams = ev.families
    s0 = np.log(np.array([pool.sigma] + [pool.tau[f] for f in fams]))
    rms = np.sqrt(ev.sd / max(ev.n, 1e-300))
    lo_t, hi_t = np.log(TAU_BOUNDS)
    bounds = [(np.log(max(rms, 1e-6)) - 5.0, np.log(max(rms, 1e-6)) + 5.0)] + [(lo_t, hi_t)] * len(fams)
    s0 = np.clip(s0, [b[0] for b in bounds], [b[1] for b in bounds])
    # with the exact gradient: by finite differences L-BFGS-B stopped where the evidence is flat (a τ
    # far below what the data resolve: 0.01-0.03 instead of the bound), short of the maximum, so that
    # the next round's estimate moved on from there: the alternation crept by what was in effect the
    # estimate's own tolerance (the German EMA's LOO 0024, JO, 17 rounds to a τ at its bound, now 3)
    best = so.minimize(ev.value_and_gradient, s0, jac=True, method="L-BFGS-B", bounds=bounds)
    s = best.x if np.isfinite(best.fun) and best.fun <= ev(s0) else s0
    total, fam = ev.effective(s)
    tau = {f: float(np.exp(t)) for f, t in zip(fams, s[1:])}
    at = {f: ("lower" if t <= lo_t + 1e-3 else "upper") for f, t in zip(fams, s[1:])
          if t <= lo_t + 1e-3 or t >= hi_t - 1e-3}
    return PoolEstimate(tau, float(np.exp(s[0])), -float(ev(s)), total, fam, dict(ev.rank), packing.n_free, at,
                        temper=w, n_valid=int(n))


def settled(a: Pool, b: PoolEstimate) -> bool:
    """τ and σ within SETTLED (in log) of the pool's, and the pool's centres counted as the estimate's
    are. The target prior is compared by its rows' sd √(τ² + v_i), what the fit sees: a τ far below
    its centres' sd moves nothing (the evidence is flat there) and need not settle."""
    if any(a.target_counts.values()) and not a.counted:  # the estimate counted the centres, the pool's fit did not
        return False
    if abs(np.log(b.sigma / a.sigma)) > SETTLED or abs(np.log(b.temper / a.temper)) > SETTLED:
        return False
    for f in b.tau:
        if f == TARGET_FAMILY:
            v = np.array(list(a.centre_variance(a.noise**2).values()))
            va = a.tau[f] ** 2 + v
            vb = b.tau[f] ** 2 + v * (b.sigma**2 / b.temper) / (a.sigma**2 / a.temper)
            if np.max(np.abs(0.5 * np.log(vb / va)), initial=0.0) > SETTLED:
                return False
        elif abs(np.log(b.tau[f] / a.tau[f])) > SETTLED:
            return False
    return True
