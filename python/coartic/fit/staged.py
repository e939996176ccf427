"""Staged fitting: targets first, then timing and dynamics, then resistance and shape.

With all parameters free from a rough start, the joint fit can settle in a poor minimum (the paper
warns of several). Each stage frees more parameters, starting from the previous stage's optimum:
stage 1 finds the targets with the dynamics held at their starting values, stage 2 adds α, θ, c, δ,
stage 3 adds k_R, σ, ψ (and β). Stages are cumulative, so the last one is the full fit: staging
can only change where the last fit starts from, never what it may fit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.fit.engines import EngineResult, get_engine, local_options
from coartic.estimation.pooling import SETTLED, TARGET_FAMILY, TAU_BOUNDS, PoolEstimate, estimate, residual_weight, settled
from coartic.estimation.problem import ChannelProblem
from coartic.table import PARAMETERS


@dataclass
class StageResult:
    parameters: tuple[str, ...]  # the parameters free in this stage
    n_free: int
    sse_start: float
    sse_end: float
    engine: EngineResult
    probe: bool = False  # a multi-start probe, capped on purpose: its limit is no finding


# The statuses a fit can end with, in the order one outranks another in a channel's status:
# - "interrupted": Ctrl-C; the best point so far was kept
# - "failed", "non-finite start": the engine produced no fit (coartic fit stops, exit status 2)
# - "max-evaluations": a stage or the final fit stopped at its evaluation or iteration limit
# - "stage-failed": an earlier stage failed, the final fit went on from its best point and converged;
#   or the fit converged and a partial pooling re-solve at a later sd failed (that round's optimum kept)
# - "best-found-once": a multi-start whose best optimum only one start reached
# - "converged"
STATUSES = ("interrupted", "failed", "non-finite start", "max-evaluations", "stage-failed", "best-found-once",
            "converged")
# The fit was written but is not to be trusted as it stands: `coartic fit` exits with status 3.
UNCONFIRMED_STATUSES = ("max-evaluations", "stage-failed", "best-found-once")


def channel_status(final: EngineResult, stages: Sequence[StageResult], best_found_once: bool = False) -> tuple[str, str]:
    """A channel's status and message from its final result and every stage, honest about the
    stages: a failed or limited stage shows even when the last one converged."""
    if final.status != "converged":
        return final.status, final.message
    for i, st in enumerate(stages[:-1]):  # the last stage's status is the final one
        if st.probe:
            continue
        if st.engine.status in ("failed", "max-evaluations"):
            status = "stage-failed" if st.engine.status == "failed" else "max-evaluations"
            return status, (f"stage {i + 1} ({', '.join(st.parameters)}) ended {st.engine.status}: "
                            f"{st.engine.message}; the next stage went on from its best point")
    if best_found_once:
        return "best-found-once", ("the best optimum was reached from one start only (no other ended within the "
                                   "noise of it): more starts may find a better one")
    return final.status, final.message


def stage_free_sets(problem: ChannelProblem, stages: Sequence[Sequence[str]]) -> list[tuple[NDArray[np.bool_], bool, tuple[str, ...]]]:
    """Cumulative free masks; whatever the full fit frees but no stage names joins the last stage."""
    full, full_beta = problem.packing.free, problem.packing.beta_free
    named: set[str] = set()
    out: list[tuple[NDArray[np.bool_], bool, tuple[str, ...]]] = []
    for i, st in enumerate(stages):
        named |= set(st)
        if i == len(stages) - 1:
            named |= set(PARAMETERS) | {"beta"}
        cols = np.array([p in named for p in PARAMETERS])
        mask = full & cols[None, :]
        beta = full_beta and "beta" in named
        if mask.any() or beta:
            if out and mask.sum() == out[-1][0].sum() and beta == out[-1][1]:
                continue  # this stage frees nothing new
            freed = [p for k, p in enumerate(PARAMETERS) if mask[:, k].any()] + (["beta"] if beta else [])
            out.append((mask, beta, tuple(freed)))
    return out


def fit_staged(problem: ChannelProblem, engine: str, options: dict[str, Any], stages: Sequence[Sequence[str]] | None,
               on_stage: Callable[[int, int, ChannelProblem], None] | None = None) -> tuple[ChannelProblem, EngineResult, list[StageResult]]:
    """Run the stages (or one full fit when ``stages`` is None) and return the final problem and result.

    A stage that is interrupted or fails to produce a finite start ends the sequence; its best point
    is carried into the final problem so that the partial result is still usable.
    """
    minimize = get_engine(engine)
    full = problem.packing
    sets = stage_free_sets(problem, stages) if stages else [(full.free, full.beta_free, ())]
    params, beta = full.base, full.base_beta
    results: list[StageResult] = []
    res: EngineResult | None = None
    nfev = njev = 0
    for i, (mask, bfree, names) in enumerate(sets):
        packing = full.with_free(mask, bfree, params, beta)
        prob = problem.with_packing(packing)
        prob.nfev = prob.njev = 0
        if on_stage is not None:
            on_stage(i, len(sets), prob)
        x0 = packing.pack()
        try:
            sse0 = prob.sse(x0)
            res = minimize(prob, x0, options)
            sse1 = prob.sse(res.x)
        except KeyboardInterrupt:  # outside the engine's own guard: keep the best point seen
            res = EngineResult(prob.best_x, "interrupted", "stopped by the user (Ctrl-C); best point kept",
                               prob.nfev, prob.njev)
            sse0 = sse0 if "sse0" in locals() else float("nan")
            sse1 = prob.best_sse
        nfev += prob.nfev
        njev += prob.njev
        params, beta = packing.unpack(res.x)
        results.append(StageResult(names, packing.n_free, sse0, sse1, res))
        if res.status in ("interrupted", "non-finite start"):
            break
    assert res is not None
    # The final problem always carries the full free set (statistics need every free column).
    packing = full.with_free(full.free, full.beta_free, params, beta)
    out = problem.with_packing(packing)
    out.nfev, out.njev = nfev, njev
    x = packing.pack()
    res = EngineResult(x, res.status, res.message, nfev, njev, polished=res.polished)
    return out, res, results


# MAP re-solves at most, alternating with the τ estimate, before the pool is reported unsettled.
# The alternation creeps where a family's τ is weakly determined (German EMA, one utterance, the
# target prior's centres counted: α's τ 1.5 → 0.001 over 15 rounds, 5 % a round, then settled);
# 12 stopped such fits half way, at a τ that depended on the start (held out 2.59 against 2.66 mm).
# Since the estimate's exact gradient, the secant (``next_scales``) and the 2-cycle stop (``two_cycle``):
# 1-9 re-solves on the data of docs/REAL_DATA.md
POOL_ROUNDS = 30
# The most the secant stretches one round's step of a creeping τ (``next_scales``): a trust region,
# so that each jump is verified by the re-solve and the estimate at its end before the next one.
STRETCH_MAX = 8.0


def next_scales(history: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]], lower: NDArray[np.float64],
                upper: NDArray[np.float64], still: float, stretchable: NDArray[np.bool_]) -> NDArray[np.float64]:
    """The next (log σ, log τ_f...) of the alternation from its rounds so far, ``history``: per
    round, s (the scales the optimum was solved at) and g (the estimate there). The last g, except
    where a τ creeps.

    The alternation is a fixed-point iteration s → G(s) in the logs, residual R = G(s) − s. Where a
    τ is weakly determined, G′ is close to 1 in its coordinate and each round moves it a fraction
    1 − G′ of the way left (α's τ on the German EMA by 0.03-0.05 in log a round for ten rounds). The
    secant through the last two rounds estimates G′ ≈ q = 1 + ΔR / Δs and puts the fixed point
    R / (1 − q) away (Aitken's Δ², Steffensen's method coordinate by coordinate; in the traces one
    family creeps at a time while the others have settled). The step is stretched by 1 / (1 − q),
    at most ``STRETCH_MAX``, only where the coordinate creeps: its last three residuals and steps
    of one sign, 0 < q < 1, the residual beyond ``still`` (its settled tolerance: no stretching of
    re-solve noise). Everything else takes the plain step, so that where the alternation does not
    creep, its path and the fixed point it reaches stay as they were: an oscillation (q < 0: the
    evidence of a τ with two maxima, the optimum moving between two basins) is not damped toward a
    middle that the plain alternation would leave again (tried: on the German EMA it found other
    fixed points, held out up to 0.3 mm away). Only the coordinates ``stretchable`` are: not σ (n
    samples determine it; it moves because the τ do), nor the target prior's τ (its rows' sd is
    √(τ² + v_i): below the centres' sd the evidence is flat in it, and a run of its steps says
    little about where it ends; stretched, it overshot on the German EMA's time split, JO, into the
    other maximum, 0.65 → 0.04, and took three rounds more). A round still ends settled only where
    the estimate at the optimum for s is s itself (``settled``)."""
    out = history[-1][1].copy()  # the estimate: within the bounds already
    if len(history) < 3:
        return out
    (s2, g2), (s1, g1), (s, g) = history[-3:]
    r, r1, r2, ds, ds1 = g - s, g1 - s1, g2 - s2, s - s1, s1 - s2
    for i in np.flatnonzero(stretchable):
        if abs(r[i]) <= still or min(r[i] * r1[i], r[i] * r2[i], r[i] * ds[i], r[i] * ds1[i]) <= 0:
            continue
        q = 1.0 + (r[i] - r1[i]) / ds[i]
        if 0.0 < q < 1.0:
            out[i] = np.clip(s[i] + min(1.0 / (1.0 - q), STRETCH_MAX) * r[i], lower[i], upper[i])
    return out


# A 2-cycle (``two_cycle``): the rounds return to within this fraction of the jump between them
CYCLE_RETURN = 1 / 8


def two_cycle(scales: Sequence[NDArray[np.float64]]) -> bool:
    """Whether the last four rounds' scales (logs) go back and forth between two points: each
    round's within ``CYCLE_RETURN`` of the jump (max over the coordinates) of where it was two rounds
    before, twice in a row. One return is not enough: the alternation on the German EMA (LOO 0020,
    LA) went θ_bw's τ 1.14 → 0.03 → 1.27 → 0.01 and settled there (a return within a sixth of the
    jump); nor is a longer cycle that drifts (LOO 0024, JO: a cycle of six rounds, left after
    two and a half by the τ's jump to its floor) a cycle to stop."""
    if len(scales) < 4:
        return False
    s = list(scales[-4:])
    jump = min(float(np.max(np.abs(s[i + 1] - s[i]))) for i in range(3))
    back = max(float(np.max(np.abs(s[3] - s[1]))), float(np.max(np.abs(s[2] - s[0]))))
    return jump > 2 * SETTLED and back <= CYCLE_RETURN * jump


def fit_pooled(problem: ChannelProblem, x: NDArray[np.float64], engine: str, options: dict[str, Any],
               rounds: int = POOL_ROUNDS, w: float | None = None) -> tuple[ChannelProblem, EngineResult | None, PoolEstimate]:
    """Partial pooling's empirical Bayes (``coartic.estimation.pooling``): from the optimum ``x`` of
    ``problem`` (its pool at its starting τ and σ), alternate the τ and σ that maximise the Laplace
    evidence at the current optimum and the optimum (one local fit from the last) at those τ, σ,
    until τ and σ settle: a fixed-point iteration in the logs of τ, σ, whose creeping steps the secant
    stretches (``next_scales``) and which stops, not settled, when it goes back and forth between two
    scales (``two_cycle``). Returns the problem at the final τ, σ (its packing's base the optimum),
    the last engine result (None if the first estimate already matched) and the estimate.
    ``w``: the data weight n_eff / n (``residual_weight``); default: from the residuals at ``x``."""
    assert problem.pool is not None
    minimize = get_engine(engine)
    # each re-solve starts at the last optimum, in its basin: local (nlopt's global phase ran once, in
    # the fit before; at every round it cost 2000 evaluations, and 30 rounds at a limit 60 000)
    options = local_options(engine, options)
    res: EngineResult | None = None
    est: PoolEstimate | None = None
    # every evaluation made here (the re-solves' and the evidence's residuals and Jacobians), so that
    # the problem returned counts the fit's evaluations in all: the ones before (``problem.nfev`` on
    # entry) and these. Before, it counted the last re-solve's alone (a pooled fit of 852 evaluations
    # reported 21).
    n_in, j_in = problem.nfev, problem.njev
    nfev = njev = 0
    # the box of the logs (σ unbounded: the estimate bounds it); per counted round, its (s, G(s))
    # and what it had (problem, optimum, estimate, re-solve), for a cycle's best round
    lower = np.array([-np.inf] + [np.log(TAU_BOUNDS[0])] * len(problem.pool.families))
    upper = np.array([np.inf] + [np.log(TAU_BOUNDS[1])] * len(problem.pool.families))
    history: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    stretchable = np.array([False] + [f != TARGET_FAMILY for f in problem.pool.families])
    kept: list[tuple[ChannelProblem, NDArray[np.float64], PoolEstimate, EngineResult | None]] = []
    polished: list[str] = []  # re-solves another local method finished: said, not silent (PoolEstimate.polished)
    for k in range(rounds + 1):
        n0, j0 = problem.nfev, problem.njev
        r = problem.residuals(x)
        j = problem.jacobian(x)
        nfev += problem.nfev - n0
        njev += problem.njev - j0
        nd = r.size - problem.pool_size
        d = problem.data
        if k == 0 and w is None:  # once, at the first optimum: a pooled fit's smoother misfit must not feed back into w
            w, _ = residual_weight(r[: d.corpus.n_samples], d.sample_offsets, d.weights)
        assert w is not None
        # the evidence counts the target prior's centres as estimates (Pool.counted), whatever the start
        est = estimate(r[:nd], j[:nd].toarray(), problem.pool.counting(), problem.packing, x, d.n_valid, w)
        # settled, unless the last re-solve stopped at its evaluation limit: then it is resumed (from
        # its point, at the same τ) rather than reported unconverged (nlopt's L-BFGS on the default
        # spec, docs/REAL_DATA.md "Partial pooling")
        if (settled(problem.pool, est) and (res is None or res.status != "max-evaluations")) or k == rounds:
            est = replace(est, rounds=k, settled=settled(problem.pool, est))
            break
        fams = list(est.tau)
        here = np.log([problem.pool.sigma] + [problem.pool.tau[f] for f in fams])
        there = np.log([est.sigma] + [est.tau[f] for f in fams])
        if k >= 1:  # the first estimate counted the target prior's centres where the fit at the start did not
            history.append((here, there))
            kept.append((problem, x, est, res))
            if two_cycle([h for h, _ in history]):
                # the alternation goes back and forth between two scales without settling: it would
                # until the last round (the synthetic session's LLO, the rate split: θ_fw's τ 0.82 →
                # 1.64 → 0.82 for thirty rounds, 40 CPU-s; the estimate there jumps between two maxima of
                # the evidence and none of the scales between is its own estimate, so there is no fixed
                # point between to settle at). Of the two, the round whose estimate has the higher
                # evidence is kept, not settled (fit_pooled_best compares optima by the same)
                best = max((-1, -2), key=lambda i: kept[i][2].log_evidence)
                problem, x, est, res = kept[best]
                est = replace(est, rounds=k, settled=False, cycle=2)
                break
        before = problem
        nxt = next_scales(history, lower, upper, SETTLED, stretchable) if history else there
        # the estimate's own values where the step is not stretched (exp(log τ) may differ in its last bit)
        tau = {f: est.tau[f] if nxt[i + 1] == there[i + 1] else float(np.exp(nxt[i + 1])) for i, f in enumerate(fams)}
        assert problem.pool is not None  # (a round kept from a cycle is a pooled problem too)
        problem = problem.with_pool(problem.pool.counting().with_scales(tau, est.sigma, est.temper))
        problem.nfev = problem.njev = 0  # the engines report the problem's own counts
        res = minimize(problem, x, options)
        nfev += problem.nfev
        njev += problem.njev
        if res.polished:
            polished.append(f"re-solve {k + 1}: {res.message}")
        if res.status in ("interrupted", "failed", "non-finite start"):
            # the last optimum kept is the previous round's, so its problem (pool at that round's τ,
            # σ) is kept with it: statistics at the new τ around the old optimum would be neither fit
            problem = before if res.status != "interrupted" else problem
            est = replace(est, rounds=k + 1, settled=False)
            break
        x = res.x
    assert est is not None
    est = replace(est, polished=tuple(polished))
    params, beta = problem.packing.unpack(x)
    problem.packing.base, problem.packing.base_beta = params, beta
    problem.nfev, problem.njev = n_in + nfev, j_in + njev
    if res is not None:
        res = EngineResult(x, res.status, res.message, nfev, njev)
    return problem, res, est


# The multi-start's distinct optima that empirical Bayes is run from, at most (the best by the
# objective at the starting τ; start 0's own optimum is always among them)
EB_CANDIDATES = 4


def fit_pooled_best(problem: ChannelProblem, xs: Sequence[NDArray[np.float64]], engine: str, options: dict[str, Any],
                    objectives: Sequence[float] | None = None, weigh_at: int = 0
                    ) -> tuple[ChannelProblem, EngineResult | None, PoolEstimate]:
    """Empirical Bayes (``fit_pooled``) from each optimum in ``xs`` (internal vectors of
    ``problem``'s packing, the best first: a multi-start's distinct optima at the starting τ), the
    one whose settled τ has the highest Laplace evidence kept. The alternation of τ and the MAP has
    several fixed points where the optima at the starting τ differ: on the German EMA (LA, utterance
    0024, the default spec) the best of them led to α free per phoneme (τ_α 1.2, log evidence −41.7)
    and start 0's to one shared value (τ → 0, −35.8), so which one the multi-start happened to
    reach first decided the fit (held out 2.54 against 2.76 mm from seeds 0 and 1). The evidence is
    compared at one data weight w, the residuals' at ``xs[weigh_at]`` (evidences at different w are
    not comparable). The runner weighs at start 0's optimum, the single fit's, which no seed
    changes: the fixed points move with w (weighed at the best optimum instead, 0.057 against start
    0's 0.045 on that example, start 0's own alternation settled per phoneme, not shared, and seed 3
    ended 0.24 mm from seed 0 held out). The estimate records every candidate
    (``PoolEstimate.candidates``)."""
    assert problem.pool is not None and len(xs) >= 1
    d = problem.data
    r0 = problem.residuals(xs[weigh_at])
    w, _ = residual_weight(r0[: d.corpus.n_samples], d.sample_offsets, d.weights)
    best: tuple[ChannelProblem, EngineResult | None, PoolEstimate] | None = None
    best_ok = False
    chosen = 0  # the kept candidate's index in ``tried``
    tried: list[dict[str, float]] = []
    nfev = njev = 0
    for i, x in enumerate(xs):
        pk = problem.packing
        start = problem.with_packing(pk.with_free(pk.free, pk.beta_free, *pk.unpack(x)))
        start.nfev = start.njev = 0
        out = fit_pooled(start, start.packing.pack(), engine, options, w=w)
        nfev += out[0].nfev  # this candidate's evaluations in all (fit_pooled's count from 0)
        njev += out[0].njev
        if out[1] is not None and out[1].status == "interrupted":
            best = out if best is None else best
            break
        tried.append({"objective_start": float(objectives[i]) if objectives is not None else float("nan"),
                      "log_evidence": out[2].log_evidence, "rmse_mm": out[0].data_rmse(out[0].packing.pack()),
                      "effective_parameters": out[2].effective})
        # a candidate whose re-solve failed (its τ not settled) wins only over others that failed too
        ok = out[1] is None or out[1].status not in ("failed", "non-finite start")
        if best is None or (ok, out[2].log_evidence) > (best_ok, best[2].log_evidence):
            best, best_ok, chosen = out, ok, len(tried) - 1
    assert best is not None
    prob, res, est = best
    est = replace(est, candidates=tuple(tried), chosen=chosen)
    # the fit's evaluations: those before (the multi-start's) and every candidate's
    prob.nfev, prob.njev = problem.nfev + nfev, problem.njev + njev
    if res is None and chosen > 0:  # the kept optimum needed no re-solve: it is the result all the same
        res = EngineResult(prob.packing.pack(), "converged", "empirical Bayes settled at this optimum", nfev, njev)
    elif res is not None:
        res = EngineResult(res.x, res.status, res.message, nfev, njev)
    return prob, res, est
