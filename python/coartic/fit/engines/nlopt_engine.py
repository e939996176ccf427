"""nlopt: a global multi-start phase, then a local gradient polish, on the SSE and its exact gradient.

The paper warns of several minima; this engine looks for the basin before polishing it. The
search runs on x scaled to the unit box by its bounds (one scale for every parameter).

Options: ``global`` ('mlsl' = G_MLSL_LDS with a local L-BFGS from low-discrepancy starts,
'crs2' = GN_CRS2_LM, 'none', or 'auto' (default): 'mlsl' up to 40 free parameters, else 'none'), ``global_maxeval`` (default 2000), ``local`` ('lbfgs' or
'slsqp'; SLSQP's dense QP stalls on whole corpora), ``local_maxeval`` (default 5000), ``ftol_rel``
and ``xtol_rel`` (1e-15: L-BFGS then stops on round-off, not early),
``population`` (0 = nlopt's default), ``seed`` (0).
"""

from __future__ import annotations

from typing import Any

import nlopt
import numpy as np
from numpy.typing import NDArray

from coartic.fit.engines import EngineResult, Unit, prepare_start
from coartic.fit.problem import ChannelProblem

_GLOBAL = {"mlsl": nlopt.G_MLSL_LDS, "crs2": nlopt.GN_CRS2_LM}
_LOCAL = {"lbfgs": nlopt.LD_LBFGS, "slsqp": nlopt.LD_SLSQP}
AUTO_GLOBAL_MAX_FREE = 40
_BIG = 1e300  # nlopt's local methods stall on inf; a huge finite value rejects the point


def minimize(problem: ChannelProblem, x0: NDArray[np.float64], options: dict[str, Any]) -> EngineResult:
    # Tolerances far below what L-BFGS reaches: looser ones stopped it early on whole corpora
    # (RMSE 0.176 instead of 0.137 mm on 150 synthetic trials); it ends on round-off instead.
    o: dict[str, Any] = {"global": "auto", "global_maxeval": 2000, "local": "lbfgs", "local_maxeval": 5000,
                         "ftol_rel": 1e-15, "xtol_rel": 1e-15, "population": 0, "seed": 0}
    unknown = set(options) - set(o)
    if unknown:
        raise ValueError(f"[engine.options] unknown nlopt option(s) {sorted(unknown)}; known: {sorted(o)}")
    o.update(options)
    if o["global"] == "auto":
        # A multi-start search is affordable, and worked, on a few dozen parameters; on a whole
        # channel (60-250 free) MLSL ended in nlopt's generic failure after its budget (docs/FITTING.md).
        o["global"] = "mlsl" if x0.size <= AUTO_GLOBAL_MAX_FREE else "none"
    if o["global"] not in (*_GLOBAL, "none") or o["local"] not in _LOCAL:
        raise ValueError(f"[engine.options] global must be one of {[*_GLOBAL, 'none']}, local one of {list(_LOCAL)}")
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
        loc.set_maxeval(int(o["local_maxeval"]))
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
                inner.set_maxeval(max(50, int(o["local_maxeval"]) // 10))
                g.set_local_optimizer(inner)
            if int(o["population"]) > 0:
                g.set_population(int(o["population"]))
            g.set_min_objective(f)
            g.set_maxeval(int(o["global_maxeval"]))
            current[:] = [g]
            try:
                g.optimize(z)
            except (nlopt.ForcedStop, nlopt.RoundoffLimited, nlopt.runtime_error, RuntimeError) as e:
                messages.append(f"global phase stopped: {type(e).__name__} {e}")
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
            except (nlopt.ForcedStop, nlopt.runtime_error, RuntimeError) as e:
                code = -99
                messages.append(f"local phase stopped: {type(e).__name__} {e}"
                                + (f" (last model error: {problem.last_error})" if problem.last_error else ""))
            messages.append(f"local {o['local']}: nlopt result {code}")
            status = "converged" if code in (nlopt.SUCCESS, nlopt.FTOL_REACHED, nlopt.XTOL_REACHED,
                                             nlopt.STOPVAL_REACHED, nlopt.ROUNDOFF_LIMITED) else (
                "max-evaluations" if code == nlopt.MAXEVAL_REACHED else "failed")
    except KeyboardInterrupt:
        interrupted = True
    if interrupted:
        return EngineResult(problem.best_x, "interrupted", "stopped by the user (Ctrl-C); best point kept",
                            problem.nfev, problem.njev)
    return EngineResult(problem.best_x, status, "; ".join(messages), problem.nfev, problem.njev)
