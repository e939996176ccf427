"""Optimisation engines. Each has ``minimize(problem, x0, options) -> EngineResult``.

Every engine is fed the Rust core's exact derivatives through ``ChannelProblem`` and returns the
best point it saw, whatever happened (divergence, evaluation failures, Ctrl-C). What they share
is in ``coartic.fit.engines.base``; each engine module is imported when its engine is asked for
(nlopt and CasADi load only when used; they come with the [engines] extra).
"""

from __future__ import annotations

from typing import Any

from coartic.errors import UsageError
from coartic.extras import EXTRAS, require
from coartic.fit.engines.base import (Check, EngineResult, Minimizer, OptionError, Unit, check_against,
                                      evaluation_budget, is_int, is_number, iteration_budget, prepare_start)

__all__ = ["Check", "EngineResult", "Minimizer", "OptionError", "Unit", "check_against", "check_options",
           "evaluation_budget", "get_engine", "is_int", "is_number", "iteration_budget", "local_options",
           "prepare_start"]


def _require(name: str) -> None:
    """nlopt and CasADi come with the [engines] extra; SciPy with every install."""
    if name in EXTRAS["engines"]:
        require("engines", f"the {name} engine", (name,))


def get_engine(name: str) -> Minimizer:
    """The engine's minimize function (imported lazily: nlopt and CasADi load only when used)."""
    _require(name)
    if name == "scipy":
        from coartic.fit.engines.scipy_ls import minimize
    elif name == "nlopt":
        from coartic.fit.engines.nlopt_engine import minimize
    elif name == "casadi":
        from coartic.fit.engines.casadi_engine import minimize
    else:
        raise UsageError(f"unknown engine {name!r} (scipy, nlopt, casadi)")
    return minimize


def check_options(name: str, options: dict[str, Any]) -> None:
    """Refuse engine options of the wrong name, type or value before any fit starts (raising
    ``OptionError`` naming the option), instead of a SciPy TypeError or a CasADi RuntimeError
    from inside the first channel's fit."""
    _require(name)
    if name == "scipy":
        from coartic.fit.engines.scipy_ls import check_options as check
    elif name == "nlopt":
        from coartic.fit.engines.nlopt_engine import check_options as check
    elif name == "casadi":
        from coartic.fit.engines.casadi_engine import check_options as check
    else:
        raise UsageError(f"unknown engine {name!r} (scipy, nlopt, casadi)")
    check(options)


def local_options(name: str, options: dict[str, Any]) -> dict[str, Any]:
    """``options`` for a local fit from a point already in its basin (a multi-start's start, a
    partial-pooling re-solve from the last optimum): nlopt's global phase off (it looks for the
    basin: run at every pooling round, its 2000 evaluations were most of a fit of up to 40 free
    parameters); the other engines are local already."""
    return {**options, "global": "none"} if name == "nlopt" else dict(options)
