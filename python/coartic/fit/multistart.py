"""Global estimation: many local least-squares fits from quasi-random starts, the best kept.

The model has several local minima (the paper: "several local minima ... guided by hand"), and on
real recordings the answer of one local fit depended more on its start than on the model
(issue 19). ``fit_multistart`` therefore:

1. draws ``starts`` points from a scrambled Sobol sequence (``scipy.stats.qmc``, seeded) over the
   free parameters' boxes in the packing's internal coordinates, which are logarithmic for α, θ, ψ
   and β, so a θ box of [0.5, 2000] is sampled evenly in its orders of magnitude. Targets are not
   drawn: they start at the data's values (the first stage fits them given the drawn dynamics; a
   random target would only cost evaluations). Start 0 is the spec's ``[parameters.start]``
   (``include_start``, default on), always continued, so the result is never worse than the single
   fit: from 32 random starts alone the synthetic session's LLO ended at 0.157 mm with one seed, where
   the single fit reaches the noise floor, 0.135 (bench/multistart.py). Without it the result does
   not depend on ``[parameters.start]`` at all;
2. runs a short probe from every start (the staged fit with every stage capped at ``probe``
   evaluations), ranks the probes by SSE and continues only the best ``keep`` of them to
   convergence (one joint fit with the engine's full budget): starts that fall clearly behind
   stop early;
3. clusters the continued optima (same optimum: SSE within ``SSE_RTOL`` and parameters within
   ``X_TOL`` in the unit box), keeps the best, and counts how many starts reached it.

Starts run in a thread pool (the Rust core releases the GIL and runs rayon inside an evaluation);
the results do not depend on the number of workers: every start is computed alike and collected by
its index. ``bench/multistart.py`` measured workers and costs (docs/FITTING.md).
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.stats import qmc

from coartic.fit.engines import EngineResult
from coartic.estimation.packing import Packing
from coartic.estimation.problem import ChannelProblem
from coartic.fit.staged import StageResult, fit_staged
from coartic.table import N_PARAMS, PARAMETERS

FloatArray = NDArray[np.float64]

SSE_RTOL = 1e-5  # two optima whose SSE differ by less than this (relative) may be one
X_TOL = 0.02  # ... if their parameters also differ by less than this (RMS, each box scaled to [0, 1])
# The engine option that caps one local run, per engine (the probe's budget).
BUDGET_OPTION = {"scipy": "max_nfev", "nlopt": "local_maxeval", "casadi": "max_iter"}


@dataclass
class Optimum:
    """One distinct local optimum: its best point and the starts (indices) that ended in it."""

    sse: float
    x: FloatArray
    starts: list[int]
    status: str  # the engine's status at its best point
    heldout_rmse: dict[str, float] = field(default_factory=dict)  # split -> held-out RMSE (validation)

    @property
    def hits(self) -> int:
        return len(self.starts)


@dataclass
class MultiStart:
    """What a multi-start fit found (``ChannelFit.multistart``)."""

    n_starts: int
    seed: int
    probe: int
    continued: list[int]  # start indices continued after the probe
    probe_sse: list[float]  # per start, SSE after the probe
    final_sse: dict[int, float]  # per continued start, SSE at its end
    optima: list[Optimum]  # distinct, best first
    names: list[str]  # the free parameters, for the spread between optima
    spread: dict[str, float]  # parameter -> largest |difference| from the best among the optima (natural units)
    workers: int
    wall_time: float
    nfev: int
    include_start: bool = False  # start 0 was [parameters.start]

    @property
    def best(self) -> Optimum:
        return self.optima[0]

    @property
    def best_found_once(self) -> bool:
        """The best optimum was reached by one start only: another run may well find a better one."""
        return len(self.continued) > 1 and self.best.hits == 1

    def summary_line(self, n_valid: int) -> str:
        """One line for the console and the report: starts, distinct optima, how often the best."""
        rm = ", ".join(f"{math.sqrt(o.sse / max(n_valid, 1)):.4f}" for o in self.optima[:5])
        more = f" (+{len(self.optima) - 5} more)" if len(self.optima) > 5 else ""
        first = ", start 0 [parameters.start]" if self.include_start else ""
        return (f"{self.n_starts} starts (seed {self.seed}{first}), {len(self.continued)} continued after the probe: "
                f"{len(self.optima)} distinct optim{'um' if len(self.optima) == 1 else 'a'}, RMSE {rm}{more} mm; "
                f"best reached by {self.best.hits} of {len(self.continued)}")

    def as_dict(self, n_valid: int) -> dict[str, Any]:
        return {"starts": self.n_starts, "seed": self.seed, "probe_evaluations": self.probe,
                "continued": len(self.continued), "include_start": self.include_start, "workers": self.workers, "nfev": self.nfev,
                "wall_time_s": self.wall_time, "best_hits": self.best.hits,
                "best_found_once": self.best_found_once,
                "optima": [{"sse": o.sse, "rmse_mm": math.sqrt(o.sse / max(n_valid, 1)), "hits": o.hits,
                            "starts": o.starts, "status": o.status, "heldout_rmse_mm": o.heldout_rmse}
                           for o in self.optima],
                "parameter_spread": dict(sorted(self.spread.items(), key=lambda kv: -kv[1])[:10])}


def sobol_starts(packing: Packing, n: int, seed: int) -> FloatArray:
    """``n`` starts (rows of internal x) from a scrambled Sobol sequence over the free boxes;
    targets (and anything with an infinite box) stay at the packing's own values."""
    x0 = packing.pack()
    lo, hi = packing.bounds()
    cols = np.append(packing.free_columns % N_PARAMS, -1) if packing.beta_free else packing.free_columns % N_PARAMS
    cols = cols[: x0.size]
    drawn = (cols != PARAMETERS.index("target")) & np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
    out = np.tile(x0, (n, 1))
    if drawn.any():
        with warnings.catch_warnings():  # n not a power of two: balance is not needed here
            warnings.simplefilter("ignore", UserWarning)
            u = qmc.Sobol(int(drawn.sum()), scramble=True, seed=seed).random(n)
        out[:, drawn] = lo[drawn] + u * (hi[drawn] - lo[drawn])
    return out


def _capped(engine: str, options: dict[str, Any], budget: int) -> dict[str, Any]:
    o = dict(options)
    o[BUDGET_OPTION[engine]] = min(int(o.get(BUDGET_OPTION[engine], budget)), budget)
    if engine == "nlopt":
        o["global"] = "none"  # the starts are the global phase
    return o


def cluster(xs: Sequence[FloatArray], sses: Sequence[float], lo: FloatArray, hi: FloatArray,
            starts: Sequence[int], statuses: Sequence[str]) -> list[Optimum]:
    """Group end points into distinct optima, best first: same SSE (relative ``SSE_RTOL``) and
    parameters within ``X_TOL`` (RMS over the free parameters, each box scaled to [0, 1])."""
    width = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
    order = np.argsort(np.asarray(sses), kind="stable")
    optima: list[Optimum] = []
    for i in order:
        s, x = float(sses[i]), xs[i]
        if not np.isfinite(s):
            continue
        for o in optima:
            close_sse = abs(s - o.sse) <= SSE_RTOL * max(abs(o.sse), 1e-12)
            close_x = float(np.sqrt(np.mean(((x - o.x) / width) ** 2))) <= X_TOL if x.size else True
            if close_sse and close_x:
                o.starts.append(int(starts[i]))
                break
        else:
            optima.append(Optimum(s, np.array(x), [int(starts[i])], statuses[i]))
    return optima


def fit_multistart(problem: ChannelProblem, engine: str, options: dict[str, Any],
                   stages: Sequence[Sequence[str]] | None, n_starts: int, seed: int = 0, probe: int = 20,
                   keep: int | None = None, workers: int = 1, include_start: bool = True,
                   on_start: Callable[[int, int], None] | None = None,
                   ) -> tuple[ChannelProblem, EngineResult, list[StageResult], MultiStart]:
    """Multi-start fit of one channel (module docstring). Returns what ``fit_staged`` returns for the
    best start (its probe stages then its final fit as the last stage) and the ``MultiStart``.

    ``keep``: starts continued after the probe (default ``default_keep(n_starts)``);
    ``include_start``: start 0 is the packing's own start ([parameters.start]), always continued;
    ``on_start``
    is called (done, total) as starts finish. Ctrl-C stops every start at its next evaluation;
    the best point so far is returned with status "interrupted".
    """
    t0 = time.perf_counter()
    full = problem.packing
    lo, hi = full.bounds()
    xs0 = sobol_starts(full, n_starts, seed)
    if include_start:  # start 0 is [parameters.start], and always continued: never worse than one fit
        xs0[0] = full.pack()
    keep = default_keep(n_starts) if keep is None else max(1, min(keep, n_starts))
    stop = threading.Event()
    done = [0]
    total = n_starts + keep
    lock = threading.Lock()

    def guard(nfev: int, best: float) -> None:
        if stop.is_set():
            raise KeyboardInterrupt

    def tick() -> None:
        with lock:
            done[0] += 1
            if on_start is not None:
                on_start(done[0], total)

    def run_probe(i: int) -> tuple[ChannelProblem, EngineResult, list[StageResult]]:
        params, beta = full.unpack(xs0[i])
        p = problem.with_packing(full.with_free(full.free, full.beta_free, params, beta))
        p.nfev = p.njev = 0
        p.monitor = guard
        out = fit_staged(p, engine, _capped(engine, options, probe), stages)
        tick()
        return out

    def run_final(item: tuple[ChannelProblem, EngineResult, list[StageResult]]) -> tuple[ChannelProblem, EngineResult, float]:
        prob, res, _ = item
        prob.monitor = guard
        nfev0 = prob.nfev
        prob.nfev = prob.njev = 0
        final, r, st = fit_staged(prob, engine, options, None)
        final.nfev += nfev0
        tick()
        return final, r, st[-1].sse_end

    pool = ThreadPoolExecutor(max_workers=max(1, workers)) if workers > 1 else None
    interrupted = False
    probes: list[tuple[ChannelProblem, EngineResult, list[StageResult]]] = []
    finals: list[tuple[ChannelProblem, EngineResult, float]] = []
    try:
        mapper = pool.map if pool is not None else map
        probes = list(mapper(run_probe, range(n_starts)))
        probe_sse = [st[-1].sse_end if st else np.inf for _, _, st in probes]
        interrupted = any(r.status == "interrupted" for _, r, _ in probes)
        ranked = [int(i) for i in np.argsort(np.where(np.isfinite(probe_sse), probe_sse, np.inf), kind="stable")]
        continued = ([0] + [i for i in ranked if i != 0][:keep - 1]) if include_start else ranked[:keep]
        if not interrupted:
            finals = list(mapper(run_final, [probes[i] for i in continued]))
            interrupted = any(r.status == "interrupted" for _, r, _ in finals)
    except KeyboardInterrupt:
        stop.set()
        interrupted = True
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    if interrupted and not finals:  # stopped during the probes: the best probe so far
        ok = [(st[-1].sse_end, i) for i, (_, _, st) in enumerate(probes) if st]
        if not ok:
            raise KeyboardInterrupt
        i = min(ok)[1]
        prob, res, st = probes[i]
        ms = MultiStart(n_starts, seed, probe, [i], [s for s, _ in ok], {i: min(ok)[0]},
                        [Optimum(min(ok)[0], prob.packing.pack(), [i], "interrupted")], full.names(), {}, workers,
                        time.perf_counter() - t0, sum(p.nfev for p, _, _ in probes))
        return prob, EngineResult(res.x, "interrupted", "stopped by the user (Ctrl-C) during the probes", res.nfev,
                                  res.njev), [replace(s, probe=True) for s in st], ms
    xs = [f.packing.pack() for f, _, _ in finals]
    sses = [s for _, _, s in finals]
    optima = cluster(xs, sses, lo, hi, continued, [r.status for _, r, _ in finals])
    best_i = optima[0].starts[0]
    k = continued.index(best_i)
    final, res, _ = finals[k]
    stage_list = [replace(st, probe=True) for st in probes[best_i][2]] + [StageResult(("final",), final.packing.n_free, probe_sse[best_i],
                                                        sses[k], res)]
    names = full.names()
    spread: dict[str, float] = {}
    if len(optima) > 1:
        nat = np.array([full.natural(o.x) for o in optima])
        diff = np.abs(nat[1:] - nat[0]).max(axis=0)
        spread = {nm: float(d) for nm, d in zip(names, diff)}
    nfev = sum(p.nfev for p, _, _ in probes) + sum(f.nfev for f, _, _ in finals) - sum(
        probes[i][0].nfev for i in continued)
    ms = MultiStart(n_starts, seed, probe, continued, probe_sse, dict(zip(continued, sses)), optima, names, spread,
                    workers, time.perf_counter() - t0, nfev, include_start)
    final.nfev = nfev
    status = "interrupted" if interrupted else res.status
    return final, EngineResult(res.x, status, res.message, nfev, res.njev), stage_list, ms


def default_keep(n_starts: int) -> int:
    """Starts continued after the probe: an eighth, at least 4 (so that reaching the best more
    than once can be seen), at most all (bench/multistart.py: the cost is mostly the continued ones)."""
    return min(n_starts, max(4, math.ceil(n_starts / 8)))
