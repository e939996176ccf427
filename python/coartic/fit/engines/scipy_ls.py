"""SciPy ``least_squares`` (trust-region reflective) with the Rust core's sparse Jacobian.

The fast default engine. Options (spec ``[engine.options]``): ``max_nfev`` (default
``coartic.fit.engines.evaluation_budget``: 100 per free parameter + 1 per 100 residuals, >= 1000),
``ftol``/``xtol``/``gtol`` (1e-8), ``loss`` ('linear'; 'soft_l1' etc. for outliers),
``tr_solver`` ('exact' densifies J, robust for the few hundred parameters of a channel; 'lsmr'
keeps it sparse: much faster on a whole corpus, where J has ~1e5 rows; default 'lsmr', and
'exact' for small problems (below 2e5 Jacobian entries).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from coartic.fit.engines.base import (Check, EngineResult, check_against, evaluation_budget, is_int, is_number,
                                      prepare_start)
from coartic.estimation.problem import ChannelProblem

_STATUS = {-1: "failed", 0: "max-evaluations", 1: "converged", 2: "converged", 3: "converged", 4: "converged"}
LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


def check_options(options: dict[str, Any]) -> None:
    """The least_squares options this engine passes on, each checked for type and value."""
    checks: dict[str, Check] = {
        "max_nfev": (lambda v: is_int(v, 1), "a positive integer"),
        "ftol": (lambda v: is_number(v, 0.0), "a number >= 0"),
        "xtol": (lambda v: is_number(v, 0.0), "a number >= 0"),
        "gtol": (lambda v: is_number(v, 0.0), "a number >= 0"),
        "loss": (lambda v: v in LOSSES, f"one of {', '.join(LOSSES)}"),
        "f_scale": (lambda v: is_number(v, positive=True), "a positive number"),
        "tr_solver": (lambda v: v in ("exact", "lsmr"), "'exact' or 'lsmr'"),
        "x_scale": (lambda v: v == "jac" or is_number(v, positive=True), "'jac' or a positive number"),
        # 'lm' (MINPACK) cannot take the bounds every fit has
        "method": (lambda v: v in ("trf", "dogbox"), "'trf' or 'dogbox' (the bounded methods)"),
        "verbose": (lambda v: v in (0, 1, 2) and not isinstance(v, bool), "0, 1 or 2"),
    }
    check_against("a scipy", checks, options)


def minimize(problem: ChannelProblem, x0: NDArray[np.float64], options: dict[str, Any]) -> EngineResult:
    x0, bad = prepare_start(problem, x0)
    if bad is not None:
        return bad
    lo, hi = problem.packing.bounds()
    opts = dict(options)
    n_entries = problem.data.corpus.n_samples * problem.packing.n_free
    tr_solver = opts.pop("tr_solver", "exact" if n_entries < 2e5 else "lsmr")
    jac = problem.jacobian
    if tr_solver == "exact":
        def jac(x: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.asarray(problem.jacobian(x).toarray(), dtype=np.float64)
    # The cap scales with the problem (evaluation_budget): a fixed cap of 200 ended one-utterance
    # fits of real EMA at max-evaluations (stage 2 needed 690-950 evaluations; docs/FITTING.md).
    kw: dict[str, Any] = dict(method="trf", x_scale="jac", ftol=1e-8, xtol=1e-8, gtol=1e-8, tr_solver=tr_solver,
                              max_nfev=evaluation_budget(problem))
    kw.update(opts)
    try:
        res = least_squares(problem.residuals, x0, jac=jac, bounds=(lo, hi), **kw)
    except KeyboardInterrupt:
        return EngineResult(problem.best_x, "interrupted", "stopped by the user (Ctrl-C); best point kept",
                            problem.nfev, problem.njev)
    except (ValueError, np.linalg.LinAlgError) as e:
        return EngineResult(problem.best_x, "failed", f"least_squares failed: {e}", problem.nfev, problem.njev)
    # least_squares returns its last accepted point; the tracker may hold a slightly better one.
    x = res.x if problem.sse(res.x) <= problem.best_sse else problem.best_x
    return EngineResult(x, _STATUS.get(res.status, "failed"), str(res.message), problem.nfev, problem.njev)
