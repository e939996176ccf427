"""Pauses as people label them (issue 25 item 2): one pause label, three postures.

The recordings are files written here that reproduce each case of the English EMA: an open-lipped
breath before the sentence, closed lips after it, and in a fast token a 20 ms "pause" inside the
closure of a /p/. The lips move as a ground-truth table with its own initial and final pause
postures says; the files are read back through the product's readers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import format_fixtures as ff
from coartic import ParameterTable, trajectories
from coartic.fit import run
from coartic.jobs.fit import fit_job
from coartic.evaluation.score import score_recordings
from coartic.fit.spec import load_spec, parse_spec
from coartic.pauses import (FINAL_PAUSE, MEDIAL_ALPHA, MEDIAL_PAUSE, POSTURES_RECORD, RECORD_KEY, is_pause,
                            pause_postures)
from coartic.table import PAUSE

ROOT = Path(__file__).resolve().parents[2]

RATE = 200.0
# Sentences of the written recordings: (labels, durations); '#' the pause label of the label files
SENTENCES = (
    (("#", "p", "a", "m", "i", "t", "u", "#"), (0.25, 0.08, 0.16, 0.08, 0.16, 0.07, 0.18, 0.30)),
    (("#", "m", "i", "p", "a", "t", "i", "#"), (0.25, 0.08, 0.15, 0.09, 0.17, 0.07, 0.16, 0.30)),
    (("#", "t", "u", "m", "a", "p", "i", "#"), (0.25, 0.07, 0.16, 0.08, 0.16, 0.08, 0.17, 0.30)),
)


def truth_table() -> ParameterTable:
    """The synthetic session's ground truth with the English postures: the breath before the
    sentence with open lips (both lips 4 mm above their /a/-less rest), closed lips after it (the
    /p/ posture), and the rules of coartic.pauses recorded."""
    t = ParameterTable.load(ff.TRUTH)
    t.values[FINAL_PAUSE] = {c: dict(v) for c, v in t.values["p"].items()}
    for c in ("ULO", "LLO"):
        t.values[PAUSE][c]["target"] = 4.0
    t.metadata[RECORD_KEY] = dict(POSTURES_RECORD)
    return t


def write_recording(tmp: Path, name: str, labels: tuple[str, ...], durations: tuple[float, ...],
                    label_rows: list[tuple[float, float, str]] | None = None) -> tuple[Path, Path]:
    """An EMA CSV of the lips and jaw moving as ``truth_table`` says over ``labels``, and its label
    file (``label_rows`` if given: the labels as an aligner wrote them)."""
    ends = np.cumsum(durations)
    starts = np.concatenate([[0.0], ends[:-1]])
    times = np.arange(int(np.floor(ends[-1] * RATE + 1e-6))) / RATE
    ch = trajectories(truth_table(), list(labels), starts, ends, times, channels=["ULO", "LLO", "JO", "ULP"])
    up, lo = ch["ULO"], ch["LLO"]
    jaw, prot = ch["JO"] - ch["JO"][0], ch["ULP"] - ch["ULP"][0]
    zeros = np.zeros_like(times)
    sensors = {
        "UL": np.stack([ff.REST["UL"][0] + prot, ff.REST["UL"][1] + up], axis=1),
        "LL": np.stack([ff.REST["LL"][0] + prot, ff.REST["LL"][1] - lo], axis=1),
        "JAW": np.stack([ff.REST["JAW"][0] - 0.2 * jaw, ff.REST["JAW"][1] - jaw], axis=1),
        **{s: np.stack([ff.REST[s][0] + zeros, ff.REST[s][1] + zeros], axis=1) for s in ("TT", "TB", "TD")},
    }
    data = ff.write_lab_csv(tmp / f"{name}.csv", ff.Motion(times, sensors, starts, ends))
    rows = label_rows or [(float(s), float(e), lab) for s, e, lab in zip(starts, ends, labels)]
    lab = tmp / f"{name}.tsv"
    lab.write_text("".join(f"{s!r}\t{e!r}\t{x if x != '#' else 'sil'}\n" for s, e, x in rows))
    return data, lab


def spec_for(tmp: Path, files: list[tuple[Path, Path]], pauses: str) -> Any:
    path = tmp / f"spec_{pauses}.toml"
    path.write_text(f"name = 'pauses {pauses}'\n[corpus]\nfiles = {json.dumps([str(d) for d, _ in files])}\n"
                    f"labels = {json.dumps([str(lab) for _, lab in files])}\n"
                    f"[model]\nchannels = ['LA']\npauses = '{pauses}'\n[fit]\nstarts = 1\n")
    return load_spec(path)


def test_rules_on_labels() -> None:
    labels = ("#", "#", "m", "a", "#", "p", "a", "#", "t", "a", "p", "#", "p", "a", "#", "#")
    durs = (0.2, 0.1, 0.08, 0.15, 0.02, 0.08, 0.15, 0.3, 0.07, 0.15, 0.05, 0.03, 0.05, 0.15, 0.2, 0.3)
    ends = np.cumsum(durs)
    starts = np.concatenate([[0.0], ends[:-1]])
    labs, s, e, changes = pause_postures(labels, starts, ends)
    # the leading pauses stay '#', the trailing ones are '#end'; the 300 ms pause mid-utterance is
    # weak '#mid'; the 20 ms pause before /p/ joins the /p/ (its closure); the 30 ms pause between
    # two /p/ joins them into one /p/
    assert labs == ("#", "#", "m", "a", "p", "a", MEDIAL_PAUSE, "t", "a", "p", "a", FINAL_PAUSE, FINAL_PAUSE)
    assert s[4] == pytest.approx(starts[4]) and e[4] == pytest.approx(ends[5])  # pause + /p/: one segment
    assert s[9] == pytest.approx(starts[10]) and e[9] == pytest.approx(ends[12])  # p # p: one /p/
    assert np.all(s[1:] == e[:-1])
    said = [c.text() for c in changes]
    assert any("(segment 5, 20 ms) is the silent closure of the /p/ after it" in x for x in said)
    assert any("(segment 12, 30 ms) lies between two segments of /p/" in x for x in said)
    assert any("(segment 8, 300 ms) lies inside the utterance: fitted as '#mid', weak" in x for x in said)
    # applying the rules again changes nothing; a table without the rows keeps '#'
    again = pause_postures(labs, s, e)
    assert again[0] == labs and not again[3]
    kept = pause_postures(labels, starts, ends, available={"#", "m", "a", "p", "t"})[0]
    assert kept[6] == PAUSE and kept[-1] == PAUSE and kept[4] == "p"
    # a table fitted on the second halves of utterances has '#end' but no '#'
    assert pause_postures(labs, s, e, available={FINAL_PAUSE, MEDIAL_PAUSE, "m", "a", "p", "t"})[0][:2] == \
        (FINAL_PAUSE, FINAL_PAUSE)
    # a long pause before a stop, or a short one between different vowels, is a medial pause
    long_before_stop = pause_postures(("#", "a", "#", "p", "a", "#"), [0, .1, .2, .35, .4, .5], [.1, .2, .35, .4, .5, .6])
    assert long_before_stop[0][2] == MEDIAL_PAUSE
    assert pause_postures(("a", "#", "i"), [0, .1, .12], [.1, .12, .2])[0] == ("a", MEDIAL_PAUSE, "i")
    assert all(is_pause(p) for p in (PAUSE, FINAL_PAUSE, MEDIAL_PAUSE)) and not is_pause("p")


def test_edge_postures_and_a_pause_inside_a_closure(tmp_path: Path) -> None:
    """Leading open-lip pause, trailing closed-lip pause and a 20 ms pause inside a /p/ closure:
    one pause target cannot fit them (LA error in the pauses), three postures can; the fit
    report names the changes; score and the runtime read the table with its pause rows."""
    files = [write_recording(tmp_path, f"s{k}", labels, durs) for k, (labels, durs) in enumerate(SENTENCES)]
    # the fast token: the aligner wrote the first 20 ms of the /p/ closure as a pause
    labels, durs = SENTENCES[2]  # # t u m a p i #: the /p/ is segment 6
    ends = np.cumsum(durs)
    starts = np.concatenate([[0.0], ends[:-1]])
    rows = [(float(s), float(e), lab) for s, e, lab in zip(starts, ends, labels)]
    rows[5:6] = [(float(starts[5]), float(starts[5]) + 0.02, "#"), (float(starts[5]) + 0.02, float(ends[5]), "p")]
    files.append(write_recording(tmp_path, "fast", labels, durs, rows))

    one = run(spec_for(tmp_path, files, "one"), quiet=True)
    out = tmp_path / "postures"
    three = fit_job(spec_for(tmp_path, files, "postures"), out, quiet=True, report=False)
    table = ParameterTable.load(out / "table.json")
    assert {PAUSE, FINAL_PAUSE} <= set(table.phonemes) and table.metadata[RECORD_KEY]["mode"] == "postures"
    # the final pause has the closed lips of /p/ (LA = 16 mm at rest + ULO + LLO = 11.5 mm), the
    # initial one the open breath (16 + 4 + 4 = 24 mm)
    la = {p: table.values[p]["LA"]["target"] for p in (PAUSE, FINAL_PAUSE)}
    assert abs(la[FINAL_PAUSE] - 11.5) < 1.0 and abs(la[PAUSE] - 24.0) < 1.0

    def pause_rmse(result: Any) -> float:
        fit = result.channels["LA"]
        r = fit.fitted - fit.problem.data.observed
        d = fit.problem.data
        pause = np.zeros(r.size, dtype=bool)
        k = 0
        for u in d.utterances:
            seg = u.sample_segments()
            labs = np.array([is_pause(x) for x in u.labels] + [True])
            pause[k:k + u.times.size] = labs[seg]
            k += u.times.size
        ok = d.weights > 0
        return float(np.sqrt(np.mean(r[pause & ok] ** 2)))

    assert pause_rmse(three) < 0.5 * pause_rmse(one)
    assert three.channels["LA"].rmse < one.channels["LA"].rmse
    report = (out / "fit_report.txt").read_text()
    assert "pauses: 4 utterance-final pause(s) fitted as '#end'" in report
    assert "fast.csv: the pause at 0.720-0.740 s (segment 6, 20 ms) is the silent closure of the /p/ after it" in report

    # `coartic score`'s figures: all samples and speech only, for the table and every baseline
    held = write_recording(tmp_path, "held", SENTENCES[1][0], SENTENCES[1][1])
    sc = score_recordings(out / "table.json", [held[0]], [held[1]], train=tmp_path / "spec_postures.toml")
    for row in sc.baseline_rows():
        assert row["speech_samples"] < row["samples"]
        assert np.isfinite(row["rmse_speech_mm"]) and np.isfinite(row["rmse_speech_offset_removed_mm"])
    assert {r["model"] for r in sc.baseline_rows()} >= {"table", "step", "constant"}
    assert "speech only (pauses left out)" in sc.text()

    # the runtime animates labels with pauses from the new table, and old tables still load
    from coartic.runtime.animate import animate
    from coartic.io.labels import read_labels
    from coartic.io.labelmap import LabelMap

    segs = LabelMap.model().apply(read_labels(files[-1][1]))
    anim = animate(table, segs, 100.0, channels=["LA"])
    final = anim.times > ends[-2] + 0.15
    assert np.all(np.isfinite(anim.channels["LA"]))
    assert abs(float(np.mean(anim.channels["LA"][final])) - la[FINAL_PAUSE]) < 1.5
    old = json.loads((out / "table.json").read_text())
    old["metadata"].pop(RECORD_KEY)
    for p in (FINAL_PAUSE,):
        for section in ("values", "parameters", "phonemes"):
            if isinstance(old.get(section), dict):
                old[section].pop(p, None)
    (tmp_path / "old.json").write_text(json.dumps(old))
    before = ParameterTable.load(tmp_path / "old.json")
    assert FINAL_PAUSE not in before.phonemes
    assert np.all(np.isfinite(animate(before, segs, 100.0, channels=["LA"]).channels["LA"]))


def test_medial_pause_is_weak(tmp_path: Path) -> None:
    """A medial pause's α starts (and, α not free, stays) at MEDIAL_ALPHA: its neighbours dominate."""
    from coartic.estimation.problem import build_problem
    from coartic.model import Utterance

    times = np.arange(0, 1.0, 0.005)
    u = Utterance(("#", "a", "#", "i", "#"), [0, .2, .4, .7, .9], [.2, .4, .7, .9, 1.0], times, "u",
                  {"LA": np.sin(times * 6)}, {"LA": np.ones(times.size, dtype=bool)})
    from coartic.fit.data import with_spec_pauses

    s = parse_spec({"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LA"]}}, tmp_path / "s.toml")
    notes: list[str] = []
    (v,) = with_spec_pauses(s, [u], notes)
    assert v.labels == ("#", "a", MEDIAL_PAUSE, "i", FINAL_PAUSE)
    assert any("'#mid', weak" in n for n in notes)
    p = build_problem(s.estimation_settings(), [v], "LA")
    row = p.phonemes.index(MEDIAL_PAUSE)
    # the default frees α (pooled): the medial pause's starts at MEDIAL_ALPHA; where α is not free it stays there
    assert p.packing.base[row, 1] == MEDIAL_ALPHA and f"{MEDIAL_PAUSE}.alpha" in p.packing.names()
    fixed = build_problem(s.with_options(free=("target", "theta_bw", "theta_fw"), pooled=()).estimation_settings(), [v], "LA")
    assert fixed.packing.base[row, 1] == MEDIAL_ALPHA and f"{MEDIAL_PAUSE}.alpha" not in fixed.packing.names()


def test_edge_pauses_share_one_alpha(tmp_path: Path) -> None:
    """The edge pauses have their own targets but one α (EDGE_TIED): the initial pause's row carries
    it, the final pause's follows; a [[tie]] that holds either decides instead, and where α is not
    free nothing is tied."""
    from coartic.estimation.problem import build_problem
    from coartic.fit.data import with_spec_pauses
    from coartic.fit.spec import Tie
    from coartic.model import Utterance
    from coartic.pauses import EDGE_TIED
    from coartic.table import N_PARAMS, PARAMETERS

    assert EDGE_TIED == ("alpha",)
    times = np.arange(0, 1.0, 0.005)
    u = Utterance(("#", "a", "i", "#"), [0, .3, .5, .7], [.3, .5, .7, 1.0], times, "u",
                  {"LA": np.sin(times * 6)}, {"LA": np.ones(times.size, dtype=bool)})
    s = parse_spec({"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LA"]}}, tmp_path / "s.toml")
    (v,) = with_spec_pauses(s, [u])
    p = build_problem(s.estimation_settings(), [v], "LA")
    names = p.packing.names()
    first, last, k = p.phonemes.index(PAUSE), p.phonemes.index(FINAL_PAUSE), PARAMETERS.index("alpha")
    assert f"{PAUSE}.alpha" in names and f"{FINAL_PAUSE}.alpha" not in names
    assert (last * N_PARAMS + k, first * N_PARAMS + k) in p.packing.ties
    # their own targets and θ: a posture is a target
    assert {f"{PAUSE}.target", f"{FINAL_PAUSE}.target", f"{FINAL_PAUSE}.theta_bw", f"{PAUSE}.theta_fw"} <= set(names)
    # a [[tie]] of α holding the final pause with a speech phoneme decides: no second tie of it
    own = build_problem(s.with_options(ties=(Tie(phonemes=(FINAL_PAUSE, "i"), parameters=("alpha",)),)).estimation_settings(),
                        [v], "LA")
    assert f"{PAUSE}.alpha" in own.packing.names() and (last * N_PARAMS + k, first * N_PARAMS + k) not in own.packing.ties
    # α not free: nothing to tie
    fixed = build_problem(s.with_options(free=("target", "theta_bw", "theta_fw"), pooled=()).estimation_settings(), [v], "LA")
    assert not any(f == last * N_PARAMS + k for f, _ in fixed.packing.ties)


def test_a_posture_no_sample_shows_stays_the_pause() -> None:
    """The German EMA's final pauses lie where the recordings are NaN: a '#end' row fitted from them
    has no sample of its own (its target went to the bottom of its box, not identified). A final or
    medial pause row with no valid sample in any channel over the corpus stays '#', with a note;
    one utterance whose final pause is measured keeps the row for every utterance."""
    from coartic.model import Utterance, utterances_with_postures

    times = np.arange(0.0, 1.0, 0.01)

    def utt(name: str, measured_to: float) -> Utterance:
        y = np.where(times < measured_to, 20.0, np.nan)
        return Utterance(["#", "a", "#", "p", "a", "#"], [0.0, 0.2, 0.4, 0.55, 0.65, 0.8],
                         [0.2, 0.4, 0.55, 0.65, 0.8, 1.0], times, name, {"LA": y}, {"LA": np.isfinite(y)})

    blind = [utt("x", 0.5), utt("y", 0.75)]  # the medial pause (0.40-0.55) measured, no final pause
    out, notes = utterances_with_postures(blind)
    assert [u.labels for u in out] == [("#", "a", MEDIAL_PAUSE, "p", "a", PAUSE)] * 2
    assert any(f"no utterance-final pause has a valid sample in any channel: none is fitted as {FINAL_PAUSE!r}" in n
               for n in notes)
    assert not any("utterance-final pause(s) fitted as" in n for n in notes)
    assert [u.labels for u in utterances_with_postures(out)[0]] == [u.labels for u in out]  # twice: the same
    seen, notes = utterances_with_postures([utt("x", 0.5), utt("z", 1.0)])  # z's final pause is measured
    assert [u.labels[-1] for u in seen] == [FINAL_PAUSE, FINAL_PAUSE]
    assert not any("has a valid sample" in n for n in notes)
    none, _ = utterances_with_postures([utt("w", 0.3)])  # nothing measured after 0.3 s: neither row
    assert none[0].labels == ("#", "a", PAUSE, "p", "a", PAUSE)


def test_a_fit_gives_its_rmse_on_speech_beside_all_samples(tmp_path: Path) -> None:
    """In sample as held out, a pause's samples can outweigh the speech: before s1em's sentence
    (tests/data/realdata/emu-tinydfg91) 0.88 s of "pause" hold a breath, the lips moving between 15
    and 33 mm, which no pause posture follows. rmse.csv and the console give the speech alone too,
    the same figure `score` gives on the same samples; a pooled multi-start's line says its optima
    are the search's, before the empirical Bayes, and where the fit ended."""
    from typer.testing import CliRunner

    from coartic.cli import app

    bundle = ROOT / "tests/data/realdata/emu-tinydfg91/tinyDfg91/0000_ses/dfg91_s1em_0666_bndl/dfg91_s1em_0666"
    spec = tmp_path / "s1em.toml"
    spec.write_text(f'[corpus]\nfiles = ["{bundle}_annot.json"]\nlabels = ["{bundle}.MAU"]\nlabel_map = "german_sampa"\n'
                    '[model]\nchannels = ["LA"]\n[parameters]\nfree = ["target"]\ntarget_prior = "none"\n'
                    '[staging]\nenabled = false\n')
    out = tmp_path / "fit"
    res = CliRunner().invoke(app, ["fit", str(spec), "--starts", "1", "--no-report", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rows = {r.split(",")[1]: r.split(",") for r in (out / "rmse.csv").read_text().splitlines()[1:]}
    all_rmse, speech_rmse, speech_n = float(rows["all"][3]), float(rows["speech"][3]), int(rows["speech"][4])
    assert speech_rmse < all_rmse / 2 and 0 < speech_n < int(rows["all"][4])  # the breath before the sentence
    table = ParameterTable.load(out / "table.json")
    scored = score_recordings(table, [str(bundle) + "_annot.json"], labels=[str(bundle) + ".MAU"], channels=["LA"])
    row = scored.channel_rows()[0]
    assert speech_rmse == pytest.approx(row["rmse_speech_mm"], rel=1e-9) and speech_n == row["speech_samples"]
    assert all_rmse == pytest.approx(row["rmse_mm"], rel=1e-9)
    head = next(line for line in res.output.splitlines() if "┃ channel" in line)
    assert "speech" in head

    # the default's pooled dynamics with two starts: the line names the search's optima as such
    spec.write_text(spec.read_text().replace('free = ["target"]\ntarget_prior = "none"\n', ""))
    res = CliRunner().invoke(app, ["fit", str(spec), "--starts", "2", "--no-report", "--out", str(tmp_path / "pooled")])
    assert res.exit_code in (0, 3), res.output
    fitted = ParameterTable.load(tmp_path / "pooled" / "table.json").metadata["rmse"]["LA"]
    flat = " ".join(res.output.split())
    assert (f"these optima are the search's, at the pooling's starting sd: the empirical Bayes that followed ended "
            f"at data RMSE {fitted:.4f} mm") in flat
    summary = json.loads((tmp_path / "pooled" / "summary.json").read_text())["channels"]["LA"]
    assert summary["multistart"]["optima_before_pooling"] and summary["rmse_mm"] == pytest.approx(fitted)
    assert 0 < summary["rmse_speech_mm"] < summary["rmse_mm"]
