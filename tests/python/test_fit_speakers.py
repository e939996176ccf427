"""Several speakers in one fit ([model] speakers): speaker-specific target offset and scale,
profiled out with an exact Jacobian, shared dynamics."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from coartic.estimation.problem import build_problem
from coartic.fit.simulate import PHONEMES, TRUTH, vcv_utterances
from coartic.errors import SpecError
from coartic.fit.spec import parse_spec
from coartic.table import PARAMETERS

from fit_helpers import paper

TARGET = PARAMETERS.index("target")


def spec(speakers: str):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]},
           "model": {"channels": ["LLO"], "speakers": speakers}, "parameters": {"free": ["target", "theta_bw"]}}
    return parse_spec(paper(raw), Path("/tmp/test_spec.toml"))


@pytest.fixture(scope="module")
def utts():  # type: ignore[no-untyped-def]
    """Speaker 1 from the model; speaker 2 = 1.2 × speaker 1 + 0.5 mm (same segments)."""
    one = vcv_utterances(np.random.default_rng(3), repetitions=1, rates={"normal": 1.0})
    out = []
    for u in one:
        u.meta = {**u.meta, "speaker": "s1"}
        v = copy.deepcopy(u)
        v.name, v.meta = u.name + "-s2", {**u.meta, "speaker": "s2"}
        v.observed = {ch: 1.2 * y + 0.5 for ch, y in u.observed.items()}
        out += [u, v]
    return out


def start() -> np.ndarray:
    p = TRUTH.copy()
    p[:, TARGET] += 1.5  # shared targets off, to be recovered
    return p


@pytest.mark.parametrize("mode", ["offset", "offset_scale"])
def test_speaker_jacobian_matches_finite_differences(utts, mode: str) -> None:  # type: ignore[no-untyped-def]
    p = build_problem(spec(mode).estimation_settings(), utts, "LLO", start=(start(), 1.0), phonemes=PHONEMES)
    x = p.packing.pack()
    jac = p.jacobian(x).toarray()
    for j in range(p.packing.n_free):
        h = 1e-6
        e = np.zeros_like(x)
        e[j] = h
        fd = (p.residuals(x + e) - p.residuals(x - e)) / (2 * h)
        np.testing.assert_allclose(jac[:, j], fd, atol=1e-6 * max(1.0, np.abs(fd).max()),
                                   err_msg=f"{mode} {p.packing.names()[j]}")
    sse, g = p.sse_gradient(x)
    r = p.residuals(x)
    assert sse == pytest.approx(float(r @ r), rel=1e-12)
    np.testing.assert_allclose(g, 2 * jac.T @ r, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(p.sse_batch(np.stack([x, x])), [sse, sse], rtol=1e-12)


def fit(utts, mode: str):  # type: ignore[no-untyped-def]
    p = build_problem(spec(mode).estimation_settings(), utts, "LLO", start=(start(), 1.0), phonemes=PHONEMES)
    res = least_squares(p.residuals, p.packing.pack(), jac=p.jacobian, bounds=p.packing.bounds(), x_scale="jac")
    rmse = float(np.sqrt(np.sum(res.fun[: p.data.corpus.n_samples] ** 2) / p.data.n_valid))
    return p, res.x, rmse


def test_pooled_offset_scale_recovers_speaker_and_beats_none(utts) -> None:  # type: ignore[no-untyped-def]
    p, x, rmse = fit(utts, "offset_scale")
    coef = p.speaker_coefficients(x)
    assert list(coef) == ["s1", "s2"] and coef["s1"] == (0.0, 1.0)  # reference speaker fixed
    a, b = coef["s2"]
    assert b == pytest.approx(1.2, abs=0.02) and a == pytest.approx(0.5, abs=0.1)
    params, _ = p.packing.unpack(x)  # shared targets are the reference speaker's
    np.testing.assert_allclose(params[1:, TARGET], TRUTH[1:, TARGET], atol=0.2)
    _, _, rmse_none = fit(utts, "none")
    assert rmse < 0.6 * rmse_none
    # docs/FITTING.md: the table for speaker s is its targets mapped a + b·target (F is a
    # dominance-weighted mean of targets), so a + b·F is the model evaluated with those targets
    f = p.evaluate(params, 1.0)
    mapped = params.copy()
    mapped[:, TARGET] = a + b * mapped[:, TARGET]
    np.testing.assert_allclose(p.evaluate(mapped, 1.0), a + b * f, atol=1e-10)


def test_speakers_need_the_column_and_a_known_mode(utts) -> None:  # type: ignore[no-untyped-def]
    bare = [copy.copy(u) for u in utts[:2]]
    bare[1].meta = {}
    with pytest.raises(ValueError, match="has no 'speaker'"):
        build_problem(spec("offset").estimation_settings(), bare, "LLO", start=(TRUTH, 1.0), phonemes=PHONEMES)
    with pytest.raises(SpecError, match="model.speakers"):
        spec("scale")


# ---------------------------------------------------------------- a fitted table's speakers: MCMC, score
@pytest.fixture(scope="module")
def fitted(utts):  # type: ignore[no-untyped-def]
    """coartic.fit.run with [model] speakers = "offset_scale" on the two speakers, and its table."""
    from coartic.fit.runner import run

    res = run(spec("offset_scale"), utterances=utts, quiet=True)
    return res, res.table()


def test_mcmc_log_posterior_uses_the_fits_speaker_mapping(utts, fitted) -> None:  # type: ignore[no-untyped-def]
    """The posterior's SSE at the least-squares a_s, b_s is the fit's cost (one mapping, Speakers.predict),
    the speakers' offset and log scale are sampled coordinates, and a spec/table mismatch is refused."""
    import math

    from coartic.mcmc.posterior import channel_posterior, phoneme_posterior
    from coartic.mcmc.run import fixed_noise, table_problem, table_speakers

    res, table = fitted
    s = spec("offset_scale")
    problem = table_problem(s, table, "LLO", utts)
    data, packing, options = problem.data, problem.packing, problem.options
    terms = table_speakers(s, table, "LLO")
    assert terms is not None and terms.names == ("s1", "s2")
    fit = res.channels["LLO"]
    lsq_sse = fit.problem.sse(fit.x)
    # s2's a and b are profiled out of x but fitted: they cost two degrees of freedom (stats, AIC/BIC)
    assert fit.problem.n_profiled == 2 and fit.stats.dof == fit.problem.data.n_valid - fit.packing.n_free - 2
    # the stale-fit check (and noise = "fit") see the mapped RMSE the fit recorded
    assert fixed_noise(data, packing, options, speakers=terms) == pytest.approx(table.metadata["rmse"]["LLO"], rel=1e-9)
    sigma = 0.1
    post = channel_posterior(data, packing, options, noise=sigma, offset_sd=0.0, speakers=terms)
    assert post.names[-2:] == ["speaker_offset:s2", "speaker_scale:s2"]
    assert post.coordinates[-1] == "log speaker_scale:s2"
    x0 = post.start_point()
    a, b = table.metadata["speakers"]["coefficients"]["LLO"]["s2"].values()
    np.testing.assert_allclose(x0[-2:], [a, math.log(b)])
    assert float(post.sse(x0[None])[0]) == pytest.approx(lsq_sse, rel=1e-10)
    n = post.n_data
    expected = (float(post.log_prior(x0[None])[0]) - 0.5 * lsq_sse / sigma**2 - n * math.log(sigma)
                - 0.5 * n * math.log(2 * math.pi))
    assert float(post(x0[None])[0]) == pytest.approx(expected, rel=1e-12)
    # the priors: a_s ~ N(0, 10 mm), log b_s ~ N(0, 0.5)
    from coartic.mcmc.posterior import SPEAKER_LOG_SCALE_SD, SPEAKER_OFFSET_SD

    lp0 = float(post.log_prior(x0[None])[0])
    assert lp0 == pytest.approx(-0.5 * (a / SPEAKER_OFFSET_SD) ** 2 - 0.5 * (math.log(b) / SPEAKER_LOG_SCALE_SD) ** 2)
    # moving b_s off the optimum raises the SSE: the sampled coordinate is used
    moved = x0.copy()
    moved[-1] += 0.05
    assert float(post.sse(moved[None])[0]) > lsq_sse * 1.01
    # a per-phoneme posterior samples the speakers as nuisance coordinates, reference fixed
    pp = phoneme_posterior(data, packing, options, "a", noise=sigma, offset_sd=0.0, speakers=terms)
    assert pp.names[-2:] == ["speaker_offset:s2", "speaker_scale:s2"] and "speaker_offset:s1" not in pp.names
    # a spec without speakers cannot sample a table fitted with them (nor the other way round)
    with pytest.raises(ValueError, match="fitted with \\[model\\] speakers = 'offset_scale'"):
        table_speakers(spec("none"), table, "LLO")
    with pytest.raises(ValueError, match="the table was fitted with 'offset_scale'"):
        table_speakers(spec("offset"), table, "LLO")


def test_score_maps_by_the_tables_speaker_and_calibrates(utts, fitted, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from typer.testing import CliRunner

    from coartic.cli import app
    from coartic.evaluation.score import score_utterances
    from coartic.speakers import SpeakerError

    res, table = fitted
    fit = res.channels["LLO"]
    s2 = [u for u in utts if u.meta["speaker"] == "s2"]
    mapped = score_utterances(table, s2, speaker="s2")
    # s2's prediction is the fit's own (a_s + b_s·F): its in-sample RMSE on those utterances
    sse, cnt = fit.utterance_sse()
    mine = [i for i, u in enumerate(fit.problem.data.utterances) if u.meta["speaker"] == "s2"]
    assert mapped.rmse("LLO") == pytest.approx(float(np.sqrt(sse[mine].sum() / cnt[mine].sum())), rel=1e-9)
    population = score_utterances(table, s2)  # as a speaker the table does not know: a = 0, b = 1
    assert population.rmse("LLO") > 1.3 * mapped.rmse("LLO")
    assert any("without --speaker it predicts the population" in n for n in population.notes)
    row = population.channel_rows()[0]
    # calibrated on s2's own data, the population table recovers s2's mapping (a = 0.5, b = 1.2)
    assert row["calibration_scale"] == pytest.approx(1.2, abs=1e-6)
    assert row["calibration_offset_mm"] == pytest.approx(0.5, abs=1e-6)
    assert row["rmse_calibrated_mm"] == pytest.approx(mapped.rmse("LLO"), rel=1e-9)
    with pytest.raises(SpeakerError, match="no speaker 's9'; the table knows s1, s2"):
        score_utterances(table, s2, speaker="s9")
    bare = copy.deepcopy(table)
    bare.metadata.pop("speakers")
    with pytest.raises(SpeakerError, match="fitted without speakers"):
        score_utterances(bare, s2, speaker="s1")
    # the command: --speaker, and an unknown one is an error (exit 2) naming the known speakers
    path = tmp_path / "table.json"
    table.save(path)
    # (the speaker is checked before any recording is read: this one does not exist)
    bad = CliRunner().invoke(app, ["score", str(path), str(tmp_path / "absent.c3d"), "--speaker", "s9"])
    assert bad.exit_code == 2 and "s1, s2" in bad.output and "Traceback" not in bad.output



# ---------------------------------------------------------------- [model] speakers = "targets"
@pytest.fixture(scope="module")
def two_speakers():  # type: ignore[no-untyped-def]
    """Two speakers from the model with the same dynamics and different targets, not an affine map
    of each other (/t/ up, /l/ down)."""
    s2 = TRUTH.copy()
    s2[:, TARGET] = [0.5, 14.0, 5.0, -3.0, 4.5, 3.0]
    one = vcv_utterances(np.random.default_rng(3), repetitions=1, rates={"normal": 1.0, "fast": 0.7})
    two = vcv_utterances(np.random.default_rng(4), params=s2, repetitions=1, rates={"normal": 1.0, "fast": 0.7})
    for u in one:
        u.meta["speaker"] = "s1"
    for u in two:
        u.meta["speaker"], u.name = "s2", u.name + "-s2"
    return one + two, s2


def targets_spec(mode: str = "targets", **sections):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"], "speakers": mode},
           "parameters": {"free": ["target", "theta_bw", "k_r"]}, **sections}
    return parse_spec(paper(raw), Path("/tmp/test_spec.toml"))


def test_speaker_targets_gradient_and_recovery(two_speakers) -> None:  # type: ignore[no-untyped-def]
    utts, s2 = two_speakers
    p = build_problem(targets_spec().estimation_settings(), utts, "LLO", start=(TRUTH, 1.0), phonemes=PHONEMES)
    names = p.packing.names()
    # one target per speaker and phoneme, the dynamics once (the first speaker's rows lead)
    assert "a|s2.target" in names and "a|s1.theta_bw" in names and "a|s2.theta_bw" not in names
    lo, hi = p.packing.bounds()
    x = np.clip(p.packing.pack() + 0.05 * np.random.default_rng(0).standard_normal(p.packing.n_free), lo + 1e-3, hi - 1e-3)
    jac = p.jacobian(x).toarray()
    for j in range(p.packing.n_free):
        e = np.zeros_like(x)
        e[j] = 1e-6
        fd = (p.residuals(x + e) - p.residuals(x - e)) / 2e-6
        np.testing.assert_allclose(jac[:, j], fd, atol=1e-6 * max(1.0, np.abs(fd).max()), err_msg=names[j])
    sse, g = p.sse_gradient(x)
    np.testing.assert_allclose(g, 2 * jac.T @ p.residuals(x), rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(p.sse_batch(np.stack([x, x])), [sse, sse], rtol=1e-12)
    res = least_squares(p.residuals, x, jac=p.jacobian, bounds=(lo, hi), x_scale="jac")
    params, _ = p.packing.unpack(res.x)
    own = p.speaker_metadata(res.x)["targets"]
    for s, truth in (("s1", TRUTH), ("s2", s2)):
        np.testing.assert_allclose([own[s][ph] for ph in PHONEMES], truth[:, TARGET], atol=0.1, err_msg=s)
    rmse = float(np.sqrt(np.sum(res.fun**2) / p.data.n_valid))
    assert rmse < 0.11  # the noise (0.1 mm)
    # the table: shared dynamics, targets the mean over the speakers
    table = p.table_matrix(params)
    np.testing.assert_allclose(table[:, TARGET], [(own["s1"][ph] + own["s2"][ph]) / 2 for ph in PHONEMES])
    np.testing.assert_allclose(table[:, 1:], params[: len(PHONEMES), 1:])
    q = build_problem(targets_spec("offset_scale").estimation_settings(), utts, "LLO", start=(TRUTH, 1.0), phonemes=PHONEMES)
    rq = least_squares(q.residuals, q.packing.pack(), jac=q.jacobian, bounds=q.packing.bounds(), x_scale="jac")
    assert float(np.sqrt(np.sum(rq.fun**2) / q.data.n_valid)) > 2 * rmse  # an affine map cannot do it


def test_speaker_targets_table_score_and_mcmc(two_speakers, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from coartic.jobs.fit import fit_job
    from coartic.evaluation.score import score_utterances
    from coartic.mcmc.posterior import phoneme_posterior
    from coartic.mcmc.run import ChannelSampling, fixed_noise, problem_priors, table_problem, table_speakers

    utts, _ = two_speakers
    s = targets_spec()
    res = fit_job(s, tmp_path / "fit", utterances=utts, quiet=True)  # what coartic fit writes, the report too
    assert (tmp_path / "fit" / "report.html").is_file()
    fit, table = res.channels["LLO"], res.table()
    meta = table.metadata["speakers"]
    assert meta["mode"] == "targets" and set(meta["targets"]["LLO"]) == {"s1", "s2"}
    own = meta["targets"]["LLO"]
    assert sorted(table.phonemes) == sorted(PHONEMES)  # the table has the phonemes, not the rows
    for ph in PHONEMES:
        assert table.values[ph]["LLO"]["target"] == pytest.approx((own["s1"][ph] + own["s2"][ph]) / 2)
    # score --speaker s2 evaluates with s2's own targets: the fit's in-sample RMSE on s2's utterances
    two = [u for u in utts if u.meta["speaker"] == "s2"]
    sse, cnt = fit.utterance_sse()
    mine = [i for i, u in enumerate(fit.problem.data.utterances) if u.meta["speaker"] == "s2"]
    assert score_utterances(table, two, speaker="s2").rmse("LLO") == pytest.approx(
        float(np.sqrt(sse[mine].sum() / cnt[mine].sum())), rel=1e-9)
    # MCMC samples the same per-speaker problem, starting at the table's own targets
    problem = table_problem(s, table, "LLO", utts)
    data, packing, options = problem.data, problem.packing, problem.options
    assert table_speakers(s, table, "LLO") is None
    assert fixed_noise(data, packing, options) == pytest.approx(table.metadata["rmse"]["LLO"], rel=1e-9)
    post = phoneme_posterior(data, packing, options, "a|s1", noise=0.1, offset_sd=0.0)
    # its shared dynamics move s2's /a/ too, so s2's utterances are in its likelihood
    assert len(post.data.utterances) == sum("a" in u.labels for u in utts)
    assert {u.meta["speaker"] for u in post.data.utterances} == {"s1", "s2"}
    assert problem_priors(problem) == {}
    # the posterior's shrinkage is the fit's: one constructor gives both the groups on the leader rows
    # (MCMC once looked the class up among the "p|s" rows, found none and sampled without it)
    shrunk = targets_spec(shrink=[{"phonemes": ["p", "t"], "parameters": ["theta_bw"], "sd": 0.3, "scale": "log"}])
    groups = table_problem(shrunk, table, "LLO", utts).shrink_groups
    assert groups and groups == build_problem(shrunk.estimation_settings(), utts, "LLO").shrink_groups
    assert [problem.data.phonemes[r] for r in groups[0].rows] == ["p|s1", "t|s1"]
    # the seam MCMC samples through (sample_table) carries that problem's pieces, the groups included
    sampling = ChannelSampling.of(table_problem(shrunk, table, "LLO", utts))
    assert sampling.channel == "LLO" and tuple(sampling.shrinkage) == tuple(groups) and sampling.speakers is None
    assert sampling.data.phonemes == problem.data.phonemes and sampling.pool is None and dict(sampling.priors) == {}


@pytest.mark.parametrize("mode", ["none", "offset_scale"])
def test_held_out_speaker_validation(utts, mode: str, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """[validate] group = "speaker": leave one speaker out, scored with the population mapping and
    after calibrating the held-out speaker's offset and scale on its own data."""
    from coartic.jobs.fit import fit_job
    from coartic.evaluation.validate import validate_all

    three = list(utts)
    for u in utts:
        if u.meta["speaker"] == "s1":  # s3 = 0.8 × s1 − 0.3 mm
            v = copy.deepcopy(u)
            v.name, v.meta = u.name + "-s3", {**u.meta, "speaker": "s3"}
            v.observed = {ch: 0.8 * y - 0.3 for ch, y in u.observed.items()}
            three.append(v)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"], "speakers": mode},
           "parameters": {"free": ["target", "theta_bw"]}, "validate": {"group": "speaker"}}
    s = parse_spec(raw, Path("/tmp/test_spec.toml"))
    scores = validate_all(s, tmp_path / "validation", utterances=three, fit=fit_job)
    assert [sc.split for sc in scores] == [f"fold {i}/3 (speaker s{i} held out)" for i in (1, 2, 3)]
    for sc in scores:
        # a speaker the table never saw: calibrating its offset and scale on its own data removes
        # what the model's dynamics do not explain only
        assert sc.test_rmse_calibrated < sc.test_rmse
    held_s2 = scores[1]
    assert held_s2.test_rmse > 1.3 * held_s2.test_rmse_calibrated
    text = (tmp_path / "validation" / "validation.csv").read_text()
    assert "test_rmse_speaker_calibrated_mm" in text.splitlines()[0]
