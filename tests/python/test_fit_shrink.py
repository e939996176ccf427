"""Shrinkage of a phoneme class toward its mean ([[shrink]]) and a setting chosen by cross-validation
([choose], coartic fit --choose): issue 10 item 2."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coartic import model
from fit_helpers import check_problem_derivatives, spec_of
from coartic.fit import run
from coartic.jobs.fit import fit_job
from coartic.evaluation.choose import Choice, CurvePoint
from coartic.fit.choose import parse_choose, set_value
from coartic.estimation.problem import build_problem
from coartic.fit.simulate import PHONEMES, vcv_utterances
from coartic.errors import SpecError
from coartic.fit.spec import Choose
from coartic.table import PARAMETERS


@pytest.fixture(scope="module")
def utts() -> list[model.Utterance]:
    return vcv_utterances(np.random.default_rng(3), repetitions=2, rates={"normal": 1.0}, consonants=("p", "t"))


def test_shrinkage_rows_have_exact_derivatives(tmp_path: Path, utts: list[model.Utterance]) -> None:
    # log-scale α and θ (α of the reference /a/ is fixed: it counts in the mean, no derivative), a
    # natural-scale k_R over a class with a [[tie]] inside it, and the target
    s = spec_of(tmp_path, parameters={"free": ["target", "alpha", "theta_bw", "theta_fw", "k_r"], "prior_noise": 0.5},
                tie=[{"phonemes": ["i", "a"], "parameters": ["k_r"]}],
                shrink=[{"phonemes": ["a", "i", "p"], "parameters": ["alpha", "theta_bw"], "sd": 0.3, "scale": "log"},
                        {"phonemes": ["a", "i", "t"], "parameters": ["k_r", "target"], "sd": 0.2}])
    prob = build_problem(s.estimation_settings(), utts, "LLO", phonemes=PHONEMES)
    assert prob.shrinkage.size == 4 * 3
    x = prob.packing.pack() + np.random.default_rng(1).normal(0.0, 0.05, prob.packing.n_free)
    check_problem_derivatives(prob, x)
    # the rows: prior_noise · (log α_i − mean log α) / sd over /a i p/
    params, _ = prob.packing.unpack(x)
    la = np.log(params[[1, 2, 3], PARAMETERS.index("alpha")])
    n = prob.data.corpus.n_samples
    np.testing.assert_allclose(prob.residuals(x)[n:n + 3], 0.5 * (la - la.mean()) / 0.3, rtol=1e-12)
    # a stage that frees only some members: the others count in the mean at their values
    free = prob.packing.free.copy()
    free[:, 1:] = False
    stage = prob.with_packing(prob.packing.with_free(free, False, params))
    check_problem_derivatives(stage, stage.packing.pack())
    assert stage.shrinkage.size == prob.shrinkage.size


def test_a_shrink_row_pulls_an_outlier_toward_its_class(tmp_path: Path, utts: list[model.Utterance]) -> None:
    # k_R: /p/ 1.0 (always reached), /a i t/ 0.3-0.4; shrunk together with sd 0.02
    free = {"free": ["target", "k_r"]}
    k = PARAMETERS.index("k_r")
    fits = {}
    for name, shrink in (("free", []), ("shrunk", [{"phonemes": ["a", "i", "p", "t"], "parameters": ["k_r"], "sd": 0.02}])):
        s = spec_of(tmp_path, parameters=free, shrink=shrink)
        res = fit_job(s, tmp_path / name, utterances=utts, quiet=True, report=False)
        fits[name] = res.channels["LLO"]
    row = {p: i for i, p in enumerate(fits["free"].phonemes)}
    for name in fits:
        v = fits[name].params[[row[p] for p in "aipt"], k]
        fits[name].spread = v.max() - v.min()  # type: ignore[attr-defined]
        fits[name].p_gap = v[2] - v[[0, 1, 3]].mean()  # type: ignore[attr-defined]
    assert fits["free"].p_gap > 0.4  # type: ignore[attr-defined]
    assert fits["shrunk"].p_gap < 0.5 * fits["free"].p_gap  # type: ignore[attr-defined]
    assert fits["shrunk"].spread < fits["free"].spread  # type: ignore[attr-defined]
    text = (tmp_path / "shrunk" / "fit_report.txt").read_text()
    assert "[[Shrinkage]]" in text and "shrink #1 k_r: sd 0.02" in text
    meta = json.loads((tmp_path / "shrunk" / "table.json").read_text())["metadata"]
    assert meta["shrinkage"][0]["phonemes"] == ["a", "i", "p", "t"] and meta["shrinkage"][0]["sd"] == 0.02


def test_cross_validation_chooses_the_strength(tmp_path: Path, utts: list[model.Utterance]) -> None:
    # /p/ and /t/ have targets 5.5 mm apart: forcing them together (sd 0.001) predicts held-out
    # repetitions badly, so CV must choose the weak end of the grid, then fit all data with it
    s = spec_of(tmp_path, shrink=[{"phonemes": ["p", "t"], "parameters": ["target"], "sd": 1.0}],
                choose={"key": "shrink.sd", "values": [100.0, 0.001], "group": "repetition", "folds": 2})
    res = fit_job(s, tmp_path / "out", utterances=utts, quiet=True, report=True)
    assert 'src="choose.png"' in (tmp_path / "out" / "report.html").read_text()
    ch = res.choice
    assert ch is not None and ch.chosen == {"LLO": 100.0} and len(ch.folds) == 2
    weak, strong = (next(p for p in ch.curve("LLO") if p.value == v) for v in (100.0, 0.001))
    assert strong.mean > 1.3 * weak.mean
    # the final fit used the chosen sd: /p/ and /t/ targets stay apart
    fit = res.channels["LLO"]
    assert fit.problem.shrinkage.groups[0].sd == 100.0
    row = {p: i for i, p in enumerate(fit.phonemes)}
    assert fit.params[row["t"], 0] - fit.params[row["p"], 0] > 4.0
    meta = json.loads((tmp_path / "out" / "table.json").read_text())["metadata"]
    assert meta["choice"]["chosen"] == {"LLO": 100.0} and meta["choice"]["rule"] == "1se"
    csv = (tmp_path / "out" / "choose.csv").read_text().splitlines()
    assert csv[0].startswith("key,value,channel") and len(csv) == 3
    assert (tmp_path / "out" / "choose.png").stat().st_size > 0
    assert "<- chosen" in (tmp_path / "out" / "fit_report.txt").read_text()


def test_the_one_standard_error_rule_moves_to_the_stronger_end() -> None:
    def choice(key: str, rule: str) -> Choice:
        pts = [CurvePoint(v, "LLO", list(m), [100, 100]) for v, m in
               ((0.1, (0.30, 0.32)), (1.0, (0.26, 0.32)), (10.0, (0.45, 0.47)))]
        c = Choice(Choose(key, (0.1, 1.0, 10.0), rule=rule), pts, ["f1", "f2"])
        c.pick()
        return c

    assert choice("shrink.sd", "min").chosen == {"LLO": 1.0}
    assert choice("shrink.sd", "1se").chosen == {"LLO": 0.1}  # 0.31 is within one SE (0.03) of 0.29
    assert choice("prior_noise", "1se").chosen == {"LLO": 1.0}  # stronger is larger: 10 is far worse


def test_mcmc_has_the_shrinkage_of_the_fit_spec(tmp_path: Path, utts: list[model.Utterance]) -> None:
    from coartic.mcmc.posterior import LogPosterior, phoneme_posterior
    from coartic.mcmc.run import table_problem

    s = spec_of(tmp_path, parameters={"free": ["target", "theta_bw"]},
                shrink=[{"phonemes": ["a", "i", "p", "t"], "parameters": ["theta_bw"], "sd": 0.5, "scale": "log"}])
    table = run(s, utterances=utts, quiet=True).table()
    problem = table_problem(s, table, "LLO", utts)
    data, packing, opts = problem.data, problem.packing, problem.options
    groups = problem.shrink_groups
    x = packing.pack()[None]
    th = np.log(packing.base[[data.phonemes.index(p) for p in "aipt"], PARAMETERS.index("theta_bw")])
    expected = -0.5 * np.sum(((th - th.mean()) / 0.5) ** 2)
    with_s = LogPosterior(data, packing, opts, noise=0.1, shrinkage=groups)
    without = LogPosterior(data, packing, opts, noise=0.1)
    assert with_s(x)[0] - without(x)[0] == pytest.approx(expected, rel=1e-9)
    # a per-phoneme posterior keeps the whole class in the penalty (the others at their fitted values)
    one = phoneme_posterior(data, packing, opts, "p", 0.1, shrinkage=groups)
    assert one.log_prior(one.start_point()[None])[0] == pytest.approx(expected, rel=1e-9)
    # a value chosen by CV is what the posterior uses
    table.metadata["choice"] = {"key": "shrink.sd", "chosen": {"LLO": 0.25}}
    assert table_problem(s, table, "LLO", utts).shrink_groups[0].sd == 0.25


@pytest.mark.parametrize("sections, key, words", [
    ({"shrink": [{"phonemes": ["p"], "parameters": ["k_r"], "sd": 0.1}]}, "shrink #1.phonemes", "two distinct"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["speed"], "sd": 0.1}]}, "shrink #1.parameters", "unknown parameter"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["k_r"]}]}, "shrink #1", "missing key 'sd'"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": 0.1},
                 {"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": -1.0}]}, "shrink #2.sd", "positive"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["theta_bw", "k_r"], "sd": 0.1, "scale": "log"}]},
     "shrink #1.scale", "log scale needs positive parameters"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": 0.1, "strength": 2}]}, "shrink #1", "unknown key"),
    ({"choose": {"key": "shrink.sd", "values": [0.1, 1.0]}}, "choose.key", r"no \[\[shrink\]\] table"),
    ({"choose": {"key": "beta", "values": [0.1, 1.0]}}, "choose.key", "not a setting"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": 0.1}],
      "choose": {"key": "shrink #2.sd", "values": [0.1, 1.0]}}, "choose.key", "no such table"),
    ({"shrink": [{"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": 0.1}],
      "choose": {"key": "shrink.sd", "values": [0.1]}}, "choose.values", "two values or more"),
    ({"choose": {"key": "plateau_fraction", "values": [0.3, 0.5]}}, "choose.rule", "no stronger end"),
    ({"choose": {"key": "prior_noise", "values": [0.3, 1.0], "group": "speaker", "folds": 1}}, "choose.folds",
     "integer >= 2"),
])
def test_bad_shrink_and_choose_tables_are_refused(tmp_path: Path, sections: dict[str, Any], key: str, words: str) -> None:
    with pytest.raises(SpecError, match=words) as e:
        spec_of(tmp_path, **sections)
    assert f"[{key}]" in str(e.value) and "spec.toml" in str(e.value)


def test_shrinkage_of_fixed_values_and_bad_choose_options_are_refused(tmp_path: Path,
                                                                     utts: list[model.Utterance]) -> None:
    s = spec_of(tmp_path, shrink=[{"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": 0.1}])  # k_r not free
    with pytest.raises(SpecError, match=r"\[shrink #1\] k_r is free for none of \['p', 't'\] on LLO"):
        build_problem(s.estimation_settings(), [u for u in vcv_utterances(np.random.default_rng(0), repetitions=1, rates={"n": 1.0},
                                                     consonants=("p", "t"))], "LLO")
    with pytest.raises(SpecError, match=r"\[--choose.values\] shrink.sd takes positive numbers"):
        parse_choose(s, "shrink.sd=0,1")
    with pytest.raises(SpecError, match=r"--choose 'shrink.sd': expected KEY=V1,V2"):
        parse_choose(s, "shrink.sd")
    assert parse_choose(s, "shrink.sd=1, 0.1").choose == Choose("shrink.sd", (0.1, 1.0), "utterance", 5, "1se")
    assert set_value(s, "shrink #1.sd", 0.5).priors.shrinks[0].sd == 0.5


def test_ctrl_c_while_choosing_writes_no_fit(tmp_path: Path, utts: list[model.Utterance],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    import coartic.evaluation.choose as choose

    def interrupted(*args: Any, **kwargs: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(choose, "score", interrupted)  # the scoring of a fold, as [choose] calls it
    s = spec_of(tmp_path, shrink=[{"phonemes": ["p", "t"], "parameters": ["target"], "sd": 1.0}],
                choose={"key": "shrink.sd", "values": [100.0, 0.001], "group": "repetition", "folds": 2})
    res = fit_job(s, tmp_path / "out", utterances=utts, quiet=True, report=False)
    assert res.interrupted and not res.channels and res.choice is None
    assert "interrupted while choosing shrink.sd" in " ".join(res.notes)
    assert not (tmp_path / "out" / "table.json").exists() and not (tmp_path / "out" / "choose.csv").exists()


def test_compare_varies_the_shrinkage_sd(tmp_path: Path) -> None:
    from coartic.evaluation.compare import vary

    s = spec_of(tmp_path, shrink=[{"phonemes": ["p", "t"], "parameters": ["target"], "sd": 1.0},
                                  {"phonemes": ["a", "i"], "parameters": ["target"], "sd": 1.0}])
    made = vary(s, "shrink #2.sd", ["0.1", "3"])
    assert [(m.priors.shrinks[0].sd, m.priors.shrinks[1].sd) for m in made] == [(1.0, 0.1), (1.0, 3.0)]
    assert made[0].name.endswith("shrink #2.sd = 0.1")
    with pytest.raises(SpecError, match="no such"):
        vary(s, "shrink #3.sd", ["0.1"])
    with pytest.raises(SpecError, match="positive"):
        vary(s, "shrink.sd", ["-1"])


def test_a_choice_without_folds_is_refused_naming_choose(tmp_path: Path, utts: list[model.Utterance]) -> None:
    s = spec_of(tmp_path, shrink=[{"phonemes": ["p", "t"], "parameters": ["target"], "sd": 1.0}],
                choose={"key": "shrink.sd", "values": [1.0, 0.1], "group": "repetition"})
    one = [u for u in utts if u.meta["repetition"] == "1"]
    with pytest.raises(SpecError, match=r"\[choose\] group = 'repetition': the 4 training utterance\(s\) form 1 "
                                        r"repetition group.*set the value in the spec"):
        run(s, utterances=one, quiet=True)


def test_coartic_fit_choose_refuses_folds_it_cannot_score(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from coartic.cli import app

    ema = Path(__file__).resolve().parents[2] / "tests" / "data" / "realdata" / "emu-ema-german" / "derived"
    files = [f"{ema}/dfgspp_mo1_prosody_00{n}_ema.csv" for n in (20, 24)]
    labels = [f"{ema}/dfgspp_mo1_prosody_00{n}_Segment.tsv" for n in (20, 24)]
    spec = tmp_path / "ema.toml"
    spec.write_text(f'[corpus]\nfiles = {json.dumps(files)}\nlabels = {json.dumps(labels)}\nlabel_map = "german_sampa"\n'
                    '[model]\nchannels = ["JO"]\n[parameters]\nfree = ["target", "k_r"]\n'
                    '[[shrink]]\nphonemes = ["a", "e", "i"]\nparameters = ["k_r"]\nsd = 0.1\n')
    # two utterances that do not share their phonemes: neither fold can be scored, nothing is written
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "o"), "--choose", "shrink.sd=0.1,1",
                                   "--no-report"])
    assert res.exit_code == 2, res.output
    assert "[choose] no utterance fold can be scored" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "o").exists()
    res = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "o"), "--choose", "shrink #2.sd=0.1,1"])
    assert res.exit_code == 2 and "no such table" in res.output


def test_a_chosen_model_option_is_what_the_table_records(tmp_path: Path, utts: list[model.Utterance]) -> None:
    # the table must evaluate as the channel was fitted: with the chosen plateau fraction
    s = spec_of(tmp_path, model={"channels": ["LLO"], "dominance": "plateau", "plateau_fraction": 0.5},
                choose={"key": "plateau_fraction", "values": [0.0, 1.0], "group": "repetition", "folds": 2,
                        "rule": "min"})
    res = fit_job(s, utterances=utts, quiet=True, report=False)  # the job: the choice is an evaluation
    assert isinstance(res.choice, Choice)
    chosen = res.choice.chosen["LLO"]
    assert res.table().channels["LLO"].plateau_fraction == chosen
    from coartic.evaluation.score import score_utterances

    assert score_utterances(res.table(), utts, ["LLO"]).channel_rows()[0]["rmse_mm"] == pytest.approx(
        res.channels["LLO"].rmse, rel=1e-9)


def test_grid_options_are_read_by_one_parser(tmp_path: Path) -> None:
    from coartic.fit.spec import parse_grid

    assert parse_grid("--vary", " prior_noise = 0.3, 1 ") == ("prior_noise", ["0.3", "1"])
    for bad, said in (("prior_noise", "expected KEY=V1"), ("=1,2", "expected KEY=V1"), ("k=", "expected KEY=V1"),
                      ("k=1,,2", "an empty value")):
        with pytest.raises(SpecError, match=rf"--vary '{re.escape(bad)}': {said}"):
            parse_grid("--vary", bad)
    with pytest.raises(SpecError, match=r"--choose 'shrink.sd=0.1,x': 'x' is not a number"):
        parse_choose(spec_of(tmp_path, shrink=[{"phonemes": ["p", "t"], "parameters": ["k_r"], "sd": 0.1}]),
                     "shrink.sd=0.1,x")
