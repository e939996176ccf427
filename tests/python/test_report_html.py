"""Statistics, saved files and the HTML report of a fit; an interrupted run still writes its result."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coartic import _core
from coartic.estimation.problem import ChannelProblem
from coartic.model import Utterance, build_corpus
from coartic.fit.result import FitResult
from coartic.jobs.fit import fit_job
from coartic.fit.simulate import PHONEMES, TRUTH, vcv_utterances
from coartic.fit.spec import parse_spec
from coartic.report.html import write_report
from coartic.table import ParameterTable

from fit_helpers import paper


def make_spec(tmp_path: Path, free: list[str]) -> Any:
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": free}, "staging": {"enabled": False},
           # /p/ reaches its target (k_R = 1 in the truth): a box below that pins it on the bound
           "override": [{"phonemes": ["p"], "bounds": {"k_r": [0.0, 0.8]}}]}
    return parse_spec(paper(raw), tmp_path / "spec.toml")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> tuple[FitResult, Path]:
    tmp = tmp_path_factory.mktemp("fit")
    utts = vcv_utterances(np.random.default_rng(5), repetitions=2)
    spec = make_spec(tmp, ["target", "alpha", "theta_bw", "theta_fw", "k_r", "psi"])
    # the HTML report is test_html_report's, written there (with the MCMC fragment beside it)
    return fit_job(spec, tmp / "out", utterances=utts, quiet=True, report=False), tmp / "out"


def test_statistics_flags(fitted: tuple[FitResult, Path]) -> None:
    result, _ = fitted
    st = result.channels["LLO"].stats
    assert st is not None
    # sigma is 0 (fixed): psi has no effect at all, so it is not identified
    assert {f"{p}.psi" for p in PHONEMES} <= set(st.unidentified)
    assert "p.k_r" in st.at_bound
    i = st.names.index("a.target")
    assert 0 < st.stderr[i] < 0.1 and abs(st.values[i] - TRUTH[1, 0]) < 5 * st.stderr[i] + 0.05
    assert np.all(np.isnan(st.stderr[[st.names.index(f"{p}.psi") for p in PHONEMES]]))
    assert "at a bound" in result.report_text() and "not identified" in result.report_text()


def test_saved_files_and_table(fitted: tuple[FitResult, Path]) -> None:
    result, out = fitted
    t = ParameterTable.load(out / "table.json")
    fit = result.channels["LLO"]
    np.testing.assert_array_equal(t.to_matrix("LLO", list(fit.phonemes))[0], fit.params)
    assert t.metadata["rmse"]["LLO"] == pytest.approx(fit.rmse) and "coartic" in t.metadata["software"]
    rows = (out / "rmse.csv").read_text().splitlines()
    assert rows[0].startswith("channel,group,value,rmse_mm") and any(",consonant,p," in r for r in rows)
    assert (out / "parameters.csv").read_text().count("\n") == len(PHONEMES) * 10 + 1
    assert ParameterTable.load(out / "table.csv").values == t.values  # values from the CSV, settings from the JSON


def test_html_report(fitted: tuple[FitResult, Path]) -> None:
    result, out = fitted
    (out / "report_mcmc.html").write_text("<h2>Posterior section</h2>")
    html = write_report(result, out).read_text()
    for f in ("trajectories_LLO.png", "residuals.png", "rmse_map.png"):
        assert (out / "figures" / f).stat().st_size > 5000 and f"figures/{f}" in html
    assert "RMSE per channel" in html and "Posterior section" in html and "LLO" in html
    # the model settings as fitted, each with its default and meaning from coartic.settings (one home)
    import markupsafe

    from coartic.settings import CHANNEL_SETTINGS

    settings = html[html.index('id="settings"'):html.index('id="report"')]
    for name, setting in CHANNEL_SETTINGS.items():
        assert f"<td class=\"l\">{name}</td>" in settings and str(markupsafe.escape(setting.meaning)) in settings


def test_interrupted_run_keeps_best_point(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    utts = vcv_utterances(np.random.default_rng(6), repetitions=1)
    orig = ChannelProblem.residuals
    calls = {"n": 0}

    def residuals(self: ChannelProblem, x: np.ndarray) -> np.ndarray:
        calls["n"] += 1
        if calls["n"] == 4:  # one Ctrl-C, inside the engine (1: stage SSE, 2: start check)
            raise KeyboardInterrupt
        return orig(self, x)

    monkeypatch.setattr(ChannelProblem, "residuals", residuals)
    spec = make_spec(tmp_path, ["target", "alpha"])
    spec = spec.with_options(channels=("LLO", "LLO"))
    result = fit_job(spec, tmp_path / "out", utterances=utts, quiet=True)
    assert result.interrupted and list(result.channels) == ["LLO"]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["interrupted"] and summary["channels"]["LLO"]["status"] == "interrupted"
    assert np.isfinite(summary["channels"]["LLO"]["rmse_mm"])


def test_report_escapes_names_and_manifest_cells(tmp_path: Path) -> None:
    """A spec name or a manifest cell holding markup is shown as text, never run in the browser
    (the template's .j2 suffix once defeated select_autoescape)."""
    utts = vcv_utterances(np.random.default_rng(7), vowels=("a",), consonants=("p",), repetitions=2)
    for u in utts:
        u.meta["repetition"] = "<img src=x onerror=alert(2)>" + u.meta["repetition"]
    raw = {"name": "<script>alert(1)</script>", "corpus": {"files": ["x"], "labels": ["y"]},
           "model": {"channels": ["LLO"]}, "parameters": {"free": ["target"]}, "staging": {"enabled": False}}
    # report=False: the report under test is the one written below, with the MCMC fragment
    result = fit_job(parse_spec(raw, tmp_path / "spec.toml"), tmp_path / "out", utterances=utts, quiet=True,
                     report=False)
    (tmp_path / "out" / "report_mcmc.html").write_text("<section class=\"mcmc\"><h3>LLO /p/</h3></section>")
    html = write_report(result, tmp_path / "out").read_text()
    assert "<script>" not in html and "<img src=x" not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html and "&lt;img src=x onerror=alert(2)&gt;1" in html
    assert '<section class="mcmc"><h3>LLO /p/</h3></section>' in html  # the project's own fragment, as HTML


def sentence(rng: np.random.Generator, n_words: int = 20) -> list[Utterance]:
    """One long utterance (a sentence of CV syllables, like the real EMA recordings) and one VCV."""
    labels = ["#"] + [x for _ in range(n_words) for x in (str(rng.choice(["p", "t", "l"])), str(rng.choice(["a", "i"])))] + ["#"]
    d = np.array([0.3] + [0.05] * (len(labels) - 2) + [0.3]) * rng.uniform(0.9, 1.1, len(labels))
    ends = np.cumsum(d)
    starts = np.concatenate([[0.0], ends[:-1]])
    t = np.arange(0.0, ends[-1], 0.01)
    u = Utterance(tuple(labels), starts, ends, t, name="dfgspp_mo1_prosody_0020_ema", observed={}, valid={},
                  meta={"stimulus": "dfgspp_mo1_prosody_0020_ema", "file": "/data/dfgspp_mo1_prosody_0020_ema.csv"})
    f = _core.evaluate(build_corpus([u], PHONEMES), TRUTH, 1.0, _core.ModelOptions("modified", 0.5, 1.0))
    u.observed["LLO"] = np.asarray(f) + rng.normal(0.0, 0.1, t.size)
    u.valid["LLO"] = np.ones(t.size, dtype=bool)
    return [u]


def overlaps(boxes: list[Any]) -> list[tuple[int, int]]:
    return [(i, j) for i in range(len(boxes)) for j in range(i + 1, len(boxes)) if boxes[i].overlaps(boxes[j])]


def test_report_of_a_sentence_reads_well(tmp_path: Path) -> None:
    """A real sentence: a figure wide enough that no two segment labels overlap, a title without
    slashes around the file name, a legend naming each phoneme's colour in the weight panel, and
    the residual over time and per phoneme."""
    from coartic.report import plots

    utts = sentence(np.random.default_rng(3))
    spec = make_spec(tmp_path, ["target"])
    result = fit_job(spec, tmp_path / "out", utterances=utts, quiet=True, report=False)  # written below
    fit = result.channels["LLO"]
    fig = plots.trajectory_figure(fit, result.table(), [0])
    fig.canvas.draw()
    top = fig.axes[0]
    labels = [t for t in top.texts if t.get_text() in PHONEMES]
    assert [t.get_text() for t in labels] == list(utts[0].labels)
    r = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    assert overlaps([t.get_window_extent(r) for t in labels]) == []
    title = top.get_title()
    assert title.startswith("dfgspp_mo1_prosody_0020_ema ") and "/" not in title
    assert top.title.get_window_extent(r).y0 > max(t.get_window_extent(r).y1 for t in labels) - 1  # above the labels
    legend = fig.legends[0]
    assert {t.get_text() for t in legend.get_texts()} == set(utts[0].labels)
    # a VCV stimulus is a transcription: slashes
    assert plots.utterance_title(vcv_utterances(np.random.default_rng(1), repetitions=1)[0]) == "/a p a/  normal"
    # residual per phoneme: the RMSE of the samples inside its segments
    per = plots.phoneme_rmse(fit)
    res = fit.residuals()
    u = utts[0]
    seg = np.searchsorted(u.starts, u.times, side="right") - 1
    for ph, (rmse, n) in per.items():
        m = np.isin(seg, [i for i, lab in enumerate(u.labels) if lab == ph])
        assert n == m.sum() and rmse == pytest.approx(np.sqrt(np.mean(res[m] ** 2)))
    html = write_report(result, tmp_path / "out").read_text()
    for f in ("residuals_time.png", "rmse_phonemes.png"):
        assert (tmp_path / "out" / "figures" / f).is_file() and f"figures/{f}" in html


def test_report_of_a_very_long_utterance_is_bounded(tmp_path: Path) -> None:
    """5000 segments: boundaries, labels and weights left out (and said) instead of minutes of drawing."""
    from coartic.report import plots

    from coartic.estimation.problem import build_problem
    from coartic.fit.result import ChannelFit

    utts = sentence(np.random.default_rng(4), n_words=2500)
    spec = make_spec(tmp_path, ["target"])
    problem = build_problem(spec.estimation_settings(), utts, "LLO", start=(TRUTH.copy(), 1.0), phonemes=PHONEMES)
    x = problem.packing.pack()
    # the model at the truth, unfitted: a fit of 5000 segments would cost the test budget
    fit = ChannelFit("LLO", problem, x, TRUTH.copy(), 1.0, "converged", "", 0, 0.0,
                     fitted=problem.evaluate(TRUTH, 1.0))
    result = FitResult(spec, {"LLO": fit}, "now")
    fig = plots.trajectory_figure(fit, result.table(), [0])
    top, bottom = fig.axes[0], fig.axes[1]
    assert "(5002 segments: boundaries and labels not drawn)" in top.get_title()
    assert not top.texts and not top.collections and "weights not drawn" in bottom.texts[0].get_text()
    assert plots.residual_time_figure(result, [utts[0].name]) is not None
    per = plots.phoneme_rmse(result.channels["LLO"])
    assert sum(n for _, n in per.values()) == len(utts[0].times)


def test_an_at_bound_row_reads_in_one_line() -> None:
    from coartic.report.html import one_line

    assert one_line("k_R = 1: full resistance — the neighbours' R ends at /p/'s target time, so /p/ reaches "
                    "its target exactly") == "full resistance"
    assert one_line("θ_fw = 2000 s^-c, reach θ^(−1/c) = 0.5 ms from its target time with c_fw = 1 (θ is in s^-c: "
                    "the box's 2000 allows reaches down to 0.5 ms at c = 1): the carry-over dominance of /z/ ends "
                    "as fast as allowed after its target: little carry-over into the next segment") == \
        "the carry-over dominance of /z/ ends as fast as allowed after its target"
    assert one_line("Nothing to split here. Second sentence.") == "Nothing to split here"
