"""nlopt: a global multi-start phase, then a local gradient polish, on the SSE and its exact gradient.

The paper warns of several minima; this engine looks for the basin before polishing it. The
search runs on x scaled to the unit box by its bounds (one scale for every parameter).

Options: ``global`` ('mlsl' = G_MLSL_LDS with a local L-BFGS from low-discrepancy starts,
'crs2' = GN_CRS2_LM, 'none', or 'auto' (default): 'mlsl' up to 40 free parameters, else 'none'), ``global_maxeval`` (default 2000), ``local`` ('lbfgs' or
'slsqp'; SLSQP's dense QP stalls on whole corpora), ``local_maxeval`` (default ``coartic.fit.engines.evaluation_budget``), ``ftol_rel``
and ``xtol_rel`` (1e-15: L-BFGS then stops on round-off, not early),
``population`` (0 = nlopt's default), ``seed`` (0), ``polish`` ('scipy' (default) or 'none').

nlopt's L-BFGS ends in its generic FAILURE when it cannot take a first step, e.g. started at the
optimum the global phase found with a parameter on its bound (the default spec of a German EMA
utterance: MLSL reached scipy's optimum, L-BFGS then failed and the whole fit was refused). With
``polish = 'scipy'`` such a local failure is finished by SciPy's least_squares (trust-region
reflective, bounded, the default engine) from the best point nlopt found, and the result says so
(``EngineResult.polished``, the message, the fit report and the console).
"""

from __future__ import annotations

from typing import Any

import nlopt
import numpy as np
from numpy.typing import NDArray

from coartic.fit.engines.base import (Check, EngineResult, Unit, check_against, evaluation_budget, is_int,
                                      is_number, prepare_start)
from coartic.estimation.problem import ChannelProblem

_GLOBAL = {"mlsl": nlopt.G_MLSL_LDS, "crs2": nlopt.GN_CRS2_LM}
_LOCAL = {"lbfgs": nlopt.LD_LBFGS, "slsqp": nlopt.LD_SLSQP}
AUTO_GLOBAL_MAX_FREE = 40
_BIG = 1e300  # nlopt's local methods stall on inf; a huge finite value rejects the point
# nlopt's result codes by name (nlopt.h), for messages.
_RESULTS = {1: "SUCCESS", 2: "STOPVAL_REACHED", 3: "FTOL_REACHED", 4: "XTOL_REACHED", 5: "MAXEVAL_REACHED",
            6: "MAXTIME_REACHED", -1: "FAILURE", -2: "INVALID_ARGS", -3: "OUT_OF_MEMORY", -4: "ROUNDOFF_LIMITED",
            -5: "FORCED_STOP"}


def _nlopt_message(opt: nlopt.opt, err: BaseException) -> str:
    """nlopt's own words: its error message (``get_errmsg``: e.g. which bound a start violates)
    rather than the exception's generic "nlopt failure"."""
    detail = opt.get_errmsg() if hasattr(opt, "get_errmsg") else None
    return f"{type(err).__name__}: {detail or err}"


# Tolerances far below what L-BFGS reaches: looser ones stopped it early on whole corpora
# (RMSE 0.176 instead of 0.137 mm on 150 synthetic trials); it ends on round-off instead.
DEFAULTS: dict[str, Any] = {"global": "auto", "global_maxeval": 2000, "local": "lbfgs", "local_maxeval": None,
                            "ftol_rel": 1e-15, "xtol_rel": 1e-15, "population": 0, "seed": 0, "polish": "scipy"}


def check_options(options: dict[str, Any]) -> None:
    """Every option this engine knows, checked for type and value."""
    checks: dict[str, Check] = {
        "global": (lambda v: v in ("auto", "none", *_GLOBAL), f"one of auto, none, {', '.join(_GLOBAL)}"),
        "local": (lambda v: v in _LOCAL, f"one of {', '.join(_LOCAL)}"),
        "global_maxeval": (lambda v: is_int(v, 0), "an integer >= 0"),
        "local_maxeval": (lambda v: is_int(v, 1), "a positive integer"),
        "ftol_rel": (lambda v: is_number(v, 0.0), "a number >= 0"),
        "xtol_rel": (lambda v: is_number(v, 0.0), "a number >= 0"),
        "population": (lambda v: is_int(v, 0), "an integer >= 0"),
        "seed": (lambda v: is_int(v, 0), "an integer >= 0"),
        "polish": (lambda v: v in ("scipy", "none"), "'scipy' or 'none'"),
    }
    check_against("an nlopt", checks, options)


def minimize(problem: ChannelProblem, x0: NDArray[np.float64], options: dict[str, Any]) -> EngineResult:
    check_options(options)
    o = dict(DEFAULTS)
    o.update(options)
    if o["global"] == "auto":
        # A multi-start search is affordable, and worked, on a few dozen parameters; on a whole
        # channel (60-250 free) MLSL ended in nlopt's generic failure after its budget (docs/FITTING.md).
        o["global"] = "mlsl" if x0.size <= AUTO_GLOBAL_MAX_FREE else "none"
    x0, bad = prepare_start(problem, x0)
    if bad is not None:
        return bad
    lo, hi = problem.packing.bounds()
    unit = Unit(lo, hi)
    n = x0.size
    interrupted = False
    current: list[nlopt.opt] = []

    def f(z: NDArray[np.float64], grad: NDArray[np.float64]) -> float:
        nonlocal interrupted
        try:
            x = unit.x(z)
            if grad.size:
                sse, g = problem.sse_gradient(x)
                g = g * unit.width
                if not (np.isfinite(sse) and np.all(np.isfinite(g))):
                    sse, g = np.inf, np.zeros_like(g)  # a rejected point, never NaN into nlopt
                grad[:] = g
            else:
                sse = problem.sse(x)
        except KeyboardInterrupt:
            interrupted = True
            for opt in current:
                opt.force_stop()
            return _BIG
        return sse if np.isfinite(sse) else _BIG

    def local_opt() -> nlopt.opt:
        loc = nlopt.opt(_LOCAL[o["local"]], n)
        loc.set_lower_bounds(unit.z_lo)
        loc.set_upper_bounds(unit.z_hi)
        loc.set_ftol_rel(o["ftol_rel"])
        loc.set_xtol_rel(o["xtol_rel"])
        loc.set_maxeval(int(o["local_maxeval"]) if o["local_maxeval"] is not None else evaluation_budget(problem))
        return loc

    nlopt.srand(int(o["seed"]))
    z = np.clip(unit.z(x0), unit.z_lo, unit.z_hi)
    messages = []
    try:
        if o["global"] != "none" and int(o["global_maxeval"]) > 0:
            g = nlopt.opt(_GLOBAL[o["global"]], n)
            g.set_lower_bounds(unit.z_lo)
            g.set_upper_bounds(unit.z_hi)
            if o["global"] == "mlsl":
                inner = local_opt()
                inner.set_maxeval(max(50, (int(o["local_maxeval"]) if o["local_maxeval"] is not None
                                           else evaluation_budget(problem)) // 10))
                g.set_local_optimizer(inner)
            if int(o["population"]) > 0:
                g.set_population(int(o["population"]))
            g.set_min_objective(f)
            g.set_maxeval(int(o["global_maxeval"]))
            current[:] = [g]
            try:
                g.optimize(z)
            except (nlopt.ForcedStop, nlopt.RoundoffLimited, nlopt.exception, RuntimeError, ValueError) as e:
                messages.append(f"global phase stopped: {_nlopt_message(g, e)}")
            messages.append(f"global {o['global']}: best SSE {problem.best_sse:.6g}")
            z = unit.z(problem.best_x)
        z = np.clip(z, unit.z_lo, unit.z_hi)  # round-off must not put the start outside the box
        if not interrupted:
            loc = local_opt()
            loc.set_min_objective(f)
            current[:] = [loc]
            try:
                loc.optimize(z)
                code = loc.last_optimize_result()
            except nlopt.RoundoffLimited:
                code = nlopt.ROUNDOFF_LIMITED  # L-BFGS at the limit of precision: at the minimum
            except (nlopt.ForcedStop, nlopt.exception, RuntimeError, ValueError) as e:
                code = loc.last_optimize_result()
                code = code if code < 0 else nlopt.FAILURE
                messages.append(f"local phase stopped: {_nlopt_message(loc, e)}"
                                + (f" (last model error: {problem.last_error})" if problem.last_error else ""))
            messages.append(f"local {o['local']}: nlopt result {code} ({_RESULTS.get(code, 'unknown')})")
            status = "converged" if code in (nlopt.SUCCESS, nlopt.FTOL_REACHED, nlopt.XTOL_REACHED,
                                             nlopt.STOPVAL_REACHED, nlopt.ROUNDOFF_LIMITED) else (
                "max-evaluations" if code == nlopt.MAXEVAL_REACHED else "failed")
    except KeyboardInterrupt:
        interrupted = True
    if interrupted:
        return EngineResult(problem.best_x, "interrupted", "stopped by the user (Ctrl-C); best point kept",
                            problem.nfev, problem.njev)
    if status == "failed" and o["polish"] == "scipy" and np.isfinite(problem.best_sse):
        return _polish(problem, messages)
    return EngineResult(problem.best_x, status, "; ".join(messages), problem.nfev, problem.njev)


def _polish(problem: ChannelProblem, messages: list[str]) -> EngineResult:
    """The fit finished by SciPy's least_squares from nlopt's best point (its local phase failed)."""
    from coartic.fit.engines import scipy_ls  # the default engine: a sibling, imported when needed

    before = problem.best_sse
    res = scipy_ls.minimize(problem, problem.best_x.copy(), {})
    messages.append(f"polished by scipy least_squares (trf) from nlopt's best point, SSE {before:.6g} -> "
                    f"{problem.best_sse:.6g}: {res.status} ({res.message})")
    return EngineResult(problem.best_x, res.status, "; ".join(messages), problem.nfev, problem.njev, polished=True)
