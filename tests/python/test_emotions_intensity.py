"""A trial's known intensity in the fit (issue 27): each trial of an emotion at intensity s (manifest
column ``intensity``; none counts as 1) is predicted with the neutral targets plus s times the
emotion's deviations, its segments on rows whose target is (1 − s)·neutral + s·emotion
(``Packing.mixes``); the emotive flavour said at 0.5 and 1 is recovered."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from coartic.emotions import EmotionError
from coartic.errors import SpecError
from coartic.estimation.problem import build_problem
from coartic.fit.data import load_utterances
from coartic.fit.spec import load_spec
from coartic.jobs.fit import fit_job
from coartic.synthetic_cli import load_generator
from coartic.table import ParameterTable

from conftest import without_overview
from test_emotions import SPEC, check_module


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """/b/ only, one repetition, every emotion at intensities 0.5 and 1 (78 trials); no test here looks
    at its overview figure."""
    out = tmp_path_factory.mktemp("intensity")
    with without_overview() as gen:
        gen.generate(out, quick=True, progress=False, flavour="emotive", consonants=["b"], intensities=[0.5, 1.0])
    return out


def spec_for(tmp: Path, manifest: Path, mode: str = "targets") -> Path:
    path = tmp / f"{mode}.toml"
    path.write_text(SPEC.format(manifest=manifest.as_posix(), channels=json.dumps(["LR"]))
                    .replace('emotions = "targets"', f'emotions = "{mode}"'), encoding="utf-8")
    return path


def test_generator_says_each_trial_at_its_intensity(session: Path) -> None:
    with (session / "manifest.csv").open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 * 2 * (1 + 6 * 2)
    assert {r["intensity"] for r in rows if r["emotion"] == "neutral"} == {"1.0"}
    assert {r["intensity"] for r in rows if r["emotion"] == "joy"} == {"0.5", "1.0"}
    # the table a trial is generated from: the neutral truth plus s times the emotion's deviations
    gen = load_generator()
    emo = {**gen.load_emotions(), "intensities": [0.5, 1.0]}
    tables = gen.emotion_tables(ParameterTable.load(session / "ground_truth.json"), emo)
    neutral = tables["neutral", 1.0].values["a"]
    assert tables["joy", 0.5].values["a"]["LR"]["target"] == pytest.approx(neutral["LR"]["target"] + 2.0)
    assert tables["joy", 1.0].values["a"]["LR"]["target"] == pytest.approx(neutral["LR"]["target"] + 4.0)


def test_intensity_rows_are_mixes_with_the_exact_jacobian(session: Path, tmp_path: Path) -> None:
    spec = load_spec(spec_for(tmp_path, session / "manifest.csv"))
    problem = build_problem(spec.estimation_settings(), load_utterances(spec), "LR")
    pk = problem.packing
    assert any(p.endswith("|joy*0.5") for p in pk.phonemes) and not any("neutral*" in p for p in pk.phonemes)
    i, n, e = (pk.phonemes.index(f"a{s}") for s in ("|joy*0.5", "|neutral", "|joy"))
    params, _ = pk.unpack(pk.pack())
    assert params[i, 0] == pytest.approx(0.5 * params[n, 0] + 0.5 * params[e, 0])
    # the Jacobian's target columns against central differences of the residuals
    x = pk.pack()
    j = problem.jacobian(x).toarray()
    names = pk.names()
    for name in ("a|neutral.target", "a|joy.target"):
        c = names.index(name)
        h = np.zeros_like(x)
        h[c] = 1e-5
        fd = (problem.residuals(x + h) - problem.residuals(x - h)) / 2e-5
        np.testing.assert_allclose(j[:, c], fd, atol=1e-6)


def test_bad_intensity_names_the_trial(session: Path, tmp_path: Path) -> None:
    with (session / "manifest.csv").open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["file"] = (session / r["file"]).as_posix()
        r["labels"] = (session / r["labels"]).as_posix()
    rows[-1]["intensity"] = "strong"
    manifest = tmp_path / "manifest.csv"
    with manifest.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    spec = load_spec(spec_for(tmp_path, manifest))
    with pytest.raises(EmotionError, match=r"manifest column 'intensity' = 'strong'"):
        build_problem(spec.estimation_settings(), load_utterances(spec), "LR")


def test_intensities_are_refused_with_dynamics(session: Path, tmp_path: Path) -> None:
    """``emotions = "targets+dynamics"`` (test_emotions_dynamics.py) takes no intensities: on this
    file's session rather than a session of its own (the same trials; 2.4 CPU-s to generate)."""
    spec = load_spec(spec_for(tmp_path, session / "manifest.csv", "targets+dynamics"))
    with pytest.raises(SpecError, match=r"targets\+dynamics.*intensity"):
        build_problem(spec.estimation_settings(), load_utterances(spec), "LR")


def test_deviations_are_recovered_from_trials_at_two_intensities(session: Path, tmp_path: Path) -> None:
    """Half the trials of every emotion at half its deviation: the fit's deviations are the full
    ones (ignoring the intensity would return 3/4 of them: 1 mm off for joy's 4 mm)."""
    # no HTML report: nothing here reads it (a third of the fit's CPU, matplotlib's import included)
    fit_job(spec_for(tmp_path, session / "manifest.csv"), tmp_path / "fit", quiet=True, report=False)
    check = check_module()
    table = ParameterTable.load(tmp_path / "fit" / "table.json")
    devs = [d for d in check.deviations(table, ParameterTable.load(session / "ground_truth.json")) if d.channel == "LR"]
    assert len(devs) == 6 * 5  # emotions x phonemes (# a i u b)
    worst = max(devs, key=lambda d: d.error)
    assert worst.error <= check.TOLERANCE_MM, worst
    assert table.metadata["emotions"]["channels"]["LR"]["tau"]["joy"] == pytest.approx(4.0, abs=0.3)
