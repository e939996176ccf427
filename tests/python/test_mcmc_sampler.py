"""The chunked, resumable emcee runner and the convergence checks, on targets whose answer is known."""

from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from coartic.mcmc import convergence, sampler
from coartic.mcmc.sampler import SamplerSettings

COV = np.diag([1.0, 4.0, 0.25])
ICOV = np.linalg.inv(COV)
NAMES = ["a", "b", "c"]


def gaussian(x: NDArray[np.float64]) -> NDArray[np.float64]:
    return -0.5 * np.einsum("ij,jk,ik->i", x, ICOV, x)


def ball(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    return 1e-3 * rng.standard_normal((n, 3))


def settings(**kw: int | str) -> SamplerSettings:
    base = dict(n_walkers=16, n_ensembles=2, chunk_steps=200, min_steps=200, max_steps=600, seed=7)
    base.update(kw)
    return SamplerSettings(**base)  # type: ignore[arg-type]


def test_gaussian_converges_to_known_moments(tmp_path: Path) -> None:
    s = settings(n_ensembles=3, chunk_steps=300, min_steps=600, max_steps=9000)
    r = sampler.run(gaussian, ball, NAMES, tmp_path / "c", s, progress=False)
    assert r.report is not None
    assert r.converged, r.report.summary()
    assert r.report.n_steps > convergence.MIN_TAU_MULTIPLE * r.report.tau_max
    d = r.draws()
    sd = np.sqrt(np.diag(COV))
    n_eff = min(r.report.ess_bulk)
    # means within 5 standard errors, standard deviations within 10 %
    assert np.all(np.abs(d.mean(axis=0)) < 5 * sd / np.sqrt(n_eff))
    assert np.allclose(d.std(axis=0), sd, rtol=0.1)


@pytest.mark.slow
def test_default_moves_keep_the_spread_of_a_correlated_gaussian_in_28_dimensions(tmp_path: Path) -> None:
    # The size and correlation of a joint-channel posterior (test_mcmc_calibration.py). The former
    # default, DEMove mixed with emcee's DESnookerMove, gives 0.967 of the true standard deviation
    # here (swapped in for the default moves), and its intervals under-covered the synthetic
    # session's truth (bench/mcmc_moves.py measures the moves on their own).
    rng = np.random.default_rng(0)
    dim = 28
    a = rng.standard_normal((dim, dim))
    cov = a @ a.T + 0.1 * dim * np.eye(dim)
    icov = np.linalg.inv(cov)
    sd = np.sqrt(np.diag(cov))
    names = [f"x{i}" for i in range(dim)]
    # first checked at 5000 steps: with tau ~ 88 no check before 50 tau = 4400 steps can pass (the
    # ones at 2000-4000 steps said "chain too short" and cost 3 of this test's 20 CPU-s); the run
    # converges at that first check, on the same chains as before
    s = SamplerSettings(n_walkers=60, n_ensembles=2, chunk_steps=1000, min_steps=5000, max_steps=12000, seed=3)
    r = sampler.run(lambda x: -0.5 * np.einsum("ij,jk,ik->i", x, icov, x),
                    lambda g, n: 1e-3 * sd * g.standard_normal((n, dim)), names, tmp_path / "c", s, progress=False)
    assert r.converged, r.report.summary() if r.report else "no report"
    ratio = r.draws().std(axis=0) / sd
    assert abs(ratio.mean() - 1.0) < 0.02 and 0.93 < ratio.min() and ratio.max() < 1.07, ratio


@pytest.mark.parametrize("moves", ["de", "de+laplace"])
def test_resume_equals_uninterrupted_run(tmp_path: Path, moves: str) -> None:
    full = sampler.run(gaussian, ball, NAMES, tmp_path / "full", settings(max_steps=600, moves=moves), progress=False,
                       stop_when_converged=False)
    first = sampler.run(gaussian, ball, NAMES, tmp_path / "part", settings(max_steps=400, moves=moves), progress=False,
                        stop_when_converged=False)
    assert len(first.chains[0]) == 400
    # (the Laplace proposal is read back from the chains' directory, not built again)
    resumed = sampler.run(gaussian, ball, NAMES, tmp_path / "part", settings(max_steps=600, moves=moves), progress=False,
                          stop_when_converged=False)
    for a, b in zip(full.chains, resumed.chains):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(full.log_probs, resumed.log_probs):
        np.testing.assert_array_equal(a, b)
    assert resumed.acceptance == pytest.approx(full.acceptance)


def test_laplace_moves_sample_a_target_cut_off_at_its_bounds(tmp_path: Path) -> None:
    # The shapes the Laplace proposal meets on a channel posterior (coartic.mcmc.laplace): a
    # coordinate piled against a bound (k_R near 1: a normal cut at 1), one decaying from a bound
    # (an offset sd near 0: an exponential on [0, 5]) and an unbounded one. The proposal lives in
    # logit coordinates, so a wrong Jacobian term in its density would bias the first two marginals.
    from scipy import stats

    from coartic.mcmc.laplace import LaplaceProposal

    lower, upper = np.array([0.0, -np.inf, 0.0]), np.array([1.0, np.inf, 5.0])
    truth = [stats.truncnorm((0 - 0.95) / 0.1, (1 - 0.95) / 0.1, loc=0.95, scale=0.1), stats.norm(0, 2),
             stats.truncexpon(5 * 5.0, scale=1 / 5.0)]

    def target(x: NDArray[np.float64]) -> NDArray[np.float64]:
        inside = np.all((x >= lower) & (x <= upper), axis=1)
        lp = -0.5 * ((x[:, 0] - 0.95) / 0.1) ** 2 - 0.5 * (x[:, 1] / 2) ** 2 - 5 * x[:, 2]
        return np.where(inside, lp, -np.inf)

    def start(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
        return np.array([0.9, 0.0, 0.2]) + 1e-3 * rng.standard_normal((n, 3))

    s = settings(n_walkers=16, chunk_steps=500, min_steps=500, max_steps=6000, moves="de+laplace")
    r = sampler.run(target, start, NAMES, tmp_path / "c", s, progress=False, bounds=(lower, upper))
    assert r.converged, r.report.summary() if r.report else "no report"
    assert LaplaceProposal.load(tmp_path / "c", 3) is not None  # built and saved, so the independence move ran
    d = r.draws()
    n_eff = min(r.report.ess_bulk)
    for j, dist in enumerate(truth):
        assert abs(d[:, j].mean() - dist.mean()) < 5 * dist.std() / np.sqrt(n_eff), (j, d[:, j].mean(), dist.mean())
        assert d[:, j].std() == pytest.approx(dist.std(), rel=0.05), j


def _interrupting(after_calls: int, how: Callable[[], None]) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    calls = {"n": 0}

    def lp(x: NDArray[np.float64]) -> NDArray[np.float64]:
        calls["n"] += 1
        if calls["n"] == after_calls:
            how()
        return gaussian(x)

    return lp


def _keyboard() -> None:
    raise KeyboardInterrupt


def _sigterm() -> None:
    os.kill(os.getpid(), signal.SIGTERM)


@pytest.mark.parametrize("how", [_keyboard, _sigterm], ids=["ctrl-c", "sigterm"])
def test_interrupted_run_loses_nothing_and_resumes(tmp_path: Path, how: Callable[[], None], capsys: pytest.CaptureFixture[str]) -> None:
    if how is _sigterm and threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers can only be installed from the main thread")
    full = sampler.run(gaussian, ball, NAMES, tmp_path / "full", settings(), progress=False, stop_when_converged=False)
    # ensemble 0's first chunk (200 steps) takes a few hundred log_prob calls: cut well after it
    cut = sampler.run(_interrupting(2 * 250 + 1, how), ball, NAMES, tmp_path / "cut", settings(), progress=False, stop_when_converged=False)
    assert cut.interrupted and not cut.converged
    steps = [len(c) for c in cut.chains]
    assert steps[0] == 200 and 0 < steps[1] < 200, steps  # chunk 0 of ensemble 0 done; ensemble 1 cut
    assert len(list((tmp_path / "cut").glob("ens01_chunk*.npz"))) == 1  # the partial chunk was saved
    assert "Exception while calling your likelihood" not in capsys.readouterr().out  # no parameter dump
    resumed = sampler.run(gaussian, ball, NAMES, tmp_path / "cut", settings(), progress=False, stop_when_converged=False)
    assert not resumed.interrupted
    for a, b in zip(full.chains, resumed.chains):
        np.testing.assert_array_equal(a, b)


def test_other_runs_chains_are_refused(tmp_path: Path) -> None:
    sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=200), fingerprint="one", progress=False)
    with pytest.raises(ValueError, match=r"different run \(fingerprint"):
        sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=200), fingerprint="two", progress=False)
    with pytest.raises(ValueError, match="n_walkers"):
        sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=200, n_walkers=18), fingerprint="one", progress=False)
    assert json.loads((tmp_path / "c" / "meta.json").read_text())["fingerprint"] == "one"


def test_damaged_chunk_is_named(tmp_path: Path) -> None:
    sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=200), progress=False)
    victim = tmp_path / "c" / "ens01_chunk00000.npz"
    victim.write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="ens01_chunk00000.npz: damaged chain chunk"):
        sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=400), progress=False)


def test_a_gap_in_the_chunks_is_refused_not_spliced(tmp_path: Path) -> None:
    s = settings(chunk_steps=50, min_steps=50, max_steps=150)
    sampler.run(gaussian, ball, NAMES, tmp_path / "c", s, progress=False, stop_when_converged=False)
    chunks = sorted(p.name for p in (tmp_path / "c").glob("ens00_chunk*.npz"))
    assert chunks == ["ens00_chunk00000.npz", "ens00_chunk00001.npz", "ens00_chunk00002.npz"]
    (tmp_path / "c" / "ens00_chunk00001.npz").unlink()
    more = settings(chunk_steps=50, min_steps=50, max_steps=300)
    with pytest.raises(ValueError, match=r"ens00_chunk00001.npz: missing, but later chunks exist \(ens00_chunk00002.npz\)"
                                         r".*resume from chunk 0"):
        sampler.run(gaussian, ball, NAMES, tmp_path / "c", more, progress=False, stop_when_converged=False)
    # nothing was written over the surviving chunk
    assert sorted(p.name for p in (tmp_path / "c").glob("ens00_chunk*.npz")) == ["ens00_chunk00000.npz", "ens00_chunk00002.npz"]
    (tmp_path / "c" / "ens00_chunk00002.npz").unlink()  # as the message says: resumes from chunk 0
    r = sampler.run(gaussian, ball, NAMES, tmp_path / "c", more, progress=False, stop_when_converged=False)
    assert len(r.chains[0]) == len(r.chains[1]) == 300
    assert len(list((tmp_path / "c").glob("ens00_chunk*.npz"))) == 6


@pytest.mark.parametrize("damage", ["empty", "truncated"])
def test_empty_or_truncated_chunk_is_named(tmp_path: Path, damage: str) -> None:
    sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(chunk_steps=100, min_steps=100, max_steps=200),
                progress=False, stop_when_converged=False)
    victim = tmp_path / "c" / "ens00_chunk00000.npz"
    data = victim.read_bytes()
    victim.write_bytes(b"" if damage == "empty" else data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"ens00_chunk00000.npz: damaged chain chunk .*delete it and the 1 chunk\(s\) "
                                         r"after it \(ens00_chunk00001.npz\)"):
        sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=400), progress=False)


def test_a_chunk_with_nan_positions_is_named_not_resumed(tmp_path: Path) -> None:
    # issue 21: such a chunk used to end in emcee's message about condition numbers
    from coartic.errors import CoarticError
    from coartic.mcmc.errors import ChainError

    sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(chunk_steps=100, min_steps=100, max_steps=200),
                progress=False, stop_when_converged=False)
    victim = tmp_path / "c" / "ens00_chunk00001.npz"
    with np.load(victim) as z:
        parts = {k: z[k] for k in z.files}
    parts["chain"][3, 5, 1] = np.nan
    np.savez(victim, **parts)
    with pytest.raises(ChainError, match=r"ens00_chunk00001.npz: damaged chain chunk \(non-finite walker positions, "
                                         r"the first at step 3, walker 5\); delete it to resume") as e:
        sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=400), progress=False)
    assert isinstance(e.value, CoarticError)


def test_chains_too_large_for_memory_are_refused_naming_the_keys() -> None:
    with pytest.raises(ValueError, match=r"max_steps = 1000000000 x walkers = 16 x ensembles = 2 .* lower \[mcmc\] max_steps"):
        settings(max_steps=10**9).validate(3)
    with pytest.raises(ValueError, match=r"walkers = 1000000000 .* lower \[mcmc\] max_steps, walkers"):
        settings(n_walkers=10**9).validate(3)
    with pytest.raises(ValueError, match=r"chunk_steps = 600000 x walkers = 16 .*needs 1.6 GiB per chunk, more than the 1.0 GiB"):
        SamplerSettings(n_walkers=16, chunk_steps=600_000, max_steps=600_000, n_ensembles=1).check_memory(10, limit=1 << 30)


def test_too_few_walkers_is_explained() -> None:
    with pytest.raises(ValueError, match="too few for 3 dimensions"):
        settings(n_walkers=6).validate(3)


def test_short_run_is_reported_not_converged(tmp_path: Path) -> None:
    r = sampler.run(gaussian, ball, NAMES, tmp_path / "c", settings(max_steps=200), progress=False)
    assert r.report is not None and not r.converged
    assert any("chain too short" in p for p in r.report.problems), r.report.problems
    assert "NOT CONVERGED" in r.report.summary()


def test_rhat_catches_ensembles_in_different_modes(tmp_path: Path) -> None:
    # Two far-apart modes: each ensemble starts in one and never crosses. Long enough that the
    # chain-length and stability criteria pass, so only R-hat can tell.
    def bimodal(x: NDArray[np.float64]) -> NDArray[np.float64]:
        a = -0.5 * np.sum((x - 20.0) ** 2, axis=1)
        b = -0.5 * np.sum((x + 20.0) ** 2, axis=1)
        return np.logaddexp(a, b)

    def start(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
        side = 20.0 if rng.random() < 0.5 else -20.0
        return side + 1e-3 * rng.standard_normal((n, 2))

    s = settings(max_steps=600, seed=3)
    # pick a seed where the two ensembles start on different sides
    for seed in range(50):
        sides = {np.sign(start(np.random.default_rng([seed, e]), 2)[0, 0]) for e in range(2)}
        if len(sides) == 2:
            s.seed = seed
            break
    r = sampler.run(bimodal, start, ["x", "y"], tmp_path / "c", s, progress=False, stop_when_converged=False)
    assert r.report is not None and not r.converged
    assert max(r.report.rhat) > 1.5
    assert any(p.startswith("R-hat of x") for p in r.report.problems), r.report.problems


def test_check_rejects_bad_acceptance() -> None:
    rng = np.random.default_rng(0)
    chain = rng.standard_normal((400, 8, 2))
    r = convergence.check([chain, rng.standard_normal((400, 8, 2))], [0.02, 0.3], ["u", "v"])
    assert any("ensemble 0: acceptance fraction 0.020" in p for p in r.problems)
    assert not any("ensemble 1" in p for p in r.problems)
    json.dumps(r.to_dict())  # serialisable for the run's summary file


def test_checks_between_chunks_skip_only_what_cannot_change_the_decision(tmp_path: Path) -> None:
    # A chain no longer than 50 tau fails whatever else is found: skip_when_short leaves out the tau
    # stability, R-hat and ESS (partial report), with the same verdict; a long enough chain gets the
    # complete check either way.
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.standard_normal((300, 8, 2)), axis=0)  # tau of the order of the chain
    chains = [walk, np.cumsum(rng.standard_normal((300, 8, 2)), axis=0)]
    full = convergence.check(chains, [0.3, 0.3], ["u", "v"])
    quick = convergence.check(chains, [0.3, 0.3], ["u", "v"], skip_when_short=True)
    assert not full.converged and not quick.converged and quick.partial and not full.partial
    assert quick.tau == full.tau and quick.problems[0] == full.problems[0]
    assert quick.problems[0].startswith("chain too short")
    assert np.isnan(quick.tau_change) and all(np.isnan(quick.rhat)) and all(np.isnan(quick.ess_bulk))
    white = [rng.standard_normal((2000, 8, 2)) for _ in range(2)]
    a = convergence.check(white, [0.3, 0.3], ["u", "v"])
    b = convergence.check(white, [0.3, 0.3], ["u", "v"], skip_when_short=True)
    assert a == b and not b.partial
    # A run stopped at max_steps while too short still returns a complete report (the sampler
    # completes a partial last check), and its chains are those of a run checked completely.
    s = settings(chunk_steps=100, min_steps=100, max_steps=300)
    r = sampler.run(gaussian, ball, NAMES, tmp_path / "c", s, progress=False)
    assert r.report is not None and not r.report.partial and not r.converged
    assert r.report.problems[0].startswith("chain too short"), r.report.problems
    assert np.all(np.isfinite(r.report.ess_bulk)) and np.isfinite(r.report.tau_change)
    assert [h["steps"] for h in r.history] == [100.0, 200.0, 300.0]  # one entry per check
    again = convergence.check(r.chains, r.report.acceptance, NAMES)
    assert again == r.report
