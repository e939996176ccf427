"""Multi-start estimation (coartic.fit.multistart) and honest fit statuses (coartic.fit.staged,
`coartic fit`'s console and exit status)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from coartic.cli import app
from coartic.fit.data import load_utterances, manifest_rows
from coartic.fit.engines import EngineResult, evaluation_budget, iteration_budget
from coartic.fit.multistart import (HOP_BOX, HOP_SCALE, Optimum, cluster, fit_multistart, hop, restart_verdict,
                                    sobol_starts, spread_within, trajectory)
from coartic.estimation.problem import build_problem
from coartic.fit.runner import run
from coartic.jobs.fit import fit_job
from coartic.evaluation.score import score_recordings
from coartic.errors import SpecError
from coartic.fit.spec import load_spec
from coartic.fit.staged import StageResult, channel_status
from coartic.table import PARAMETERS

from fit_helpers import EMA, german_utterance_spec

# target_prior = "none": the fit then minimises the SSE alone, which the in-sample comparisons compare.
# The default pause postures: 0024's final pause lies where the recording is NaN, so it stays '#'
# (coartic.model.utterances_with_postures). Fitted as its own '#end' row (before), its 3 more free
# parameters, identified by no sample of their own, gave this unpooled problem more optima: from
# θ 15 (seed 0) and θ 100 (seed 1) the search stopped at two (in-sample 0.3608 and 0.3658 mm), held
# out 1.666 and 2.488 mm, and the test said pauses = "one".
SMALL = ('[model]\nchannels = ["JO"]\n[parameters]\ntarget_prior = "none"\nfree = ["target", "theta_bw", "theta_fw"]\n'
         'start = {{ theta_bw = {theta}, theta_fw = {theta} }}\n[fit]\nstarts = {starts}\nprobe = 5\nkeep = 2\n'
         'include_start = {inc}\n')


def small_problem(tmp_path: Path, theta: float = 40.0, starts: int = 4, inc: str = "true"):
    # utterance 0024: its phonemes cover those of 0020 but /p t/, which score by their class fallbacks
    spec = load_spec(german_utterance_spec(tmp_path / f"s{theta}_{starts}_{inc}.toml",
                                           SMALL.format(theta=theta, starts=starts, inc=inc), utterance="0024"))
    utts = load_utterances(spec, manifest_rows(spec))
    return spec, utts, build_problem(spec.estimation_settings(), utts, "JO")


def test_sobol_starts_cover_the_boxes_in_log_scale_and_keep_the_data_targets(tmp_path: Path) -> None:
    _, _, prob = small_problem(tmp_path)
    pk = prob.packing
    lo, hi = pk.bounds()
    xs = sobol_starts(pk, 32, seed=0)
    np.testing.assert_array_equal(xs, sobol_starts(pk, 32, seed=0))  # deterministic for a seed
    assert not np.allclose(xs, sobol_starts(pk, 32, seed=1))
    assert np.all(xs >= lo) and np.all(xs <= hi)
    col = pk.free_columns % len(PARAMETERS)
    target = col == PARAMETERS.index("target")
    np.testing.assert_array_equal(xs[:, target], np.tile(pk.pack()[target], (32, 1)))
    theta = col == PARAMETERS.index("theta_bw")
    # θ is drawn evenly in log θ over [0.5, 2000]: half the starts below the geometric middle (~32)
    below = (xs[:, theta] < (lo[theta] + hi[theta]) / 2).mean()
    assert 0.4 <= below <= 0.6
    assert np.exp(xs[:, theta]).min() < 5 and np.exp(xs[:, theta]).max() > 200


def test_cluster_groups_end_points_by_fit_and_reports_what_the_data_leave_free(tmp_path: Path) -> None:
    """Two end points with the same fitted curve whose parameter g.theta_fw differs across its box
    (deliberately non-identifiable: the curves are made equal) are one optimum, g.theta_fw reported
    as not identified inside it; the same SSE with another curve, or the same curve with an SSE
    more than the residual variance worse, are distinct optima."""
    _, _, prob = small_problem(tmp_path)
    pk = prob.packing
    x = pk.pack()
    names = pk.names()
    k = names.index("g.theta_fw")
    lo, hi = pk.bounds()
    x_free = x.copy()
    x_free[k] = lo[k] + 0.9 * (hi[k] - lo[k])  # far across its (log) box
    tr = trajectory(prob, x)
    n = prob.data.n_valid
    rmse = float(np.sqrt(np.sum(tr**2) / n))
    other = tr + 0.5 * rmse  # same SSE below, but a fitted curve half the noise away: another optimum
    sse = float(tr @ tr)
    xs = [x, x_free, x.copy(), x.copy()]
    sses = [sse, sse * (1 + 0.1 / n), sse, sse * (1 + 5.0 / n)]  # the last: Δχ² about 5 worse
    optima = cluster(xs, sses, [tr, tr, other, tr], n, [3, 5, 7, 9], ["converged"] * 4, n_free=pk.n_free)
    assert [o.starts for o in optima] == [[3, 5], [7], [9]]
    assert [o.hits for o in optima] == [2, 1, 1]
    assert isinstance(optima[0], Optimum) and optima[0].objective == sse
    free = spread_within(optima[0], pk)
    assert list(free) == ["g.theta_fw"]
    assert free["g.theta_fw"] == pytest.approx(abs(pk.natural(x_free)[k] - pk.natural(x)[k]))
    assert spread_within(optima[1], pk) == {}
    # a start counts once however many of its end points (polishing restarts) fall in one optimum
    again = cluster([x, x], [sse, sse], [tr, tr], n, [4, 4], ["converged"] * 2, n_free=pk.n_free)
    assert len(again) == 1 and again[0].hits == 1 and len(again[0].members) == 2


@pytest.mark.slow
@pytest.mark.multistart
def test_fit_is_independent_of_the_start_held_out_on_real_ema(tmp_path: Path) -> None:
    """Fit utterance 0024 of the German EMA (JO; targets and θ free) from θ starts of 15 and 100 and
    predict utterance 0020 (held out; its /p t/, unseen in 0024, by their class fallbacks): one start
    gives held-out errors 1 mm apart; the default multi-start (32 starts, [parameters.start] among
    them) the same to 0.05 mm, even with another seed (issue 19)."""
    held, rmse = {}, {}
    for starts, theta, seed in ((1, 15.0, 0), (1, 100.0, 0), (32, 15.0, 0), (32, 100.0, 1)):
        spec, utts, _ = small_problem(tmp_path, theta, starts)
        spec = spec.with_options(seed=seed, keep=None, probe=10)  # the default [fit] but for the start
        out = tmp_path / f"out{starts}_{theta}"
        fit = fit_job(spec, out, quiet=True, report=False).channels["JO"]
        rmse[starts, theta] = fit.rmse
        sc = score_recordings(out / "table.json", [EMA / "dfgspp_mo1_prosody_0020_ema.csv"],
                              [EMA / "dfgspp_mo1_prosody_0020_Segment.tsv"], channels=["JO"])
        held[starts, theta] = sc.channel_rows()[0]["rmse_mm"]
        assert (fit.multistart is None) == (starts == 1)
        if fit.multistart is not None:
            assert 0 in fit.multistart.continued  # [parameters.start] is start 0, always continued
    assert abs(held[1, 15.0] - held[1, 100.0]) > 0.05, held  # the test can fail: one start depends on it
    assert abs(held[32, 15.0] - held[32, 100.0]) <= 0.05, held
    assert rmse[32, 15.0] <= rmse[1, 15.0] * (1 + 1e-6) and rmse[32, 100.0] <= rmse[1, 100.0] * (1 + 1e-6)


@pytest.mark.multistart
def test_the_default_spec_is_start_independent_held_out_with_pause_postures(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The default spec (pause postures, partial pooling) on utterance 0024's LA from θ starts of 15
    and 100 and seeds 0, 1 and 3, predicting 0020 held out. Before: 2.539 (seed 0) and 2.765 mm
    (seed 1), because the multi-start's optima at the starting pooling sd lead empirical Bayes to
    different fixed points (α per phoneme, or one shared value) and the search's best decided; and a
    '#end' row fitted from final pauses the recordings do not measure (NaN there). With one pause
    label seed 3 gave 2.524 against 2.765 for the same reason. Now the final pauses stay '#', and
    empirical Bayes runs from each distinct optimum at start 0's data weight, the highest evidence
    kept (coartic.fit.staged.fit_pooled_best): the three agree to 0.05 mm. Seed 3 runs without the
    stopping rule's return test (multistart.RETURNS = 0, the rule before it), where its search reaches
    two optima: with it, the search stops at start 0's optimum, and fit_pooled_best has one candidate."""
    import coartic.fit.multistart as multistart

    held, pools = {}, {}
    for theta, seed in ((15.0, 0), (100.0, 1), (100.0, 3)):
        if seed == 3:
            monkeypatch.setattr(multistart, "RETURNS", 0)
        spec = load_spec(Path(__file__).resolve().parents[2] / "fit" / "ema_german_defaults_0024.toml")
        assert spec.model.pauses == "postures" and spec.fit.starts == 32  # the defaults, as a user gets them
        spec = spec.with_options(channels=("LA",), seed=seed, start={**spec.parameters.start, "theta_bw": theta, "theta_fw": theta})
        out = tmp_path / f"o{seed}"
        fit = fit_job(spec, out, quiet=True, report=False).channels["LA"]
        # its final pauses hold no valid sample: no '#end' row (coartic.model.utterances_with_postures)
        assert "#end" not in fit.problem.phonemes and "#" in fit.problem.phonemes
        pools[seed] = fit.pooling
        sc = score_recordings(out / "table.json", [EMA / "dfgspp_mo1_prosody_0020_ema.csv"],
                              [EMA / "dfgspp_mo1_prosody_0020_Segment.tsv"], channels=["LA"])
        held[seed] = sc.channel_rows()[0]["rmse_mm"]
    assert max(held.values()) - min(held.values()) <= 0.05, held
    # seed 3 reaches two optima; the one kept has the highest settled evidence of them
    est = pools[3]
    assert est is not None and len(est.candidates) >= 2, est
    ev = [c["log_evidence"] for c in est.candidates]
    assert est.log_evidence == max(ev) == ev[est.chosen]
    assert "the highest evidence kept" in (tmp_path / "o3" / "fit_report.txt").read_text()


@pytest.mark.multistart
def test_multistart_is_deterministic_and_reports_its_optima(tmp_path: Path) -> None:
    spec, utts, prob = small_problem(tmp_path, starts=4)
    capped = {"max_nfev": 8}  # determinism, not convergence, is tested: short final fits
    a = fit_multistart(prob, "scipy", capped, spec.staging.stages, 4, seed=3, probe=3, keep=2)
    b = fit_multistart(prob, "scipy", capped, spec.staging.stages, 4, seed=3, probe=3, keep=2, workers=2)
    np.testing.assert_array_equal(a[1].x, b[1].x)  # threads or not, the same answer
    ms = a[3]
    assert len(ms.probe_objective) == 4 and len(ms.continued) == 2
    # [parameters.start] is start 0 and always goes on. Start 1 is fitted in full to confirm it (the
    # stopping rule), here stopped at its cap (one single fit's evaluations): it is then ranked with the
    # probes of the others, and the best of them goes on
    assert np.isnan(ms.probe_objective[0]) and ms.probed == 3 and ms.include_start
    assert ms.continued == [0, min(range(1, 4), key=lambda i: ms.probe_objective[i])]
    # every continued start ended in some optimum (its polishing restarts may reach others too)
    assert set().union(*(o.starts for o in ms.optima)) == set(ms.continued)
    # the return test's restart from start 0's optimum stopped at its cap (8 evaluations): not a return
    assert 1 <= ms.returns <= 2 and "reached again" not in ms.stopped
    assert ms.hops == sum(len(o.members) for o in ms.optima) - 2 - ms.returns and set(ms.chains) <= set(ms.continued)
    assert ms.best.objective == min(ms.final_objective.values()) == pytest.approx(prob.with_packing(a[0].packing).sse(a[1].x))
    # the best start's stages: its probe's then its continued fit, or start 0's own staged fit
    assert [s.probe for s in a[2]] == [ms.best.starts[0] != 0] * (len(a[2]) - 1) + [False]
    d = ms.as_dict(prob.data.n_valid)
    assert d["starts"] == 4 and d["best_hits"] == ms.best.hits and len(d["optima"]) == len(ms.optima)


@pytest.mark.multistart
def test_cli_reports_optima_everywhere_and_exits_3_when_the_best_was_found_once(tmp_path: Path) -> None:
    spec = german_utterance_spec(tmp_path / "s.toml", SMALL.format(theta=40.0, starts=4, inc="true"))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(out)])
    summary = json.loads((out / "summary.json").read_text())
    ms = summary["channels"]["JO"]["multistart"]
    html = (out / "report.html").read_text()
    assert "Multi-start: distinct optima" in html and f"of {ms['continued']} continued (4 started)" in html
    assert ms["starts"] == 4 and ms["continued"] == 2 and ms["optima"]
    text = (out / "fit_report.txt").read_text()
    assert "multi-start: 4 starts drawn (seed 0, start 0 [parameters.start])" in text and "optimum 1: data RMSE" in text
    assert "spread_between_optima" in (out / "parameters.csv").read_text().splitlines()[0]
    status = summary["channels"]["JO"]["status"]
    assert status == ("best-found-once" if ms["best_hits"] == 1 else "converged")
    assert res.exit_code == (3 if status == "best-found-once" else 0), res.output
    assert "distinct optim" in res.output


def test_fit_section_is_checked(tmp_path: Path) -> None:
    for body, key in (("starts = 0", "fit.starts"), ("seed = -1", "fit.seed"), ("starts = 2\nkeep = 3", "fit.keep"),
                      ("start = 4", "fit"), ("include_start = 1", "fit.include_start")):
        with pytest.raises(SpecError, match=key.replace(".", r"\.")):
            load_spec(german_utterance_spec(tmp_path / "s.toml", f'[model]\nchannels = ["JO"]\n[fit]\n{body}\n'))
    spec = load_spec(german_utterance_spec(tmp_path / "d.toml", '[model]\nchannels = ["JO"]\n'))
    assert spec.fit.starts == 1  # (conftest: tests fit once unless marked multistart)


@pytest.mark.multistart
def test_default_is_multistart(tmp_path: Path) -> None:
    spec = load_spec(german_utterance_spec(tmp_path / "d.toml", '[model]\nchannels = ["JO"]\n'))
    assert spec.fit.starts == 32 and spec.fit.seed == 0


def _stage(status: str, probe: bool = False) -> StageResult:
    return StageResult(("target",), 3, 10.0, 5.0, EngineResult(np.zeros(3), status, f"{status} here", 10, 10), probe)


def test_channel_status_names_a_failed_or_limited_stage_and_a_lone_best() -> None:
    final = EngineResult(np.zeros(3), "converged", "ok", 10, 10)
    assert channel_status(final, [_stage("converged"), _stage("converged")]) == ("converged", "ok")
    st, msg = channel_status(final, [_stage("failed"), _stage("converged")])  # nlopt's failed local lbfgs
    assert st == "stage-failed" and "stage 1" in msg and "failed here" in msg
    assert channel_status(final, [_stage("max-evaluations"), _stage("converged")])[0] == "max-evaluations"
    # a multi-start probe is capped on purpose: no finding
    assert channel_status(final, [_stage("max-evaluations", probe=True), _stage("converged")])[0] == "converged"
    assert channel_status(final, [_stage("converged")], best_found_once=True)[0] == "best-found-once"
    limited = EngineResult(np.zeros(3), "max-evaluations", "IPOPT: Maximum_Iterations_Exceeded", 10, 10)
    assert channel_status(limited, [_stage("converged")])[0] == "max-evaluations"


@pytest.mark.parametrize("engine, option", [("scipy", "max_nfev"), ("nlopt", "local_maxeval"), ("casadi", "max_iter")])
def test_every_engine_reports_its_limit_in_status_summary_and_exit_code(tmp_path: Path, engine: str, option: str) -> None:
    """The issue's cases: casadi at its iteration limit exited 0; any engine at its limit now says
    so in the console line, summary.json and the exit status (3)."""
    spec = german_utterance_spec(tmp_path / "s.toml", '[model]\nchannels = ["JO"]\n[parameters]\nfree = ["target", '
                                 f'"theta_bw"]\n[staging]\nenabled = false\n[engine]\nname = "{engine}"\n'
                                 f'[engine.options]\n{option} = 3\n')
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(out), "--no-report"])
    assert res.exit_code == 3, res.output
    assert json.loads((out / "summary.json").read_text())["channels"]["JO"]["status"] == "max-evaluations"
    assert "JO: max-evaluations" in res.output


def test_budget_scales_with_the_problem(tmp_path: Path) -> None:
    _, _, prob = small_problem(tmp_path)
    n = prob.packing.n_free
    assert evaluation_budget(prob) == max(1000, 100 * n + prob.n_residuals // 100)
    assert iteration_budget(prob) == max(300, evaluation_budget(prob) // 10)
    few = prob.with_packing(prob.packing.with_free(prob.packing.free & False, False))
    assert evaluation_budget(few) == 1000


@pytest.mark.parametrize("width", [40, 80, 200])
def test_status_words_are_never_cut(width: int) -> None:
    """The console's RMSE table and status lines at any width: every status word whole."""
    from types import SimpleNamespace

    from coartic.console import print_table
    from coartic.jobs.fit_cli import rmse_table, status_lines

    statuses = {"ULO": "max-evaluations", "LLO": "best-found-once", "JO": "stage-failed", "LA": "converged"}
    chans = {}
    for ch, st in statuses.items():
        chans[ch] = SimpleNamespace(status=st, message=f"why {ch}", rmse=0.2, multistart=None, polished=[],
                                    speech_rmse=lambda: (0.25, 100))
    result = SimpleNamespace(channels=chans, worst=lambda g: {ch: ("a", 0.3) for ch in chans} if g == "vowel" else {},
                             speech_rmse=lambda: {ch: 0.25 for ch in chans})
    buf = io.StringIO()
    console = Console(file=buf, width=width, force_terminal=False, color_system=None)
    print_table(console, rmse_table(result))  # type: ignore[arg-type]
    for line in status_lines(result):  # type: ignore[arg-type]
        console.print(line, soft_wrap=True, highlight=False)
    text = buf.getvalue()
    words = text.split()
    for st in statuses.values():
        assert sum(w.strip("│|:") == st for w in words) >= (1 if st == "converged" else 2), (st, text)
    assert "…" not in text


@pytest.mark.multistart
def test_validation_scores_every_optimum_held_out(tmp_path: Path) -> None:
    """--validate: each split's multi-start optima are scored on its held-out data (validation.csv,
    the split's fit_report.txt)."""
    from coartic.fit.simulate import vcv_utterances
    from coartic.fit.spec import parse_spec
    from coartic.evaluation.validate import validate_all

    utts = vcv_utterances(np.random.default_rng(2), repetitions=2, noise=0.1)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           # a fixed target prior: an estimated one re-solves the best optimum at its sd after the multi-start
           "parameters": {"free": ["target", "theta_bw"], "target_prior": 0.3}, "staging": {"enabled": False},
           "fit": {"starts": 3, "probe": 3, "keep": 2}, "validate": {"holdout_repetition": 2, "test_rate": None}}
    scores = validate_all(parse_spec(raw, tmp_path / "spec.toml"), tmp_path / "val", utterances=utts, fit=fit_job)
    sc = scores[0]
    assert 1 <= len(sc.optima_test_rmse) <= 2 and sc.optima_test_rmse[0] == pytest.approx(sc.test_rmse)
    assert "optima_test_rmse_mm" in (tmp_path / "val" / "validation.csv").read_text().splitlines()[0]
    report = next((tmp_path / "val").glob("*/fit_report.txt")).read_text()
    assert f"held out {sc.split}: {sc.test_rmse:.4f} mm" in report


def test_help_documents_the_exit_statuses_and_the_starts() -> None:
    res = CliRunner().invoke(app, ["fit", "--help"], terminal_width=100)
    text = " ".join(res.output.replace("│", " ").split())
    assert res.exit_code == 0
    for words in ("Exit status: 0 every channel converged; 3", "best-found-once", "max-evaluations", "stage-failed",
                  "[fit] starts", "--starts", "--seed"):
        assert words in text, words


def defaults_spec(path: Path, starts: int = 32) -> Path:
    """The recording (German EMA 0024, JO), the starts and the model that was the default before
    partial pooling (shared θ, a fixed target prior: a penalised objective), well identified. (The
    pooled default re-solves the multi-start's best at its estimated sd: its optima are those of the
    fit at the starting sd, docs/FITTING.md.)"""
    return german_utterance_spec(path, f'[model]\nchannels = ["JO"]\n[parameters]\nfree = ["target", "theta_bw", '
                                 f'"theta_fw"]\nshared = ["theta_bw", "theta_fw"]\ntarget_prior = 0.3\n'
                                 f'[fit]\nstarts = {starts}\n', utterance="0024")


@pytest.mark.multistart
def test_stopping_rule_ends_a_well_identified_search_after_one_start_and_its_return(tmp_path: Path) -> None:
    """Issue 25 item 5: the default spec on one German utterance has one optimum; start 0 reaches it
    and a perturbed restart from it comes back (the return test), so the search stops there (no
    probe, no second start) at most twice one single fit's evaluations (13-29 times before the rule,
    about 2 times with two starts)."""
    one = run(load_spec(defaults_spec(tmp_path / "one.toml", 1)), quiet=True).channels["JO"]
    fit = run(load_spec(defaults_spec(tmp_path / "many.toml")), quiet=True).channels["JO"]
    ms = fit.multistart
    assert ms is not None and ms.continued == [0] and ms.probed == 0 and ms.returns == 1
    assert "reached again from a perturbed restart (1 of at most 2 run)" in ms.stopped and fit.status == "converged"
    assert ms.best.hits == 1 and len(ms.best.members) == 2  # start 0's end and its restart's, one optimum
    assert fit.nfev <= 2.0 * one.nfev, (fit.nfev, one.nfev)
    assert fit.rmse == pytest.approx(one.rmse, abs=1e-6)
    d = ms.as_dict(fit.problem.data.n_valid)
    assert d["return_restarts"] == 1 and d["probed"] == 0 and "stopping rule" in d["stopped"]
    assert "1 perturbed restart from start 0's optimum" in ms.summary_line(fit.problem.data.n_valid)
    # without the return test (returns = 0) the second start confirms, at about twice the cost
    prob = build_problem(load_spec(defaults_spec(tmp_path / "x.toml")).estimation_settings(), fit.problem.data.utterances, "JO")
    spec = load_spec(defaults_spec(tmp_path / "y.toml", 8))
    _, _, _, two = fit_multistart(prob, "scipy", {}, spec.staging.stages, 8, returns=0)
    assert two.continued == [0, 1] and two.best.hits == 2 and two.returns == 0 and "first 2 starts" in two.stopped
    # without the rule (confirm = 0) the same search probes every start
    _, _, _, old = fit_multistart(prob, "scipy", {}, spec.staging.stages, 8, probe=10, confirm=0)
    assert old.probed == 7 and old.nfev > ms.nfev and old.returns == 0


def test_a_restart_is_back_when_it_converged_in_start_0s_curves_no_lower() -> None:
    """The return test's verdict on one restart (issue 25 item 5). On the gestures flavour (LLO, 207
    free, 6974 samples) every restart converged at 141.0505 against start 0's 140.98: Δχ² 3.3 above
    it, its fitted curves 0.03 of the residual RMSE away, a neighbouring minimum; it found nothing
    better, so it is back (before: not, and the search went on to 15 times one start). On the German
    EMA from θ = 100 the restarts stopped at their budget 0.05-0.11 s² above start 0's poor optimum:
    not back (counting them stopped the search there). Lower and elsewhere: a better optimum."""
    n, m = 6974, 207
    rng = np.random.default_rng(0)
    tr0 = rng.normal(0.0, 0.1422, n)
    s0 = float(tr0 @ tr0)
    s2 = s0 / (n - m)
    near = tr0 + 0.03 * np.sqrt(s0 / n) * rng.normal(0.0, 1.0, n)  # the same curves (0.03 of the RMSE)
    far = tr0 + 0.5 * np.sqrt(s0 / n)  # curves half the residual RMSE away: another optimum
    assert restart_verdict(s0, s0 + 3.3 * s2, tr0, near, "converged", n, m) == "back"
    assert restart_verdict(s0, s0 + 0.5 * s2, tr0, near, "converged", n, m) == "back"  # in its optimum
    assert restart_verdict(s0, s0 - 0.5 * s2, tr0, near, "converged", n, m) == "back"  # in it, a little lower
    assert restart_verdict(s0, s0 + 0.1 * s2, tr0, near, "max-evaluations", n, m) == ""  # stopped by its budget
    assert restart_verdict(s0, s0 + 3.3 * s2, tr0, far, "converged", n, m) == ""  # worse, elsewhere: the next
    assert restart_verdict(s0, s0 - 3.3 * s2, tr0, near, "converged", n, m) == "better"  # lower by more than s²
    assert restart_verdict(s0, s0 - 0.5 * s2, tr0, far, "converged", n, m) == "better"  # lower, other curves
    assert restart_verdict(s0, s0 - 3.3 * s2, tr0, near, "max-evaluations", n, m) == "better"


def test_a_restart_moves_log_entries_by_a_factor_and_the_others_within_their_box(tmp_path: Path) -> None:
    """The perturbed restarts (the return test, the polish) move α and θ by a factor of about e^0.5,
    and c, k_R, δ by a twentieth of their box: before, every entry moved by N(0, 0.5), which threw δ
    (box ±0.08 s) and k_R ([0, 1]) onto their bounds, and on the gestures flavour no restart came back
    to the best optimum (bench/results/multistart_confirm-gestures.txt)."""
    spec = load_spec(german_utterance_spec(tmp_path / "h.toml", '[model]\nchannels = ["JO"]\n[parameters]\n'
                                           'free = ["target", "alpha", "theta_bw", "c_bw", "k_r", "delta"]\n',
                                           utterance="0024"))
    pk = build_problem(spec.estimation_settings(), load_utterances(spec, manifest_rows(spec)), "JO").packing
    x = pk.pack()
    lo, hi = pk.bounds()
    y = hop(pk, x, np.random.default_rng(0))
    col = np.array([PARAMETERS.index(p) for _, p in pk.entries()])
    assert np.array_equal(y[col == 0], x[col == 0])  # the targets stay
    assert np.all((y >= lo) & (y <= hi))
    for name in ("alpha", "theta_bw"):  # fitted in logs: a factor e^N(0, 0.5)
        d = (y - x)[col == PARAMETERS.index(name)]
        assert 0.25 < np.std(d) < 1.0, (name, np.std(d))
    for name in ("c_bw", "k_r", "delta"):  # the others: N(0, HOP_BOX of the box), off the bounds
        m = col == PARAMETERS.index(name)
        d = (y - x)[m]
        assert np.all(np.abs(d) <= 5 * HOP_BOX * (hi - lo)[m]), (name, d)
        assert np.all(d != 0) and not np.any((y[m] == lo[m]) | (y[m] == hi[m])), name
    assert HOP_SCALE == 0.5 and 0 < HOP_BOX < 0.2


@pytest.mark.multistart
def test_multistart_reports_data_rmse_and_the_penalised_objective(tmp_path: Path) -> None:
    """Issue 25 item 3: the optima's RMSE is the data RMSE (the fit's own), the penalised objective is
    called so, and the progress counts every evaluation."""
    from coartic.console import LineProgress
    from coartic.fit.runner import fit_channel
    from rich.progress import TextColumn

    spec = load_spec(defaults_spec(tmp_path / "d.toml", 4))
    utts = load_utterances(spec, manifest_rows(spec))
    buf = io.StringIO()
    console = Console(file=buf, width=200, force_terminal=False, color_system=None)
    with LineProgress(TextColumn("{task.description}"), console=console) as progress:
        fit = fit_channel(spec, utts, "JO", progress)
    ms = fit.multistart
    assert ms is not None and fit.problem.penalised and "target prior" in ms.penalty
    assert ms.best.rmse == pytest.approx(fit.rmse, rel=1e-9)  # the data RMSE, not √(objective / n)
    n = fit.problem.data.n_valid
    assert ms.best.objective > ms.best.rmse ** 2 * n  # the target prior's rows add to the SSE
    d = ms.as_dict(n)
    assert d["optima"][0]["rmse_mm"] == pytest.approx(fit.rmse, rel=1e-9)
    assert d["optima"][0]["objective"] == ms.best.objective and d["optima"][0]["sse"] < ms.best.objective
    assert f"data RMSE {fit.rmse:.4f}" in ms.summary_line(n)
    # never worse in data RMSE than start 0, or it says why (the penalty)
    assert ms.best.rmse <= ms.start0_rmse * (1 + 1e-9) or "penalised objective" in (ms.worse_than_start0 or "")
    # the progress line counts every evaluation of every start (it said "done 4 evaluations" after 792)
    last = [ln for ln in buf.getvalue().splitlines() if ln.startswith("JO done")][-1]
    assert f" {fit.nfev} evaluations " in last and "penalised RMS" not in last and "RMSE" in last, last


def test_a_penalised_optimum_worse_in_data_rmse_than_start_0_says_why() -> None:
    from coartic.fit.multistart import MultiStart

    x = np.zeros(2)
    best = Optimum(10.0, x, [3], "converged", rmse=0.6335)
    other = Optimum(10.5, x, [0], "converged", rmse=0.6240)
    ms = MultiStart(8, 0, 10, [0, 3], [np.nan] * 8, {0: 10.5, 3: 10.0}, [best, other], ["a.target"], {}, 1, 1.0, 100,
                    include_start=True, penalty="the priors (the target prior, [parameters.prior])",
                    start0_rmse=0.6240, start0_objective=10.5)
    why = ms.worse_than_start0
    assert why is not None and "0.6240" in why and "0.6335" in why and "target prior" in why
    assert why in ms.summary_line(100) and ms.as_dict(100)["worse_than_start0"] == why
    ms.start0_rmse = 0.64  # start 0 fitted the data worse too: nothing to explain
    assert ms.worse_than_start0 is None
