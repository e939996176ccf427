"""Engines and staging on data the model made (truth known): recovery, bad starts, Ctrl-C."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coartic.fit.engines import get_engine
from coartic.estimation.problem import ChannelProblem, build_problem
from coartic.fit.simulate import PHONEMES, TRUTH, vcv_utterances
from coartic.fit.spec import parse_spec
from coartic.fit.staged import fit_staged, stage_free_sets
from coartic.table import PARAMETERS

from fit_helpers import paper

FREE = ["target", "alpha", "theta_bw", "theta_fw", "k_r"]


def make_problem(free: list[str] = FREE, noise: float = 0.1, **extra: Any) -> ChannelProblem:
    utts = vcv_utterances(np.random.default_rng(11), repetitions=1, noise=noise)
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": free}, **extra}
    return build_problem(parse_spec(paper(raw), Path("/tmp/spec.toml")).estimation_settings(), utts, "LLO", phonemes=PHONEMES)


def recovered(problem: ChannelProblem, x: np.ndarray) -> np.ndarray:
    return problem.packing.unpack(x)[0]


@pytest.mark.parametrize("engine, options", [
    ("scipy", {}),
    ("nlopt", {"global": "none", "local_maxeval": 3000}),
    ("casadi", {"max_iter": 400}),
])
def test_engines_recover_truth(engine: str, options: dict[str, Any]) -> None:
    p = make_problem()
    final, res, stages = fit_staged(p, engine, options, [["target"], ["alpha", "theta_bw", "theta_fw"], ["k_r"]])
    assert res.status in ("converged", "max-evaluations"), res.message
    params = recovered(final, res.x)
    rmse = np.sqrt(final.sse(res.x) / final.data.n_valid)
    assert rmse < 0.12, f"{engine}: RMSE {rmse} (noise 0.1)"
    np.testing.assert_allclose(params[:, 0], TRUTH[:, 0], atol=0.2, err_msg=f"{engine}: targets")
    assert params[PHONEMES.index("p"), PARAMETERS.index("k_r")] >= 0.9
    # stages are cumulative and each one does not make the fit worse
    assert [s.n_free for s in stages] == sorted(s.n_free for s in stages)
    assert all(s.sse_end <= s.sse_start * (1 + 1e-9) for s in stages)


@pytest.mark.parametrize("method", ["mlsl", "crs2"])
def test_nlopt_global_phase_finds_the_least_squares_optimum(method: str) -> None:
    # targets only: F is linear in them (σ = 0), so the optimum is unique and SciPy's is exact
    p = make_problem(free=["target"], noise=0.05)
    ref = get_engine("scipy")(p, p.packing.pack(), {})
    q = make_problem(free=["target"], noise=0.05)
    res = get_engine("nlopt")(q, q.packing.pack(), {"global": method, "global_maxeval": 300, "local_maxeval": 300})
    assert f"global {method}" in res.message
    assert q.sse(res.x) == pytest.approx(p.sse(ref.x), rel=1e-6)


def test_stage_sets_cover_the_full_fit() -> None:
    p = make_problem(free=list(PARAMETERS))
    sets = stage_free_sets(p, [["target"], ["alpha"]])
    assert sets[0][0][:, 0].all() and not sets[0][0][:, 1:].any()
    np.testing.assert_array_equal(sets[-1][0], p.packing.free)  # the rest joins the last stage


@pytest.mark.parametrize("engine", ["scipy", "nlopt", "casadi"])
def test_bad_start_is_reported_not_raised(engine: str) -> None:
    p = make_problem()
    # a fixed parameter the core refuses (NaN): every evaluation fails
    p.packing.base[PHONEMES.index("t"), PARAMETERS.index("sigma")] = np.nan
    res = get_engine(engine)(p, p.packing.pack(), {})
    assert res.status == "non-finite start" and "not finite" in res.message


@pytest.mark.parametrize("engine, options", [("scipy", {}), ("nlopt", {"global": "none"}), ("casadi", {})])
def test_ctrl_c_keeps_best_point(engine: str, options: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    p = make_problem()
    calls = {"n": 0}
    for name in ("residuals", "sse_gradient"):
        orig = getattr(p, name)

        def wrapped(x: np.ndarray, _orig: Any = orig) -> Any:
            calls["n"] += 1
            if calls["n"] > 12:
                raise KeyboardInterrupt
            return _orig(x)

        monkeypatch.setattr(p, name, wrapped)
    x0 = p.packing.pack()
    sse0 = ChannelProblem(p.data, p.packing, p.options).sse(x0)
    res = get_engine(engine)(p, x0, options)
    assert res.status == "interrupted"
    assert np.all(np.isfinite(res.x)) and np.isfinite(p.best_sse) and p.best_sse <= sse0
    np.testing.assert_array_equal(res.x, p.best_x)


def test_nlopt_fits_the_default_spec_polished_by_scipy_and_says_so(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """The default spec on a German EMA utterance: nlopt's MLSL reaches scipy's optimum, then its
    L-BFGS fails to take a step from it (nlopt's generic FAILURE); the fit is finished by scipy's
    least_squares from that point instead of refused, and the status says so everywhere."""
    from functools import partial

    import coartic.fit.runner as runner
    from coartic.fit import load_spec, run
    from coartic.jobs.fit import fit_job
    from coartic.jobs.fit_cli import status_lines

    root = Path(__file__).resolve().parents[2]
    spec = load_spec(root / "fit" / "ema_german_defaults_0024.toml").with_options(channels=("LA",), starts=1)
    scipy_fit = run(spec, quiet=True).channels["LA"]
    result = fit_job(spec.with_options(engine={"name": "nlopt"}), tmp_path / "nlopt", quiet=True, report=False)
    fit = result.channels["LA"]
    assert fit.status == "converged" and fit.polished
    # (the default's pooling sd is settled to 2 %: two engines' re-solves end within a few 1e-4 mm)
    assert fit.rmse == pytest.approx(scipy_fit.rmse, abs=5e-4)
    assert "nlopt result -1 (FAILURE); polished by scipy least_squares" in fit.polished[-1]
    assert any("LA: polished" in line and "polished by scipy" in line for line in status_lines(result))
    assert "polished by scipy least_squares" in (tmp_path / "nlopt" / "fit_report.txt").read_text()
    # polish = "none": the failure stands, said in the status (stage-failed: exit 3 in `coartic fit`).
    # The failure is stage 1's; the partial pooling after the stages stops at its first estimate here:
    # its re-solves (nlopt's L-BFGS, one at its 7500-evaluation limit: 5 CPU-s) are the fit's above,
    # which checked that they converge (an unconverged re-solve would be the status)
    monkeypatch.setattr(runner, "fit_pooled", partial(runner.fit_pooled, rounds=0))
    unpolished = run(spec.with_options(engine={"name": "nlopt", "options": {"polish": "none"}}), quiet=True).channels["LA"]
    assert unpolished.status == "stage-failed" and not unpolished.polished
    assert "local lbfgs: nlopt result -1 (FAILURE)" in unpolished.message


def test_a_pooling_re_solve_at_its_evaluation_limit_is_resumed(monkeypatch: pytest.MonkeyPatch) -> None:
    """A partial-pooling re-solve that stops at its evaluation limit once τ has settled is resumed
    from its point, not reported unconverged (nlopt's L-BFGS on the default spec of a German EMA
    utterance, where whether a limited re-solve falls on a settled τ depends on the alternation's
    path: here scipy's re-solves stop at 3 evaluations until τ settles, so that it settles at an
    optimum not reached). The fit converges and its pooling settles."""
    import coartic.fit.staged as staged
    from coartic.fit import load_spec, run
    from coartic.fit.engines import EngineResult

    seen: list[tuple[str, object]] = []  # ("re-solve", its status) and ("settled", the answer), in order

    def limited(name: str) -> Any:
        engine = get_engine(name)

        def minimize(problem: ChannelProblem, x0: np.ndarray, options: dict[str, Any]) -> EngineResult:
            if problem.pool is None or not problem.pool.counted:  # the stages, not a re-solve
                return engine(problem, x0, options)
            res = engine(problem, x0, options if ("settled", True) in seen else {**options, "max_nfev": 3})
            seen.append(("re-solve", res.status))
            return res
        return minimize

    def settled(*args: Any) -> bool:
        out = settled_before(*args)
        seen.append(("settled", out))
        return out

    settled_before = staged.settled
    monkeypatch.setattr(staged, "get_engine", limited)
    monkeypatch.setattr(staged, "settled", settled)
    root = Path(__file__).resolve().parents[2]
    spec = load_spec(root / "fit" / "ema_german_defaults_0024.toml").with_options(channels=("LA",), starts=1)
    fit = run(spec, quiet=True).channels["LA"]
    assert fit.status == "converged" and fit.pooling is not None and fit.pooling.settled
    # τ settled after a re-solve at its limit, and the next step was a re-solve (the resume), not the end
    i = seen.index(("settled", True))
    assert seen[i - 1] == ("re-solve", "max-evaluations") and seen[i + 1] == ("re-solve", "converged")


def test_a_pooling_re_solve_polished_by_another_method_is_reported(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A partial-pooling re-solve that another local method finished (nlopt's failed L-BFGS
    polished by scipy) is said where a polished stage is: the fit's polished notes (the console
    line), fit_report.txt and summary.json; before, the re-solve's note was dropped and a polished
    fit read as nlopt's own. Here the engine marks every re-solve polished."""
    import json
    from dataclasses import replace

    import coartic.fit.staged as staged
    from coartic.fit import load_spec
    from coartic.jobs.fit import fit_job
    from coartic.jobs.fit_cli import status_lines

    def polishing(name: str) -> Any:
        engine = get_engine(name)

        def minimize(problem: ChannelProblem, x0: np.ndarray, options: dict[str, Any]) -> Any:
            res = engine(problem, x0, options)
            if problem.pool is not None and problem.pool.counted:  # a re-solve, not a stage
                return replace(res, polished=True, message=f"{res.message}; polished by a test method")
            return res
        return minimize

    monkeypatch.setattr(staged, "get_engine", polishing)
    root = Path(__file__).resolve().parents[2]
    spec = load_spec(root / "fit" / "ema_german_defaults_0024.toml").with_options(channels=("LA",), starts=1)
    result = fit_job(spec, tmp_path / "out", quiet=True, report=False)
    fit = result.channels["LA"]
    assert fit.pooling is not None and fit.pooling.rounds >= 1
    notes = [p for p in fit.polished if p.startswith("pooling re-solve")]
    assert len(notes) == fit.pooling.rounds and all("polished by a test method" in n for n in notes)
    assert any("LA: polished" in line and "pooling re-solve 1" in line for line in status_lines(result))
    assert "polished: re-solve 1:" in (tmp_path / "out" / "fit_report.txt").read_text()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert len(summary["channels"]["LA"]["pooling"]["polished"]) == fit.pooling.rounds


def test_a_failed_pooling_re_solve_keeps_the_last_optimum_that_converged(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A partial-pooling re-solve that fails: the optimum at the last sd that converged is kept,
    written, not refused, and the status (stage-failed) and the pooling (not settled) say so. The
    re-solves are the fits whose pool counts its target centres (Pool.counted); the engine fails
    those alone."""
    import coartic.fit.staged as staged
    from coartic.fit import load_spec, run
    from coartic.fit.engines import EngineResult

    def failing(name: str) -> Any:
        engine = get_engine(name)

        def minimize(problem: ChannelProblem, x0: np.ndarray, options: dict[str, Any]) -> EngineResult:
            if problem.pool is not None and problem.pool.counted:
                return EngineResult(x0, "failed", "a re-solve made to fail", 0, 0)
            return engine(problem, x0, options)
        return minimize

    monkeypatch.setattr(staged, "get_engine", failing)
    root = Path(__file__).resolve().parents[2]
    spec = load_spec(root / "fit" / "ema_german_defaults_0024.toml").with_options(channels=("LA",), starts=1)
    fit = run(spec, quiet=True).channels["LA"]
    assert fit.status == "stage-failed" and "a re-solve made to fail" in fit.message
    assert np.isfinite(fit.rmse) and fit.pooling is not None and not fit.pooling.settled
    assert "the optimum at the last pooling sd that converged is kept" in fit.message
