"""Do emcee's moves sample the target? Standard deviations recovered on correlated Gaussians.

Not a speed benchmark: it measures accuracy, the reason `coartic mcmc` samples with emcee's
differential-evolution move ("de") and no longer mixes in emcee's DESnookerMove. For each move set
and dimension, emcee runs on a zero-mean Gaussian with a dense random covariance (the size and
correlation of a per-phoneme posterior, d = 9, and of a joint-channel one, d = 28) from a tiny
ball, as `coartic mcmc` starts; after discarding the first quarter of the chain it prints the
ratio of each coordinate's sample standard deviation to the true one (1 is right), the
integrated autocorrelation time τ and the acceptance fraction. With τ ≈ 100 steps and 60 walkers,
8000 steps give about 3600 effective samples, so a correct move's mean ratio is within ~0.01 of 1.

Run: .venv/bin/python bench/mcmc_moves.py   (output saved in bench/results/mcmc_moves.txt)
"""

from __future__ import annotations

import emcee
import numpy as np

STEPS = 8000
SEED = 0


def move_sets() -> dict[str, object]:
    from coartic.mcmc.sampler import make_moves

    return {
        "de (coartic's default)": make_moves("de"),
        "stretch (emcee's default)": make_moves("stretch"),
        "DE 80 % + DESnooker 20 % (coartic's default until 2026-11)": [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)],
        "DESnooker alone": [(emcee.moves.DESnookerMove(), 1.0)],
    }


def main() -> None:
    print(f"emcee {emcee.__version__}; {STEPS} steps, first quarter discarded")
    print(f"{'moves':58s} {'dim':>3s} {'walkers':>7s} {'sd ratio mean':>13s} {'min':>6s} {'max':>6s} {'tau':>5s} {'accept':>6s}")
    for dim in (9, 28):
        rng = np.random.default_rng(SEED)
        a = rng.standard_normal((dim, dim))
        cov = a @ a.T + 0.1 * dim * np.eye(dim)
        icov = np.linalg.inv(cov)
        sd = np.sqrt(np.diag(cov))
        walkers = max(32, 2 * dim + 4)

        def log_prob(x: np.ndarray) -> np.ndarray:
            return -0.5 * np.einsum("ij,jk,ik->i", x, icov, x)

        for name, moves in move_sets().items():
            start = 1e-3 * sd * rng.standard_normal((walkers, dim))
            sampler = emcee.EnsembleSampler(walkers, dim, log_prob, vectorize=True, moves=moves)
            sampler.random_state = np.random.RandomState(SEED).get_state()
            sampler.run_mcmc(start, STEPS, progress=False)
            chain = sampler.get_chain()[STEPS // 4 :]
            ratio = chain.reshape(-1, dim).std(axis=0) / sd
            tau = float(emcee.autocorr.integrated_time(chain, tol=0).max())
            print(f"{name:58s} {dim:3d} {walkers:7d} {ratio.mean():13.3f} {ratio.min():6.3f} {ratio.max():6.3f} "
                  f"{tau:5.0f} {sampler.acceptance_fraction.mean():6.2f}")


if __name__ == "__main__":
    main()
