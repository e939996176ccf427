"""The vectorised log-posterior: equal to a direct computation, priors, support, sub-posteriors, table fields."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

import mcmc_data
from coartic import _core
from coartic.mcmc.posterior import LogPosterior, channel_posterior, phoneme_posterior
from coartic.mcmc.run import sample_posterior
from coartic.mcmc.sampler import SamplerSettings, SamplingResult
from coartic.mcmc import summary
from coartic.table import ChannelSettings, ParameterTable, PARAMETERS

OPTIONS = _core.ModelOptions("modified")


@pytest.fixture(scope="module")
def data() -> object:
    return mcmc_data.channel(mcmc_data.utterances(repetitions=2))


def direct_log_posterior(post: LogPosterior, x: NDArray[np.float64]) -> float:
    """One walker, the slow way: unpack, evaluate the trajectory, Gaussian log-likelihood."""
    params, beta = post.packing.unpack(x[: post.n_free])
    f = _core.evaluate(post.data.corpus, params, beta, OPTIONS)
    w = post.data.weights
    r = (post.data.observed - f)[w > 0]
    sigma = post.noise if post.noise is not None else math.exp(x[-1])
    return float(-0.5 * np.sum(r**2) / sigma**2 - r.size * math.log(sigma) - 0.5 * r.size * math.log(2 * math.pi))


@pytest.mark.parametrize("noise", [None, 0.15])
def test_batch_log_posterior_equals_direct_evaluation(data: object, noise: float | None) -> None:
    post = LogPosterior(data, mcmc_data.packing(), OPTIONS, noise=noise)  # type: ignore[arg-type]
    rng = np.random.default_rng(0)
    x = post.initial_ball(post.start_point(), 6, rng, scale=0.05)
    lp = post(x)
    expected = [direct_log_posterior(post, xi) for xi in x]
    np.testing.assert_allclose(lp, expected, rtol=1e-10)
    assert post.dim == post.n_free + (noise is None)


def test_outside_the_bounds_is_minus_inf_and_never_evaluated(data: object) -> None:
    seen: list[int] = []

    def counting(corpus, params, betas, options, observed, weights):  # type: ignore[no-untyped-def]
        seen.append(params.shape[0])
        return _core.sse_batch(corpus, params, betas, options, observed, weights)

    post = LogPosterior(data, mcmc_data.packing(), OPTIONS, sse_batch=counting)  # type: ignore[arg-type]
    x = np.repeat(post.start_point()[None], 5, axis=0)
    k_r = post.names.index("p.k_r")
    x[1, k_r] = 1.0001  # k_R above 1
    x[3, -1] = 50.0  # log sigma_n far above its range
    seen.clear()  # start_point evaluated the optimum once
    lp = post(x)
    assert np.isneginf(lp[[1, 3]]).all() and np.isfinite(lp[[0, 2, 4]]).all()
    assert seen == [3]


def test_gaussian_prior_adds_its_term_and_unknown_names_are_refused(data: object) -> None:
    flat = LogPosterior(data, mcmc_data.packing(), OPTIONS, noise=0.1)  # type: ignore[arg-type]
    prior = LogPosterior(data, mcmc_data.packing(), OPTIONS, noise=0.1, priors={"p.k_r": (0.9, 0.05)})  # type: ignore[arg-type]
    x = flat.start_point()[None]
    assert prior(x)[0] - flat(x)[0] == pytest.approx(-0.5 * ((1.0 - 0.9) / 0.05) ** 2)
    with pytest.raises(ValueError, match=r"Gaussian prior on 'q.k_r': not a free parameter"):
        LogPosterior(data, mcmc_data.packing(), OPTIONS, priors={"q.k_r": (0.9, 0.05)})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="positive sd"):
        LogPosterior(data, mcmc_data.packing(), OPTIONS, priors={"p.k_r": (0.9, 0.0)})  # type: ignore[arg-type]


def test_initial_ball_stays_inside_when_the_optimum_sits_on_a_bound(data: object) -> None:
    post = LogPosterior(data, mcmc_data.packing(), OPTIONS)  # type: ignore[arg-type]
    x0 = post.start_point()
    assert x0[post.names.index("p.k_r")] == 1.0  # on its upper bound
    ball = post.initial_ball(x0, 64, np.random.default_rng(1))
    assert post.in_support(ball).all() and np.isfinite(post(ball)).all()
    assert np.all(ball.std(axis=0) > 0)  # not degenerate


def test_phoneme_posterior_differs_from_the_full_one_by_a_constant(data: object) -> None:
    """Utterances without the phoneme do not depend on its parameters: leaving them out only shifts lp."""
    full = mcmc_data.packing()
    sub = phoneme_posterior(data, full, OPTIONS, "t", noise=0.1)  # type: ignore[arg-type]
    assert all("t" in u.labels for u in sub.data.utterances)
    assert len(sub.data.utterances) < len(data.utterances)  # type: ignore[attr-defined]
    assert sub.names == [f"t.{p}" for p in ("target", "alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "k_r", "delta")]
    whole = LogPosterior(data, full.with_free(sub.packing.free, False), OPTIONS, noise=0.1)  # type: ignore[arg-type]
    x = sub.initial_ball(sub.start_point(), 5, np.random.default_rng(2), scale=0.05)
    diff = whole(x) - sub(x)
    assert np.ptp(diff) < 1e-6 * np.abs(diff).max()
    with pytest.raises(ValueError, match="phoneme 'x' does not occur"):
        phoneme_posterior(data, full, OPTIONS, "x")  # type: ignore[arg-type]


def test_predict_matches_evaluate(data: object) -> None:
    post = LogPosterior(data, mcmc_data.packing(), OPTIONS)  # type: ignore[arg-type]
    x = post.initial_ball(post.start_point(), 3, np.random.default_rng(3), scale=0.05)
    pred = post.predict(x)
    for i in range(3):
        params, beta = post.packing.unpack(x[i, : post.n_free])
        np.testing.assert_allclose(pred[i], _core.evaluate(post.data.corpus, params, beta, OPTIONS), rtol=1e-13)


def test_quantiles_go_into_the_table_and_survive_a_round_trip(data: object, tmp_path: Path) -> None:
    post = phoneme_posterior(data, mcmc_data.packing(), OPTIONS, "t")  # type: ignore[arg-type]
    rng = np.random.default_rng(4)
    chain = post.initial_ball(post.start_point(), 40, rng, scale=0.01)[None].repeat(50, axis=0)
    chain = chain + 1e-3 * rng.standard_normal(chain.shape)
    res = SamplingResult(post.coordinates, [chain], [np.zeros(chain.shape[:2])], [0.3], None)
    sums = summary.summarize(post, res, post.start_point())
    table = ParameterTable(
        channels={"LLO": ChannelSettings(reference_phoneme="a")},
        values={p: {"LLO": dict(zip(PARAMETERS, map(float, row)))} for p, row in zip(mcmc_data.PHONEMES, mcmc_data.TRUTH)},
    )
    assert summary.write_uncertainty(table, "LLO", sums) == 8  # sigma_n has no slot in the table
    table.save(tmp_path / "t.json")
    back = ParameterTable.load(tmp_path / "t.json")
    q = back.uncertainty["t"]["LLO"]["theta_bw"]
    assert list(q) == list(summary.QUANTILE_LEVELS) and q["q2.5"] <= q["q50"] <= q["q97.5"]
    assert q["q50"] == pytest.approx(50.0, rel=0.05)  # natural units, not log


def test_channel_posterior_samples_every_free_parameter(data: object) -> None:
    packing = mcmc_data.packing(("target", "k_r"))
    joint = channel_posterior(data, packing, OPTIONS)  # type: ignore[arg-type]
    assert joint.dim == packing.n_free + 1 and len(joint.data.utterances) == len(data.utterances)  # type: ignore[attr-defined]
    x = joint.initial_ball(joint.start_point(), 4, np.random.default_rng(5), scale=0.05)
    np.testing.assert_allclose(joint(x), [direct_log_posterior(joint, xi) for xi in x], rtol=1e-10)


def test_an_interrupted_posterior_keeps_its_chains_but_gives_no_intervals(data: object, tmp_path: Path) -> None:
    calls = {"n": 0}

    def stopping(*args):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == 40:
            raise KeyboardInterrupt
        return _core.sse_batch(*args)

    post = phoneme_posterior(data, mcmc_data.packing(("target", "k_r")), OPTIONS, "t", sse_batch=stopping)  # type: ignore[arg-type]
    settings = SamplerSettings(n_walkers=8, n_ensembles=2, chunk_steps=50, min_steps=50, max_steps=100)
    run = sample_posterior(post, tmp_path / "t", settings, "LLO /t/", "t", progress=False)
    assert run.result.interrupted and not run.result.converged
    assert run.summaries == [] and run.images == []
    assert sum(len(c) for c in run.result.chains) > 0  # what was sampled is on disk
    assert list((tmp_path / "t" / "chains").glob("ens00_chunk*.npz"))


def direct_log_likelihood_with_offsets(post: LogPosterior, x: NDArray[np.float64], sigma: float, tau: float) -> float:
    """The dense way: each utterance's valid residuals ~ N(0, σ² I + τ² 1 1ᵀ)."""
    from scipy.stats import multivariate_normal

    params, beta = post.packing.unpack(x[: post.n_free])
    r = post.data.observed - _core.evaluate(post.data.corpus, params, beta, OPTIONS)
    total = 0.0
    for k in range(len(post.data.utterances)):
        sl = post.data.utterance_samples(k)
        ru = r[sl][post.data.weights[sl] > 0]
        cov = sigma**2 * np.eye(ru.size) + tau**2 * np.ones((ru.size, ru.size))
        total += float(multivariate_normal(np.zeros(ru.size), cov).logpdf(ru))
    return total


@pytest.fixture(scope="module")
def few() -> object:
    """Six utterances (/a/ around each consonant, both rates): the dense likelihood below costs an
    eigendecomposition per utterance and walker, 9 CPU-s on the 36 of ``data``. What it checks, the
    offsets integrated out utterance by utterance, does not depend on how many utterances there are."""
    return mcmc_data.channel(mcmc_data.utterances(vowels=("a",), repetitions=1))


@pytest.mark.parametrize(("noise", "offset_sd"), [(None, None), (0.12, None), (None, 0.05), (0.12, 0.05)])
def test_per_utterance_offsets_integrate_out_exactly(few: object, noise: float | None, offset_sd: float | None) -> None:
    post = LogPosterior(few, mcmc_data.packing(), OPTIONS, noise=noise, offset_sd=offset_sd)  # type: ignore[arg-type]
    assert post.dim == post.n_free + (noise is None) + (offset_sd is None)
    assert post.names[post.n_free:] == (["sigma_n"] if noise is None else []) + (["offset_sd"] if offset_sd is None else [])
    rng = np.random.default_rng(3)
    x = post.initial_ball(post.start_point(), 4, rng, scale=0.02)
    if offset_sd is None:
        x[:, -1] = [0.0, 0.01, 0.05, 0.4]  # τ = 0 is the iid likelihood
    sigma, tau = post.sigma_n(x), post.offsets(x)
    expected = [direct_log_likelihood_with_offsets(post, xi, s, t) for xi, s, t in zip(x, sigma, tau)]
    np.testing.assert_allclose(post(x), expected, rtol=1e-9)
    iid = LogPosterior(few, mcmc_data.packing(), OPTIONS, noise=0.12)  # type: ignore[arg-type]
    if offset_sd is None and noise == 0.12:
        assert post(x[:1])[0] == pytest.approx(iid(x[:1, : post.n_free])[0], rel=1e-12)


def test_offset_start_reads_the_spread_of_utterance_means(data: object) -> None:
    # add a known offset to every utterance: the start of τ sees it, the walkers start inside the prior
    shifted = mcmc_data.channel(mcmc_data.utterances(repetitions=2))
    rng = np.random.default_rng(0)
    for k in range(len(shifted.utterances)):
        shifted.observed[shifted.utterance_samples(k)] += rng.normal(0.0, 0.3)
    post = LogPosterior(shifted, mcmc_data.packing(), OPTIONS, offset_sd=None)
    tau0 = post.start_point()[-1]
    assert 0.15 < tau0 < 0.5
    with pytest.raises(ValueError, match="offset_sd must be >= 0"):
        LogPosterior(shifted, mcmc_data.packing(), OPTIONS, offset_sd=-1.0)


def test_covers_counts_a_truth_on_its_bound_when_the_interval_reaches_it() -> None:
    assert summary.covers(0.5, 0.4, 0.6, (0.0, 1.0)) and not summary.covers(0.5, 0.51, 0.6, (0.0, 1.0))
    assert summary.covers(1.0, 0.9, 0.995, (0.0, 1.0)) and not summary.covers(1.0, 0.9, 0.98, (0.0, 1.0))
    assert summary.covers(0.0, 0.004, 0.2, (0.0, 1.0)) and not summary.covers(0.0, 0.02, 0.2, (0.0, 1.0))
