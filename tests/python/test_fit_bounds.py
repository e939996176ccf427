"""Every free parameter at a bound is explained from the fit itself (coartic.estimation.bounds): each category
on a case built to produce it, and the explanation in fit_report.txt, parameters.csv, summary.json
and the HTML report (escaped)."""

from __future__ import annotations

import csv
import json
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coartic.estimation.bounds import summary_counts
from coartic.estimation.parameters import CATEGORIES
from coartic.fit.result import FitResult, finish_channel
from coartic.jobs.fit import fit_job
from coartic.fit.simulate import PHONEMES, TRUTH, vcv_utterances
from coartic.fit.spec import parse_spec
from coartic.model import Utterance
from coartic.report.html import write_report
from coartic.table import PARAMETERS

from fit_helpers import paper

K = {p: i for i, p in enumerate(PARAMETERS)}
ROW = {p: i for i, p in enumerate(PHONEMES)}


def spec(tmp: Path, free: list[str], parameters: dict[str, Any] | None = None,
         override: list[dict[str, Any]] | None = None) -> Any:
    raw: dict[str, Any] = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
                           "parameters": {"free": free, **(parameters or {})}, "staging": {"enabled": False}}
    if override:
        raw["override"] = override
    return parse_spec(paper(raw), tmp / "spec.toml")


def utterances(seed: int, params: np.ndarray = TRUTH) -> list[Utterance]:
    return vcv_utterances(np.random.default_rng(seed), params, vowels=("a",), consonants=("p", "t", "l"),
                          repetitions=2)


def start_table(tmp: Path) -> Path:
    """The truth as a start table, so the tiny fits start where the data were made."""
    from coartic.table import ParameterTable

    t = ParameterTable(variant="modified", source="truth")
    from coartic.table import ChannelSettings

    t.channels["LLO"] = ChannelSettings("a")
    t.set_from_matrix("LLO", list(PHONEMES), TRUTH, 1.0)
    path = tmp / "truth.json"
    t.save(path)
    return path


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[FitResult, Path]:
    """One fit that puts a parameter in each of domain, active and insensitive:

    - /p/ is made with α 10 but fitted with α fixed at the truth's 2.5 and k_R free: the data want
      more of /p/ than k_R = 1 gives → p.k_r on 1, the model's own limit (domain);
    - /t/'s θ_fw (truth 55) is boxed by an override to [0.5, 20] → active, source the override;
    - /l/'s ψ starts on its lower bound while σ is fixed at 0: ψ changes nothing → insensitive.
    """
    tmp = tmp_path_factory.mktemp("bounds")
    made = TRUTH.copy()
    made[ROW["p"], K["alpha"]] = 10.0
    utts = utterances(11, made)
    s = spec(tmp, ["target", "theta_fw", "k_r"],
             parameters={"start_table": str(start_table(tmp))},
             override=[{"phonemes": ["t"], "bounds": {"theta_fw": [0.5, 20.0]}},
                       {"phonemes": ["l"], "free": ["psi"], "start": {"psi": 10.0}}])
    out = tmp / "out"
    return fit_job(s, out, utterances=utts, quiet=True), out


def notes(result: FitResult) -> dict[str, Any]:
    st = result.channels["LLO"].stats
    assert st is not None
    assert set(st.bounds) == set(st.at_bound)  # every one explained
    return st.bounds


def test_domain_active_insensitive(built: tuple[FitResult, Path]) -> None:
    result, _ = built
    nb = notes(result)
    p = nb["p.k_r"]
    assert (p.category, p.side, p.bound) == ("domain", "upper", 1.0)
    assert "model's domain" in p.source and "k_R" in p.source
    assert p.gradient < 0  # the data pull above 1 (SSE falls as k_R grows)
    assert "bilabial" in p.reading and "reaches its target" in p.reading
    # measured on the fit: with k_R = 1 the model is at T·S(0) at /p/'s target times (MODEL.md §3 item 3)
    gap = re.search(r"At its 4 target times the fitted LLO is on average (\S+) mm", p.reading)
    assert gap is not None and float(gap.group(1)) < 1e-6
    t = nb["t.theta_fw"]
    assert (t.category, t.side, t.bound) == ("active", "upper", pytest.approx(20.0))
    assert t.source == "[override #1] bounds.theta_fw"
    assert t.gain_held_chi2 >= 1 and t.rmse_relaxed < t.rmse
    assert "Relaxing the bound would lower the RMSE" in t.explanation
    psi = nb["l.psi"]
    assert (psi.category, psi.side) == ("insensitive", "lower")
    assert psi.range_chi2 < 1 and "any value fits as well" in psi.explanation
    assert "default box" in psi.source
    assert all(n.category in CATEGORIES for n in nb.values())


def test_optimal_and_unexplained(built: tuple[FitResult, Path]) -> None:
    """A bound put exactly at the fitted value (the data hold it there: not binding), and a point that
    is not a fit, with k_R of /t/ left on 0 while the data want 0.3 (unexplained: a finding)."""
    result, _ = built
    fit = result.channels["LLO"]
    pk = fit.problem.packing
    i = ROW["a"]
    upper = pk.upper.copy()
    upper[i, K["target"]] = fit.params[i, K["target"]]  # the box now ends at the optimum
    again = finish_channel(fit.problem.with_packing(replace(pk, upper=upper)), fit.x, "converged", "", 0.0, [])
    assert again.stats is not None
    n = again.stats.bounds["a.target"]
    assert n.category == "optimal" and n.gain_gn_chi2 < 1 and "best value is the bound itself" in n.explanation

    s = spec(Path(result.spec.path).parent, ["target", "k_r"])
    from coartic.estimation.problem import build_problem

    start = TRUTH.copy()
    start[ROW["t"], K["k_r"]] = 0.0
    pr = build_problem(s.estimation_settings(), utterances(11), "LLO", start=(start, 1.0), phonemes=PHONEMES)
    bad = finish_channel(pr, pr.packing.pack(), "interrupted", "", 0.0, [])
    assert bad.stats is not None
    u = bad.stats.bounds["t.k_r"]
    assert u.category == "unexplained" and "inside the box, the SSE is lower" in u.explanation
    assert "UNEXPLAINED" in FitResult(s, {"LLO": bad}, "now").report_text()
    from coartic.jobs.fit_cli import warning_lines

    assert any(line.startswith("[red]LLO: ") and "UNEXPLAINED" in line
               for line in warning_lines(FitResult(s, {"LLO": bad}, "now")))


def test_saturated_direction_is_not_binding(tmp_path: Path) -> None:
    """/t/'s carry-over made as a step (θ_fw 1e8) and held at a box's 1e6 s^-1, where D is already a
    step between 100 Hz samples: past the bound nothing changes, into the box it costs → not binding.
    (At the default 2000 s^-1 it is not yet a step: samples 0.1 ms after t_i still see it: active.)"""
    from coartic.estimation.problem import build_problem

    made = TRUTH.copy()
    made[ROW["t"], K["theta_fw"]] = 1e8
    start = made.copy()
    start[ROW["t"], K["theta_fw"]] = 1e6
    s = spec(tmp_path, ["target", "theta_fw"], override=[{"phonemes": ["t"], "bounds": {"theta_fw": [0.5, 1e6]}}])
    pr = build_problem(s.estimation_settings(), utterances(13, made), "LLO", start=(start, 1.0), phonemes=PHONEMES)
    fit = finish_channel(pr, pr.packing.pack(), "converged", "", 0.0, [])
    assert fit.stats is not None
    n = fit.stats.bounds["t.theta_fw"]
    assert (n.category, n.side) == ("optimal", "upper")
    assert n.beyond_chi2 < 1 <= n.range_chi2 and "any value beyond fits as well" in n.explanation
    assert "reach θ^(−1/c) = 0.001 ms" in n.reading


def test_report_csv_and_json_carry_the_explanations(built: tuple[FitResult, Path]) -> None:
    result, out = built
    nb = notes(result)
    text = (out / "fit_report.txt").read_text()
    assert "[[At a bound]]" in text and f"why (computed from the fit, [[At a bound]] below): {summary_counts(nb)}" in text
    assert {"domain", "active", "insensitive"} <= {n.category for n in nb.values()}
    for n in nb.values():
        assert f"{n.name} = " in text and n.explanation in text and n.reading in text
    with (out / "parameters.csv").open(newline="") as f:
        rows = {f"{r['phoneme']}.{r['parameter']}": r for r in csv.DictReader(f)}
    assert rows["t.theta_fw"]["bound_category"] == "active" and rows["t.theta_fw"]["bound_side"] == "upper"
    assert rows["t.theta_fw"]["bound_source"] == "[override #1] bounds.theta_fw"
    assert rows["p.k_r"]["bound_category"] == "domain" and "bilabial" in rows["p.k_r"]["bound_explanation"]
    assert rows["a.target"]["bound_category"] == ""  # not at a bound: nothing to explain
    doc = json.loads((out / "summary.json").read_text())
    got = {d["name"]: d for d in doc["channels"]["LLO"]["at_bound_explained"]}
    assert set(got) == set(doc["channels"]["LLO"]["at_bound"]) == set(nb)
    assert got["l.psi"]["category"] == "insensitive" and got["t.theta_fw"]["bound"] == pytest.approx(20.0)
    from coartic.jobs.fit_cli import warning_lines

    assert f"[yellow]LLO: {len(nb)} parameter(s) at a bound[/yellow]: {summary_counts(nb)}" in warning_lines(result)[0]
    html = (out / "report.html").read_text()
    assert "Parameters at a bound, and why" in html and "[override #1] bounds.theta_fw" in html


def test_html_escapes_names_in_the_explanations(tmp_path: Path) -> None:
    """A phoneme label holding markup (it reaches the explanation, the reading and the table) is text."""
    utts = utterances(12)
    evil = "<b onmouseover=alert(3)>"
    for u in utts:
        u.labels = tuple(evil if x == "t" else x for x in u.labels)
    s = spec(tmp_path, ["target", "theta_fw"],
             override=[{"phonemes": [evil], "bounds": {"theta_fw": [0.5, 20.0]}}])
    result = fit_job(s, tmp_path / "out", utterances=utts, quiet=True, report=False)
    st = result.channels["LLO"].stats
    assert st is not None and f"{evil}.theta_fw" in st.bounds
    html = write_report(result, tmp_path / "out").read_text()
    assert evil not in html and "&lt;b onmouseover=alert(3)&gt;" in html


def test_a_shared_parameter_is_reported_as_every_phonemes_everywhere(tmp_path: Path) -> None:
    """Issue 25 item 3: the report called the default's shared θ_bw at its bound "the anticipatory reach
    of /#/" (its carrier's) when it is every phoneme's. The reading, fit_report.txt and parameters.csv
    say whose value it is; a [[tie]] names the tied phonemes."""
    from coartic.estimation.packing import tie_group
    from coartic.estimation.bounds import explain_bounds, reading
    from coartic.fit.result import parameter_stats

    from fit_helpers import german_utterance_spec

    # the previous default's freedom (one θ_bw, θ_fw per channel), given explicitly
    path = german_utterance_spec(tmp_path / "d.toml", '[model]\nchannels = ["JO"]\n[parameters]\n'
                                 'free = ["target", "theta_bw", "theta_fw"]\nshared = ["theta_bw", "theta_fw"]\n'
                                 'target_prior = 0.3\n')
    res = fit_job(path, tmp_path / "out", quiet=True, report=False)
    fit = res.channels["JO"]
    pk = fit.packing
    carrier = next(nm for nm in pk.names() if nm.endswith(".theta_bw"))
    ph = carrier.rpartition(".")[0]
    group = tie_group(pk.phonemes, pk.ties, ph, "theta_bw")
    assert set(group) == set(pk.phonemes) and group[0] == ph
    words = reading("theta_bw", "lower", 0.5, ph, fit.problem, 0.5, {"c_bw": 1.0}, group)
    assert f"every phoneme (one theta_bw shared by all {len(pk.phonemes)})" in words and f"/{ph}/" not in words
    # a bound note made for it carries the group (the fit puts it wherever the data say: forced here)
    st = parameter_stats(fit.problem, fit.x)
    jac = fit.problem.jacobian(fit.x)
    r = fit.problem.residuals(fit.x)
    note = explain_bounds(fit.problem, fit.x, [carrier], jac, r, st.s2, st.corr)[carrier]
    assert note.shared_by == group and "every phoneme" in note.reading and note.as_dict()["shared_by"] == group
    text = (tmp_path / "out" / "fit_report.txt").read_text()
    assert f"every phoneme (one theta_bw shared by all {len(pk.phonemes)}): {carrier} names its carrier" in text
    with (tmp_path / "out" / "parameters.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["parameter"] == "theta_bw"]
    assert {r["shared_by"] for r in rows} == {"all"} and sum(r["tied_to"] == "" for r in rows) == 1
    # a [[tie]] of two phonemes: named as tied across them
    tied = german_utterance_spec(tmp_path / "t.toml", '[model]\nchannels = ["JO"]\n[parameters]\nfree = ["target", '
                                 '"alpha"]\n[[tie]]\nphonemes = ["e", "i"]\nparameters = ["alpha"]\n')
    fit = fit_job(tied, tmp_path / "tied", quiet=True, report=False).channels["JO"]
    assert set(fit.parameters["e.alpha"].shared_by) == set(fit.parameters["i.alpha"].shared_by) == {"e", "i"}
    text = (tmp_path / "tied" / "fit_report.txt").read_text()
    assert "(one alpha tied across them)" in text
