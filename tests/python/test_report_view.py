"""report.html as a reader sees it, in headless Chromium (Debian's chromium, as the face viewer's
tests drive it), on a real sentence (one German EMA utterance) and on synthetic VCVs with held-out
validation: the first figure is on the first screen, every at-bound row is one compact line whose
explanation opens on demand, and no section is empty."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from coartic.face.viewer import chromium_program
from coartic.evaluation.heldout import held_out
from coartic.jobs.fit import fit_job
from coartic.fit.simulate import vcv_utterances
from coartic.fit.spec import load_spec, parse_spec
from fit_helpers import PAPER_TOML, german_utterance_spec, paper

SCREEN = (1280, 800)

# Appended to a copy of the page: Chromium's --dump-dom then carries the layout's numbers.
MEASURE = """<script>
window.addEventListener("load", () => {
  const b = document.body, top = e => e.getBoundingClientRect().top + window.scrollY;
  const fig = document.querySelector("figure");
  b.dataset.screen = window.innerHeight;
  b.dataset.firstFigure = fig ? top(fig) : -1;
  const bounds = document.getElementById("bounds");
  b.dataset.bounds = bounds ? top(bounds) : -1;
  const rows = [...document.querySelectorAll("#bound-table tr")].slice(1);
  b.dataset.boundRows = rows.length;
  b.dataset.tallestBoundRow = Math.max(0, ...rows.map(r => r.getBoundingClientRect().height));
  b.dataset.lineHeight = parseFloat(getComputedStyle(document.querySelector("td")).lineHeight) || 20;
  // a heading followed by another heading (or by nothing) heads an empty section
  b.dataset.emptySections = [...document.querySelectorAll("h2")].filter(
    h => !h.nextElementSibling || h.nextElementSibling.tagName === "H2").length;
});
</script>"""


@pytest.fixture(scope="module")
def chromium() -> str:
    try:
        return chromium_program()
    except Exception as err:  # scripts/setup.sh installs it; without it there is nothing to look at
        pytest.skip(str(err))


def layout(chromium: str, report: Path, tmp_path: Path) -> dict[str, float]:
    page = report.with_name("measured.html")
    page.write_text(report.read_text(encoding="utf-8").replace("</body>", MEASURE + "</body>"), encoding="utf-8")
    dom = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu",
                          f"--window-size={SCREEN[0]},{SCREEN[1]}", f"--user-data-dir={tmp_path / 'profile'}",
                          "--virtual-time-budget=3000", "--dump-dom", page.resolve().as_uri()],
                         capture_output=True, text=True, timeout=120).stdout
    body = re.search(r"<body([^>]*)>", dom)
    assert body is not None, dom[:500]
    found = {k: float(v) for k, v in re.findall(r'data-([a-z-]+)="(-?[0-9.]+)"', body.group(1))}
    assert "first-figure" in found, body.group(1)
    return found


def check_reads_well(m: dict[str, float], html: str) -> None:
    assert 0 < m["first-figure"] < 0.75 * m["screen"], m  # the first figure shows on the first screen
    assert m["empty-sections"] == 0, m
    if m["bound-rows"]:
        assert m["bounds"] > m["first-figure"], m  # the at-bound table after the figures
        # one row per parameter at a bound: its reading in one or two lines, the explanation closed
        assert m["tallest-bound-row"] <= 3.2 * m["line-height"], m
        assert html.count("<details><summary>") >= m["bound-rows"]


def test_report_of_a_real_sentence_leads_with_the_figures(chromium: str, tmp_path: Path) -> None:
    spec = german_utterance_spec(tmp_path / "german.toml", '[model]\nvariant = "modified"\nchannels = ["LA"]\n'
                                 'reference_phoneme = "a"\n' + PAPER_TOML[0] + '[parameters]\n' + PAPER_TOML[1] +
                                 'free = ["target", "alpha", "k_r"]\n'
                                 '[staging]\nenabled = false\n', name="German EMA, one sentence")
    result = fit_job(load_spec(spec), tmp_path / "out", quiet=True)
    html = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    st = result.channels["LA"].stats
    assert st is not None and len(st.at_bound) >= 5  # a real sentence: many parameters at a bound
    m = layout(chromium, tmp_path / "out" / "report.html", tmp_path)
    assert m["bound-rows"] == len(st.bounds)
    check_reads_well(m, html)
    assert "RMSE by group" not in html  # one sentence has no groups: no empty table
    # its pause ('#' with pauses = "one") has samples: the speech alone is a column of the channels' table
    speech = result.channels["LA"].speech_rmse()
    assert speech is not None and f"<th>speech (pauses left out)</th>" in html and f"<td>{speech[0]:.3f}</td>" in html
    assert html.index('id="trajectories"') < html.index('id="residuals"') < html.index('id="bounds"')


def test_report_of_synthetic_vcvs_shows_the_held_out_figure_with_baselines(chromium: str, tmp_path: Path) -> None:
    utts = vcv_utterances(np.random.default_rng(5), repetitions=2)
    raw = {"name": "synthetic VCVs", "corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target", "alpha", "theta_bw", "theta_fw", "k_r"]},
           "staging": {"enabled": False}, "override": [{"phonemes": ["p"], "bounds": {"k_r": [0.0, 0.8]}}]}
    result = fit_job(parse_spec(paper(raw), tmp_path / "spec.toml"), tmp_path / "out", utterances=utts, quiet=True, validate=True)
    assert held_out(result)
    html = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    m = layout(chromium, tmp_path / "out" / "report.html", tmp_path)
    check_reads_well(m, html)
    assert 'src="figures/heldout.png"' in html and "baseline" in html
    assert "RMSE by group" in html  # the VCVs have vowel and consonant groups
    assert html.index('id="residuals"') < html.index('id="heldout"') < html.index('id="bounds"')
