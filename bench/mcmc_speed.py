"""Effective samples per second: emcee on the Rust batch log-posterior vs on a plain NumPy one.

Both samplers target the same per-consonant posterior with the likelihood `coartic mcmc` uses by
default (one consonant's 8 parameters plus log σ_n and the sd of the per-utterance offsets, in the
3 vowel contexts × 2 rates × 5 repetitions of a model-generated session, 100 Hz): the Rust one
hands all walkers to ``_core.residual_sums_batch`` in one call (``vectorize=True``); the NumPy one
is the plain reference model of tests/python/numpy_model.py called walker by walker, as emcee
does by default. Both use the sampler's default moves (differential evolution). Same seed, same
moves: the chains agree (checked below), so the autocorrelation time τ is the same and is
measured once, on the longer Rust chain. ESS/s = steps × walkers / τ / seconds.

Run: .venv/bin/python bench/mcmc_speed.py   (output saved in bench/results/mcmc_speed.txt)
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import emcee
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))

import mcmc_data  # noqa: E402
import numpy_model  # noqa: E402

from coartic import _core  # noqa: E402
from coartic.mcmc.convergence import autocorr_time  # noqa: E402
from coartic.mcmc.posterior import LogPosterior, phoneme_posterior  # noqa: E402
from coartic.mcmc.run import walkers_for  # noqa: E402
from coartic.mcmc.sampler import SamplerSettings, make_moves  # noqa: E402

RUST_STEPS = 1500
NUMPY_STEPS = 75
BLOCKS = 15
SEED = 42


def numpy_residual_sums_batch(utterances, rows):  # type: ignore[no-untyped-def]
    """A drop-in for ``_core.residual_sums_batch`` built on the NumPy reference, one walker at a time."""
    seg_offsets = np.cumsum([0] + [len(u.labels) for u in utterances])
    seg_phoneme = np.array([rows[lab] for u in utterances for lab in u.labels])
    seg_start = np.concatenate([u.starts for u in utterances])
    seg_end = np.concatenate([u.ends for u in utterances])
    sample_offsets = np.cumsum([0] + [len(u.times) for u in utterances])
    sample_times = np.concatenate([u.times for u in utterances])

    def residual_sums_batch(corpus, params, betas, options, observed, weights):  # type: ignore[no-untyped-def]
        sse, sums = np.empty(len(params)), np.empty((len(params), len(utterances)))
        for w in range(len(params)):
            f = numpy_model.evaluate_corpus(params[w], seg_offsets, seg_phoneme, seg_start, seg_end, sample_offsets,
                                            sample_times, float(betas[w]), options.variant, options.apex_fraction,
                                            options.edge_extent)
            r = weights * (observed - f)
            sse[w] = float(np.sum(r * (observed - f)))
            sums[w] = np.add.reduceat(r, sample_offsets[:-1]) if len(r) else 0.0
        return sse, sums

    return residual_sums_batch


def sampler(post: LogPosterior, walkers: int, vectorize: bool) -> tuple[emcee.EnsembleSampler, np.ndarray]:
    p0 = post.initial_ball(post.start_point(), walkers, np.random.default_rng(SEED))
    fn = post if vectorize else (lambda x: float(post(x[None])[0]))
    s = emcee.EnsembleSampler(walkers, post.dim, fn, vectorize=vectorize, moves=make_moves(SamplerSettings().moves))
    s.random_state = np.random.RandomState(SEED).get_state()
    return s, p0


def timed(s: emcee.EnsembleSampler, start: np.ndarray | None, steps: int) -> float:
    t = time.perf_counter()
    s.run_mcmc(start, steps, progress=False)
    return time.perf_counter() - t


def main() -> None:
    options = _core.ModelOptions("modified")
    utts = mcmc_data.utterances(consonants=("t",), repetitions=5)
    data = mcmc_data.channel(utts)
    packing = mcmc_data.packing()
    # the likelihood `coartic mcmc` uses by default: σ_n and the per-utterance offsets' sd sampled
    rust = phoneme_posterior(data, packing, options, "t", offset_sd=None)
    rows = {p: i for i, p in enumerate(data.phonemes)}
    slow = LogPosterior(rust.data, rust.packing, options, rust.noise, offset_sd=None,
                        residual_sums_batch=numpy_residual_sums_batch(rust.data.utterances, rows))
    walkers = walkers_for(rust.dim, 0)
    n_samples = rust.data.corpus.n_samples
    print(f"posterior: /t/ on LLO, {rust.dim} dimensions, {len(rust.data.utterances)} utterances, {n_samples} samples, "
          f"{walkers} walkers")
    # The machine is shared: alternate blocks of the two so that both see the same load.
    s_r, p_r = sampler(rust, walkers, vectorize=True)
    s_n, p_n = sampler(slow, walkers, vectorize=False)
    t_r = t_n = 0.0
    for block in range(BLOCKS):
        t_r += timed(s_r, p_r if block == 0 else None, RUST_STEPS // BLOCKS)
        t_n += timed(s_n, p_n if block == 0 else None, NUMPY_STEPS // BLOCKS)
    chain_r, chain_n = s_r.get_chain(), s_n.get_chain()
    agree = float(np.max(np.abs(chain_r[:NUMPY_STEPS] - chain_n)))
    tau = float(np.max(autocorr_time(chain_r)))
    ess_r = RUST_STEPS * walkers / tau / t_r
    ess_n = NUMPY_STEPS * walkers / tau / t_n
    print(f"same moves: max |chain_rust - chain_numpy| over the first {NUMPY_STEPS} steps = {agree:.2e}")
    print(f"autocorrelation time (Rust chain, {RUST_STEPS} steps, N/tau = {RUST_STEPS / tau:.0f}, a rough estimate; "
          f"the ratio below does not depend on it): tau = {tau:.1f} steps")
    print(f"Rust batch  : {RUST_STEPS} steps in {t_r:7.2f} s = {1e3 * t_r / RUST_STEPS:8.3f} ms/step, ESS/s = {ess_r:9.1f}")
    print(f"NumPy plain : {NUMPY_STEPS} steps in {t_n:7.2f} s = {1e3 * t_n / NUMPY_STEPS:8.3f} ms/step, ESS/s = {ess_n:9.1f}")
    print(f"ratio (Rust / NumPy effective samples per second): {ess_r / ess_n:.1f}x  (aim >= 10x)")
    print(f"machine: {os.cpu_count()} CPUs shared with other jobs; load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
