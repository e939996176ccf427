"""Convergence diagnostics for emcee ensembles: checked, never assumed.

A run is declared converged only when every one of these holds (docs/MCMC.md explains why):

* the chain is longer than ``MIN_TAU_MULTIPLE`` (50) integrated autocorrelation times τ, τ taken as
  the largest over parameters (emcee's estimator with ``tol=0``, so that it always returns a number
  and the comparison with the chain length is ours), its autocorrelation function averaged over the
  walkers of all ensembles;
* τ is stable: every parameter's τ changes by less than ``MAX_TAU_CHANGE`` (1 %) between the chain
  without its last ``TAU_STEP`` (100) steps and the whole chain (the emcee documentation's criterion
  with a check every 100 steps);
* the mean acceptance fraction of every ensemble lies in ``ACCEPTANCE_RANGE`` (0.15–0.70);
* between independent ensembles, ArviZ's rank-normalised split R-hat is below ``MAX_RHAT`` (1.01)
  and the bulk and tail ESS are at least ``MIN_ESS`` (400) for every parameter.

R-hat is computed with one chain per ensemble (its walkers pooled step by step), because walkers of
one ensemble are not independent of each other; ensembles are. ESS treats every walker as a chain
(ArviZ's convention for emcee output).

While sampling, most checks find the chain shorter than 50 τ; such a run cannot pass whatever the
other checks say, so ``check(..., skip_when_short=True)`` (the sampler's checks between chunks)
then leaves out the τ stability, R-hat and ESS (two thirds of a check's cost: a second τ over the
chain less its last ``TAU_STEP`` steps, ArviZ per parameter) and marks the report ``partial``. The
decision is the same and the sampler's final report is always complete.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.extras import require
from coartic.mcmc.errors import McmcError

MIN_TAU_MULTIPLE = 50.0
MAX_TAU_CHANGE = 0.01
TAU_STEP = 100
ACCEPTANCE_RANGE = (0.15, 0.80)
MAX_RHAT = 1.01
MIN_ESS = 400.0


@dataclass
class ConvergenceReport:
    """What was measured, what was required, and whether the run passed."""

    n_steps: int
    n_ensembles: int
    n_walkers: int
    tau: list[float]  # per parameter, the largest over ensembles
    tau_max: float
    tau_change: float  # largest relative change of a parameter's tau over the last TAU_STEP steps
    acceptance: list[float]  # mean acceptance fraction per ensemble
    rhat: list[float]  # per parameter (nan with a single ensemble)
    ess_bulk: list[float]
    ess_tail: list[float]
    burn_in: int
    thin: int
    converged: bool
    problems: list[str] = field(default_factory=list)
    # True when the chain was too short to pass and tau_change, R-hat and ESS were not computed
    # (nan): check(..., skip_when_short=True)
    partial: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {k: _jsonable(v) for k, v in asdict(self).items()}

    def summary(self) -> str:
        head = "CONVERGED" if self.converged else "NOT CONVERGED"
        lines = [
            f"{head}: {self.n_steps} steps x {self.n_walkers} walkers x {self.n_ensembles} ensembles; "
            f"tau_max = {self.tau_max:.1f} (N/tau = {self.n_steps / max(self.tau_max, 1e-300):.1f}, "
            f"need > {MIN_TAU_MULTIPLE:g}); "
            f"max R-hat = {np.nanmax(self.rhat) if self.rhat and not np.all(np.isnan(self.rhat)) else float('nan'):.4f}; "
            f"min ESS bulk = {min(self.ess_bulk) if self.ess_bulk else float('nan'):.0f}; "
            f"acceptance = {', '.join(f'{a:.2f}' for a in self.acceptance)}"
        ]
        lines += [f"  - {p}" for p in self.problems]
        return "\n".join(lines)


def _jsonable(v: Any) -> Any:
    if isinstance(v, float) and not np.isfinite(v):
        return None if np.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, list):
        return [_jsonable(x) for x in v]
    return v


def load_arviz() -> Any:
    """ArviZ, imported quietly (it warns about its coming refactor on import)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        require("mcmc", "MCMC convergence diagnostics")
        import arviz as az
    return az


def autocorr_time(chain: NDArray[np.float64]) -> NDArray[np.float64]:
    """Integrated autocorrelation time per parameter of one ensemble, chain shaped (steps, walkers, dim).

    emcee's estimator (``emcee.autocorr.integrated_time`` with ``tol=0``: it never raises, the
    caller compares the length with τ): each walker's normalised autocorrelation function, averaged
    over the walkers, summed up to Sokal's window (c = 5). Computed here with a real FFT of all
    walkers at once, zero-padded to a fast length >= 2 n - 1 rather than emcee's complex FFT per
    walker padded to twice the next power of two: the same linear autocorrelation (no wrap-around
    either way), equal to emcee's to rounding (1e-15 relative), at a quarter of its CPU time (a
    7000-step chain of 108 walkers in 26 dimensions, as test_mcmc_calibration's: 1.2 against 5
    CPU-s, and the sampler computes it twice per complete check).
    """
    from scipy import fft

    n_t, _, n_d = chain.shape
    if n_t < 2:
        return np.full(n_d, np.inf)
    n = fft.next_fast_len(2 * n_t - 1, real=True)
    tau = np.empty(n_d)
    for d in range(n_d):
        x = np.array(chain[:, :, d].T, dtype=np.float64)  # (walkers, steps): each series contiguous
        x -= x.mean(axis=1, keepdims=True)
        f = fft.rfft(x, n=n, axis=1)
        acf = fft.irfft(f.real ** 2 + f.imag ** 2, n=n, axis=1)[:, :n_t]
        with np.errstate(invalid="ignore", divide="ignore"):  # a constant walker: nan, as emcee gives
            acf /= acf[:, :1]
        taus = 2.0 * np.cumsum(acf.mean(axis=0)) - 1.0
        tau[d] = taus[_auto_window(taus, 5.0)]
    return tau


def _auto_window(taus: NDArray[np.float64], c: float) -> int:
    """Sokal's window: the first lag m with m >= c τ(m) (emcee.autocorr.auto_window)."""
    m = np.arange(len(taus)) < c * taus
    return int(np.argmin(m)) if np.any(m) else len(taus) - 1


def ensemble_chains(chains: Sequence[NDArray[np.float64]], burn_in: int, thin: int) -> NDArray[np.float64]:
    """(ensembles, draws, dim): each ensemble's walkers pooled step by step after burn-in and thinning."""
    n = min(c.shape[0] for c in chains)
    out = []
    for c in chains:
        kept = c[burn_in:n:thin]  # (draws, walkers, dim)
        out.append(kept.reshape(-1, c.shape[2]))
    return np.stack(out)


def walker_chains(chains: Sequence[NDArray[np.float64]], burn_in: int, thin: int) -> NDArray[np.float64]:
    """(ensembles x walkers, draws, dim): every walker a chain, after burn-in and thinning (for ESS)."""
    n = min(c.shape[0] for c in chains)
    return np.concatenate([np.swapaxes(c[burn_in:n:thin], 0, 1) for c in chains])


def rhat_ess(
    chains: Sequence[NDArray[np.float64]], burn_in: int, thin: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """ArviZ R-hat (one chain per ensemble), bulk ESS and tail ESS (one chain per walker) per parameter."""
    az = load_arviz()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pooled = ensemble_chains(chains, burn_in, thin)
        walkers = walker_chains(chains, burn_in, thin)
        dim = pooled.shape[2]
        rhat = np.full(dim, np.nan)
        bulk = np.empty(dim)
        tail = np.empty(dim)
        for j in range(dim):
            if pooled.shape[0] > 1:
                rhat[j] = float(az.rhat(pooled[:, :, j]))
            bulk[j] = float(az.ess(walkers[:, :, j], method="bulk"))
            tail[j] = float(az.ess(walkers[:, :, j], method="tail"))
    return rhat, bulk, tail


def check(
    chains: Sequence[NDArray[np.float64]],
    acceptance: Sequence[float],
    names: Sequence[str] | None = None,
    skip_when_short: bool = False,
) -> ConvergenceReport:
    """Diagnose a set of independent ensembles, each chain shaped (steps, walkers, dim).

    ``skip_when_short``: when the chain is no longer than ``MIN_TAU_MULTIPLE`` τ (the run fails
    whatever else is found), leave out the τ stability, R-hat and ESS and return a ``partial``
    report (module docstring).
    """
    if not chains:
        raise McmcError("convergence check: no ensembles given")
    n_steps = min(c.shape[0] for c in chains)
    dim = chains[0].shape[2]
    names = list(names) if names is not None else [f"x{j}" for j in range(dim)]
    every_walker = np.concatenate([c[:n_steps] for c in chains], axis=1)
    tau = autocorr_time(every_walker)
    tau_max = float(np.max(tau)) if tau.size else 0.0
    finite_tau = np.isfinite(tau_max) and tau_max > 0
    short = not finite_tau or n_steps <= MIN_TAU_MULTIPLE * tau_max
    partial = skip_when_short and short
    if partial:
        change = float("nan")
    elif n_steps > 2 * TAU_STEP:
        before = autocorr_time(every_walker[: n_steps - TAU_STEP])
        with np.errstate(invalid="ignore", divide="ignore"):
            change = float(np.max(np.abs(tau - before) / tau))
        change = change if np.isfinite(change) else float("inf")
    else:
        change = float("inf")

    problems: list[str] = []
    if not finite_tau:
        problems.append("the autocorrelation time could not be estimated")
    elif n_steps <= MIN_TAU_MULTIPLE * tau_max:
        worst = names[int(np.argmax(tau))]
        problems.append(
            f"chain too short: {n_steps} steps <= {MIN_TAU_MULTIPLE:g} x tau = "
            f"{MIN_TAU_MULTIPLE * tau_max:.0f} (slowest parameter: {worst}, tau = {tau_max:.1f})"
        )
    if not partial and not change < MAX_TAU_CHANGE:
        problems.append(
            "autocorrelation time not yet stable"
            + ("" if not np.isfinite(change) else f": changed by {100 * change:.1f} % over the last {TAU_STEP} steps (need < {100 * MAX_TAU_CHANGE:g} %)")
        )
    lo, hi = ACCEPTANCE_RANGE
    for e, a in enumerate(acceptance):
        if not lo <= a <= hi:
            problems.append(f"ensemble {e}: acceptance fraction {a:.3f} outside [{lo}, {hi}]")

    # Discard a few τ of burn-in and thin by about τ/2: the draws left are what the summary uses.
    burn_in = int(min(np.ceil(3 * tau_max), n_steps // 2)) if finite_tau else n_steps // 2
    thin = max(1, int(tau_max // 2)) if finite_tau else 1
    if partial:
        rhat, bulk, tail = np.full(dim, np.nan), np.full(dim, np.nan), np.full(dim, np.nan)
        problems.append("tau stability, R-hat and ESS not computed: the chain is too short to pass whatever they say")
    elif len(range(burn_in, n_steps, thin)) >= 4:
        rhat, bulk, tail = rhat_ess([c[:n_steps] for c in chains], burn_in, thin)
    else:
        rhat, bulk, tail = np.full(dim, np.nan), np.zeros(dim), np.zeros(dim)
        problems.append("too few draws after burn-in for R-hat and ESS")
    if len(chains) < 2:
        problems.append("a single ensemble: R-hat between independent ensembles cannot be computed")
    elif not partial:
        for j in np.flatnonzero(~(rhat < MAX_RHAT)):
            problems.append(f"R-hat of {names[j]} = {rhat[j]:.4f} (need < {MAX_RHAT})")
    if not partial:
        for j in np.flatnonzero(~(np.minimum(bulk, tail) >= MIN_ESS)):
            problems.append(f"ESS of {names[j]}: bulk {bulk[j]:.0f}, tail {tail[j]:.0f} (need >= {MIN_ESS:g})")

    return ConvergenceReport(
        n_steps=int(n_steps),
        n_ensembles=len(chains),
        n_walkers=int(chains[0].shape[1]),
        tau=[float(t) for t in tau],
        tau_max=tau_max,
        tau_change=change,
        acceptance=[float(a) for a in acceptance],
        rhat=[float(r) for r in rhat],
        ess_bulk=[float(b) for b in bulk],
        ess_tail=[float(t) for t in tail],
        burn_in=burn_in,
        thin=thin,
        converged=not problems,
        problems=problems,
        partial=partial,
    )
