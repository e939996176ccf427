"""CPU cost of the sampler's convergence checks over a run, complete at every check (as before) or
skipping what cannot change a too-short chain's verdict (convergence.check(skip_when_short=True),
what the sampler's checks between chunks do now), for checks every 500, 1000 or 2000 steps.

The chains mimic a joint-channel run of test_mcmc_calibration.py's synthetic session (2 ensembles of
62 walkers, tau about 135, converged at 8000 steps): AR(1) walkers with tau = 135 (coefficient
134/136), with fewer parameters (--dim, default 4, against 30 there) to keep the benchmark short; a
check's cost is linear in the number of parameters (one autocorrelation function and one ArviZ call
per parameter), so the ratios hold. Also checked: each schedule reaches the same verdicts and the
same last report. CPU seconds (time.process_time) of one run.

Run: .venv/bin/python bench/mcmc_checks.py [--dim 4] [--out bench/results/mcmc_checks.txt]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from coartic.mcmc import convergence

ROOT = Path(__file__).resolve().parents[1]
STEPS, WALKERS, ENSEMBLES, TAU = 8000, 62, 2, 135.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dim", type=int, default=4)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "mcmc_checks.txt"))
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    phi = (TAU - 1) / (TAU + 1)
    chains = [lfilter([1.0], [1.0, -phi], rng.standard_normal((STEPS, WALKERS, args.dim)), axis=0) for _ in range(ENSEMBLES)]
    acc = [0.3] * ENSEMBLES
    names = [f"x{j}" for j in range(args.dim)]
    lines = [f"# bench/mcmc_checks.py --dim {args.dim}: {ENSEMBLES} ensembles x {WALKERS} walkers, AR(1) tau {TAU:g}, "
             f"checks until {STEPS} steps; CPU s of all checks of a run"]
    convergence.load_arviz()
    for chunk in (500, 1000, 2000):
        cost = {}
        last = {}
        for skip in (False, True):
            t0 = time.process_time()
            verdicts = []
            for n in range(chunk, STEPS + 1, chunk):
                r = convergence.check([c[:n] for c in chains], acc, names, skip_when_short=skip)
                verdicts.append(r.converged)
            if r.partial:  # the sampler completes a partial last report
                r = convergence.check([c[:STEPS] for c in chains], acc, names)
            cost[skip] = time.process_time() - t0
            last[skip] = (verdicts, r.to_dict())
        same = last[False] == last[True]
        lines.append(f"checks every {chunk:5d} steps: complete {cost[False]:6.2f} s, skip_when_short {cost[True]:6.2f} s "
                     f"(ratio {cost[True] / cost[False]:.2f}); same verdicts and last report: {same}; "
                     f"verdicts {''.join('C' if v else '.' for v in last[True][0])}")
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    tmp = Path(args.out + ".partial")
    tmp.write_text(text)
    tmp.replace(args.out)


if __name__ == "__main__":
    main()
