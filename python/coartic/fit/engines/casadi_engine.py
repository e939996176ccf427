"""CasADi + IPOPT, with the Rust core's SSE and exact gradient wrapped in ``casadi.Callback``s.

IPOPT is an interior-point method: it handles the bounds natively and is robust far from the
optimum. The Hessian is approximated by L-BFGS (the Callback gives value and gradient only). x
is scaled to the unit box by its bounds.

Options: ``max_iter`` (default ``coartic.fit.engines.iteration_budget``, >= 300), ``tol`` (1e-6), ``print_level`` (0), and any other IPOPT
option by name (passed through as ``ipopt.<name>``).
"""

from __future__ import annotations

from typing import Any, Sequence

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from coartic.fit.engines.base import EngineResult, OptionError, Unit, iteration_budget, prepare_start
from coartic.estimation.problem import ChannelProblem


IPOPT_DEFAULTS: dict[str, Any] = {"tol": 1e-6, "acceptable_tol": 1e-4, "print_level": 0,
                                  "hessian_approximation": "limited-memory", "sb": "yes"}


def check_options(options: dict[str, Any]) -> None:
    """Each option as IPOPT sees it: a one-variable problem is built with it, so an unknown name,
    a wrong type or a value IPOPT refuses is named before any fit, not raised from inside one."""
    x = ca.SX.sym("x", 1)
    for key, value in options.items():
        if not isinstance(value, (bool, int, float, str)):
            raise OptionError(key, f"{value!r}: expected a number or a string (an IPOPT option)")
        ipopt: dict[str, Any] = {"print_level": 0, "sb": "yes", key: value}
        opts: dict[str, Any] = {"ipopt": ipopt, "print_time": False}
        try:
            ca.nlpsol("coartic_check", "ipopt", {"x": x, "f": x * x}, opts)
        except RuntimeError as e:
            lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
            why = lines[-1].split(": ", 1)[-1] if lines else str(e)
            if why.startswith("type mismatch") or "failed" in why:
                why = "wrong type for this IPOPT option"
            raise OptionError(key, f"{value!r}: IPOPT refuses it ({why})") from None


class _Objective(ca.Callback):
    """f(z) = SSE(x(z)), with a Jacobian (the gradient) callback below."""

    def __init__(self, name: str, problem: ChannelProblem, unit: Unit, state: dict[str, Any]) -> None:
        ca.Callback.__init__(self)
        self.problem, self.unit, self.state = problem, unit, state
        self.n = unit.lo.size
        self._grad: _Gradient | None = None
        self.construct(name, {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.n, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(1, 1)

    def eval(self, arg: Sequence[Any]) -> list[Any]:
        try:
            sse = self.problem.sse(self.unit.x(np.asarray(arg[0]).ravel()))
        except KeyboardInterrupt:
            self.state["interrupted"] = True
            raise
        return [sse if np.isfinite(sse) else np.nan]

    def has_jacobian(self) -> bool:
        return True

    def get_jacobian(self, name: str, inames: Sequence[str], onames: Sequence[str],  # type: ignore[override]
                     opts: dict[str, Any]) -> ca.Function:
        self._grad = _Gradient(name, self.problem, self.unit, self.state, opts)
        return self._grad


class _Gradient(ca.Callback):
    def __init__(self, name: str, problem: ChannelProblem, unit: Unit, state: dict[str, Any],
                 opts: dict[str, Any]) -> None:
        ca.Callback.__init__(self)
        self.problem, self.unit, self.state = problem, unit, state
        self.n = unit.lo.size
        self.construct(name, opts)

    def get_n_in(self) -> int:
        return 2  # z and the nominal output

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.n, 1) if i == 0 else ca.Sparsity.dense(1, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(1, self.n)

    def eval(self, arg: Sequence[Any]) -> list[Any]:
        try:
            _, g = self.problem.sse_gradient(self.unit.x(np.asarray(arg[0]).ravel()))
        except KeyboardInterrupt:
            self.state["interrupted"] = True
            raise
        return [ca.DM(g * self.unit.width).T]


def minimize(problem: ChannelProblem, x0: NDArray[np.float64], options: dict[str, Any]) -> EngineResult:
    x0, bad = prepare_start(problem, x0)
    if bad is not None:
        return bad
    lo, hi = problem.packing.bounds()
    unit = Unit(lo, hi)
    state: dict[str, Any] = {"interrupted": False}
    f = _Objective("coartic_sse", problem, unit, state)
    z = ca.MX.sym("z", unit.lo.size)
    ipopt = dict(IPOPT_DEFAULTS, max_iter=iteration_budget(problem))
    ipopt.update(options)
    nlp: dict[str, Any] = {"x": z, "f": f(z)}
    solver_opts: dict[str, Any] = {"ipopt": ipopt, "print_time": False, "error_on_fail": False}
    try:
        solver = ca.nlpsol("coartic_fit", "ipopt", nlp, solver_opts)
    except RuntimeError as e:
        return EngineResult(problem.best_x, "failed", f"IPOPT could not be set up: {str(e).splitlines()[-1]}",
                            problem.nfev, problem.njev)
    try:
        sol = solver(x0=unit.z(x0), lbx=unit.z_lo, ubx=unit.z_hi)
        stats = solver.stats()
    except KeyboardInterrupt:
        state["interrupted"] = True
    except RuntimeError as e:
        if not state["interrupted"]:
            return EngineResult(problem.best_x, "failed", f"IPOPT failed: {e}", problem.nfev, problem.njev)
    if state["interrupted"]:
        return EngineResult(problem.best_x, "interrupted", "stopped by the user (Ctrl-C); best point kept",
                            problem.nfev, problem.njev)
    x = unit.x(np.asarray(sol["x"]).ravel())
    x = x if problem.sse(x) <= problem.best_sse else problem.best_x
    rs = str(stats.get("return_status", "?"))
    status = "converged" if stats.get("success") or rs in ("Solve_Succeeded", "Solved_To_Acceptable_Level") else (
        "max-evaluations" if rs == "Maximum_Iterations_Exceeded" else "failed")
    return EngineResult(x, status, f"IPOPT: {rs}", problem.nfev, problem.njev)
