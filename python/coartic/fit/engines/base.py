"""What every engine shares: its result, option checks, the start's check, and the budgets that
scale with the problem. The engine modules and the package's dispatch (``coartic.fit.engines``)
import it; it imports none of them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from coartic.errors import CoarticError
from coartic.estimation.problem import ChannelProblem


@dataclass
class EngineResult:
    x: NDArray[np.float64]
    status: str  # "converged", "max-evaluations", "interrupted", "failed", "non-finite start"
    message: str
    nfev: int
    njev: int
    # the engine's own local method stopped short and another one finished the fit from its best
    # point (nlopt: scipy least_squares after L-BFGS failed); ``message`` says which and why
    polished: bool = False

    @property
    def success(self) -> bool:
        return self.status == "converged"


Minimizer = Callable[[ChannelProblem, NDArray[np.float64], dict[str, Any]], EngineResult]


class OptionError(CoarticError, ValueError):
    """An engine option the engine cannot use: ``key`` is the option's name."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


Check = tuple[Callable[[Any], bool], str]  # (accepts the value?, what it should be)


def check_against(engine: str, checks: Mapping[str, Check], options: Mapping[str, Any]) -> None:
    """Each option known to ``checks`` and accepted by its test, else ``OptionError`` naming it."""
    for key, value in options.items():
        if key not in checks:
            raise OptionError(key, f"not {engine} option; known: {', '.join(sorted(checks))}")
        ok, what = checks[key]
        if not ok(value):
            raise OptionError(key, f"{value!r}: expected {what}")


def is_number(v: Any, low: float = -math.inf, positive: bool = False) -> bool:
    """A real number (not a bool), finite, >= low (or > 0 with ``positive``)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return False
    return v > 0 if positive else v >= low


def is_int(v: Any, low: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= low


def prepare_start(
    problem: ChannelProblem, x0: NDArray[np.float64]
) -> tuple[NDArray[np.float64], EngineResult | None]:
    """x0 clipped into the bounds, and an EngineResult explaining why it cannot start a fit (None
    if it can): every engine starts this way, so a bad start is reported alike by all of them."""
    lo, hi = problem.packing.bounds()
    x0 = np.clip(x0, lo, hi)
    r = problem.residuals(x0)
    if np.all(np.isfinite(r)):
        return x0, None
    why = problem.last_error or "the model gives non-finite values there"
    return x0, EngineResult(x0, "non-finite start", f"residuals not finite at the start: {why}",
                            problem.nfev, problem.njev)


def evaluation_budget(problem: ChannelProblem) -> int:
    """Default cap on model evaluations (SciPy, nlopt) for one local fit, scaled with the problem:
    100 per free parameter (SciPy's own rule for least_squares), plus one per 100 residual rows
    (more samples, more curvature to follow; a whole rate-aware session has ~1e5), at least 1000.
    A fit that reaches it is reported as "max-evaluations" (exit status 3), never as converged."""
    return max(1000, 100 * problem.packing.n_free + problem.n_residuals // 100)


def iteration_budget(problem: ChannelProblem) -> int:
    """Default cap on IPOPT iterations (each several evaluations): a tenth of the evaluation budget,
    at least 300 (IPOPT's limited-memory Hessian needs more iterations per parameter than SciPy's
    Gauss-Newton steps)."""
    return max(300, evaluation_budget(problem) // 10)


class Unit:
    """Map x to z in [0, 1]^n by its bounds: gradient engines (L-BFGS, IPOPT) see one scale."""

    def __init__(self, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> None:
        finite = np.isfinite(lo) & np.isfinite(hi)
        self.bound_lo, self.bound_hi = lo, hi
        self.lo = np.where(finite, lo, 0.0)
        self.width = np.where(finite, hi - lo, 1.0)
        self.z_lo = np.where(finite, 0.0, lo)
        self.z_hi = np.where(finite, 1.0, hi)

    def x(self, z: NDArray[np.float64]) -> NDArray[np.float64]:
        # Clipped: interior-point methods relax bounds by ~1e-8 and lo + width*1 can round past hi;
        # the core rightly refuses k_R = 1 + 1e-16.
        return np.asarray(np.clip(self.lo + self.width * np.asarray(z), self.bound_lo, self.bound_hi), dtype=np.float64)

    def z(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return (np.asarray(x) - self.lo) / self.width
