"""[model] emotions = "targets+dynamics" (issue 27): every emotion's own alpha, theta_bw, theta_fw per
phoneme, each log deviation from neutral pooled toward 0 with an sd per parameter and emotion that
empirical Bayes estimates (coartic.estimation.pooling); the emotive flavour with planted dynamics
(sadness's rates x 0.7, anger's x 1.4) is recovered, the unplanted emotions pooled into neutral."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coartic.emotions import emotion_table
from coartic.estimation.problem import build_problem
from coartic.fit.data import load_utterances
from coartic.fit.spec import load_spec
from coartic.jobs.fit import fit_job
from coartic.table import N_PARAMS, PARAMETERS, ParameterTable

from conftest import without_overview
from test_emotions import SPEC


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """/b/ only, one repetition, the emotions' dynamics planted (42 trials); no test here looks at its
    overview figure."""
    out = tmp_path_factory.mktemp("dynamics")
    with without_overview() as gen:
        gen.generate(out, quick=True, progress=False, flavour="emotive", consonants=["b"], emotion_dynamics=True)
    return out


# The engine stops when the objective or the step changes by less than 1e-6 (relative) instead of its
# default 1e-8: at 1e-8 the emotion prior's refit and the three pooled re-solves took 969 of the fit's
# 1084 evaluations (12.6 of 17 CPU-s, the first re-solve 509 of them), creeping along the stiff
# directions of the families pooled to an sd of 0.001-0.02; at 1e-6 the fit takes 134 evaluations
# (5.4 CPU-s) and recovers as well: every planted deviation within 0.075 of the truth (0.11 at 1e-8;
# the test allows 0.15), the unplanted families' sd 0.001-0.026 (< 0.05 asked), the planted ones'
# 0.19-0.25 (> 0.1 asked); so too before the alternation extrapolated τ's steps (within 0.09; sd
# below 0.01 and 0.21-0.27). Not a setting to copy blindly: in test_emotions_compare a split's fit
# stopped at 1e-6 at a worse optimum (held out 0.171 against 0.145 mm), and the other emotion tests
# keep the defaults.
TOLERANCES = "[engine.options]\nftol = 1e-6\nxtol = 1e-6\n"


def spec_for(tmp: Path, manifest: Path, mode: str = "targets+dynamics") -> Path:
    """test_emotions' spec on LR with ``mode``, staged (with the emotions' own rates free from the
    start, the one-stage fit took 28 CPU-s against the staged one's 20), the engine's tolerances
    ``TOLERANCES``."""
    path = tmp / f"{mode}.toml"
    path.write_text(SPEC.format(manifest=manifest.as_posix(), channels=json.dumps(["LR"]))
                    .replace('emotions = "targets"', f'emotions = "{mode}"')
                    .replace("[staging]\nenabled = false", "[staging]\nenabled = true") + TOLERANCES,
                    encoding="utf-8")
    return path


def test_emotion_rows_have_their_own_rates_pooled_toward_neutral(session: Path, tmp_path: Path) -> None:
    spec = load_spec(spec_for(tmp_path, session / "manifest.csv"))
    problem = build_problem(spec.estimation_settings(), load_utterances(spec), "LR")
    pk, rows = problem.packing, problem.speaker_rows
    assert rows is not None
    tb, kc = PARAMETERS.index("theta_bw"), PARAMETERS.index("c_bw")
    r = pk.phonemes.index("b|sadness")
    followers = {f for f, _ in pk.ties}
    assert pk.free[r, tb] and r * N_PARAMS + tb not in followers  # its own theta_bw
    assert r * N_PARAMS + kc in followers  # c is still the neutral row's
    assert problem.pool is not None
    fams = problem.pool.families
    assert {"emotion theta_bw sadness", "emotion theta_fw anger", "emotion alpha joy"} <= set(fams)
    group = next(g for g in problem.pool.groups if g.family == "emotion theta_bw sadness" and "b|sadness" in g.phonemes)
    assert group.log and group.phonemes == ("b|neutral", "b|sadness")


def test_planted_rates_are_recovered_and_the_others_pooled(session: Path, tmp_path: Path) -> None:
    # no HTML report: nothing here reads it (a third of the fit's CPU, matplotlib's import included)
    fit_job(spec_for(tmp_path, session / "manifest.csv"), tmp_path / "fit", quiet=True, report=False)
    table = ParameterTable.load(tmp_path / "fit" / "table.json")
    dyn = table.metadata["emotions"]["channels"]["LR"]["dynamics"]
    truth = ParameterTable.load(session / "ground_truth.json").metadata["emotions"]["channels"]["LR"]["dynamics"]
    for q in ("theta_bw", "theta_fw"):
        for e, planted in (("sadness", -0.357), ("anger", 0.336)):
            assert truth[q]["deviations"][e]["a"] == pytest.approx(planted, abs=1e-3)
            for ph in ("b", "i", "u"):
                assert dyn[q]["deviations"][e][ph] == pytest.approx(planted, abs=0.15), (q, e, ph)
    fams = table.metadata["pooling"]["LR"]["families"]
    # an emotion on the neutral rates is pooled into them: its family's sd far below the planted ones'
    assert fams["emotion theta_bw sadness"]["sd"] > 0.1 and fams["emotion theta_bw anger"]["sd"] > 0.1
    assert fams["emotion theta_bw joy"]["sd"] < 0.05
    # the table speaks sadness with the slower rates
    sad = emotion_table(table, "sadness", 1.0)
    assert sad.values["b"]["LR"]["theta_bw"] < 0.85 * table.values["b"]["LR"]["theta_bw"]
