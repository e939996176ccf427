"""Fit speed: SciPy least_squares on the plain NumPy model with finite differences, against the same
fit fed by the Rust core (values + exact sparse Jacobian), on the same data, in one run.

    .venv/bin/python bench/fit_speed.py            # prints, and writes bench/results/fit_speed.txt

Both fits use trf with x_scale='jac', the same bounds, start and tolerances; the data are VCV
utterances made by the model (coartic.fit.simulate) with 0.1 mm noise.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))
import numpy_model  # noqa: E402  (the NumPy reference of MODEL.md, written by B)

from coartic.estimation.problem import build_problem  # noqa: E402
from coartic.fit.simulate import PHONEMES, vcv_utterances  # noqa: E402
from coartic.fit.spec import parse_spec  # noqa: E402


def main() -> str:
    utts = vcv_utterances(np.random.default_rng(7), vowels=("a", "i"), consonants=("p", "t", "l"),
                          repetitions=5, noise=0.1)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target", "alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "k_r", "delta"]}}
    problem = build_problem(parse_spec(raw, ROOT / "bench" / "fit_speed.toml").estimation_settings(), utts, "LLO", phonemes=PHONEMES)
    data, pk = problem.data, problem.packing
    row = {p: i for i, p in enumerate(data.phonemes)}
    x0 = pk.pack()
    lo, hi = pk.bounds()
    kw = dict(method="trf", x_scale="jac", ftol=1e-8, xtol=1e-8, gtol=1e-8, max_nfev=200, bounds=(lo, hi))

    def numpy_residuals(x: np.ndarray) -> np.ndarray:
        params, beta = pk.unpack(x)
        f = np.concatenate([numpy_model.evaluate_utterance(params, [row[lab] for lab in u.labels], u.starts,
                                                           u.ends, u.times, beta) for u in data.utterances])
        return problem.sqrt_w * (f - data.observed)

    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        ref = least_squares(numpy_residuals, x0, jac="2-point", **kw)
        t_numpy = time.perf_counter() - t0
        t0 = time.perf_counter()
        fast = least_squares(problem.residuals, x0, jac=lambda x: problem.jacobian(x).toarray(), **kw)
        t_rust = time.perf_counter() - t0
    n = data.n_valid
    lines = [
        f"fit speed (bench/fit_speed.py), {len(data.utterances)} utterances, {n} samples, {pk.n_free} free "
        f"parameters, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs",
        f"  NumPy model + finite differences : {t_numpy:8.2f} s  ({ref.nfev} evaluations + FD Jacobians, "
        f"RMSE {np.sqrt(2 * ref.cost / n):.4f} mm)",
        f"  Rust core + exact Jacobian       : {t_rust:8.2f} s  ({fast.nfev} evaluations, {fast.njev} Jacobians, "
        f"RMSE {np.sqrt(2 * fast.cost / n):.4f} mm)",
        f"  speed-up (wall time ratio)       : {t_numpy / t_rust:8.1f}x   (aim: 20x or more)",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    text = main()
    print(text)
    out = ROOT / "bench" / "results" / "fit_speed.txt"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text + "\n")
