"""bench/real_data.py's core (``evaluate_cell``) on a tiny case, so the benchmark cannot rot: the
German EMA's jaw channel, targets only, both held-out schemes; what is scored is checked by hand.
And its second German speaker (tinyDfg91, s1em): the bundle read through the product, and the
split across speakers."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from coartic.fit import load_spec
from coartic.evaluation.baselines import Baselines
from coartic.fit.data import load_utterances
from coartic.io import load_trial
from coartic.io.emu import parse_ssff
from coartic.model import Utterance
from coartic.pauses import is_pause

ROOT = Path(__file__).resolve().parents[2]
S1EM = ROOT / "tests" / "data" / "realdata" / "emu-tinydfg91" / "tinyDfg91" / "0000_ses" / "dfg91_s1em_0666_bndl"


def bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("real_data", ROOT / "bench" / "real_data.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["real_data"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def rows_and_data() -> tuple[ModuleType, list[dict[str, object]], list[object]]:
    rd = bench()
    base = load_spec(ROOT / "fit" / "ema_german.toml").with_options(channels=("JO",))
    utts = load_utterances(base)
    rows = rd.evaluate_cell(base, utts, "modified", ("target",), "none", ("loo", "time"), starts=1)
    return rd, rows, utts


def test_one_row_per_split_and_channel(rows_and_data: tuple[ModuleType, list[dict[str, object]], list[object]]) -> None:
    _, rows, _ = rows_and_data
    assert [r["split"] for r in rows] == ["LOO 0020", "LOO 0024", "time split"]
    for r in rows:
        for key in ("table", "table_off", "constant", "constant_off", "step", "step_off", "in_sample"):
            assert math.isfinite(float(r[key])), (r["split"], key)  # type: ignore[arg-type]
        assert float(r["table_off"]) <= float(r["table"]) + 1e-12  # type: ignore[arg-type]
    # 0020 lacks /u v/ and their classes: the prediction of 0024 gives them the step model's fallback
    # (the training mean), says so, scores them not
    assert any("/u v/ (no fallback trained) predicted at the training mean" in n
               for n in rows[1]["notes"])  # type: ignore[attr-defined]
    # without each test utterance's last segment: fewer samples, every figure again
    assert all(0 < int(r["samples_nolast"]) < int(r["samples"]) for r in rows)  # type: ignore[call-overload]


def test_scored_samples_and_step_by_hand(rows_and_data: tuple[ModuleType, list[dict[str, object]], list[object]]) -> None:
    rd, rows, utts = rows_and_data
    train, held = utts[1], utts[0]  # "LOO 0020": fit 0024, predict 0020
    seen = set(train.labels)
    seg = held.sample_segments()
    keep = np.array([lab in seen and lab != "#" for lab in held.labels] + [False])[seg] & held.valid["JO"]
    r = rows[0]
    assert r["samples"] == int(keep.sum()) and 0 < int(keep.sum()) < held.times.size
    step = Baselines.fit([train], ["JO"]).step["JO"]
    pred = np.array([step[lab] if lab in step else np.nan for lab in held.labels] + [np.nan])[seg]
    by_hand = float(np.sqrt(np.mean((pred[keep] - held.observed["JO"][keep]) ** 2)))
    assert r["step"] == pytest.approx(by_hand, rel=1e-9)
    assert rd.pooled([r], "step") == pytest.approx(by_hand, rel=1e-9)


def test_summary_ranks_by_held_out_error() -> None:
    rd = bench()
    common = {"split": "s", "channel": "LA", "samples": 10, "in_sample": 0.1, "table_off": 1.0, "constant": 3.0,
              "constant_off": 3.0, "step": 2.0, "step_off": 2.0, "notes": []}
    rows = [{**common, "variant": "modified", "freedom": "tat", "reg": "none", "table": 2.5, "in_sample": 0.01},
            {**common, "variant": "original", "freedom": "tat", "reg": "none", "table": 1.5}]
    lines = rd.summary_lines(rows)
    assert lines[1].startswith("original")  # lower held-out error wins, whatever the in-sample error
    assert "1 of 1 in favour of the best" in lines[-1]


def test_cells_are_the_products_own_settings() -> None:
    """A cell sets the spec's own fields (what a spec file with them fits), whatever the base says."""
    rd = bench()
    # the base's own starts set (the test session's default is already 1, conftest): --starts 1 must win
    base = load_spec(ROOT / "fit" / "ema_german.toml").with_options(starts=32)
    s = rd.cell_spec(base, "rate-aware", rd.FREEDOM["t+shared"], "tprior:0.3", starts=1)
    assert (s.model.dominance, s.model.handover, s.parameters.free, s.parameters.shared, s.priors.target_prior,
            s.fit.starts) == (
        "plateau", True, ("target", "theta_bw", "theta_fw"), ("theta_bw", "theta_fw"), 0.3, 1)
    s = rd.cell_spec(base.with_options(dominance="plateau", handover=True), "modified", rd.FREEDOM["tat"], "none")
    assert (s.model.dominance, s.model.handover, s.parameters.shared, s.priors.target_prior) == ("centre", False, (), None)
    assert rd.tprior_sd("tprior-cv") == "cv" and rd.tprior_sd("tprior:x") is None and rd.tprior_sd("shrink") is None
    with pytest.raises(ValueError, match="unknown regularisation"):
        rd.cell_spec(base, "modified", rd.FREEDOM["tat"], "tprior:-1")


def test_merge_counts_a_cell_run_in_two_parts_once(tmp_path: Path) -> None:
    rd = bench()
    row = {"variant": "rate-aware", "freedom": "t+shared", "reg": "tprior:0.3", "unseen": "constant", "starts": 1,
           "theta0": 40.0, "channel": "LA", "samples": 10, "in_sample": 0.1, "table": 1.0, "table_off": 1.0,
           "constant": 3.0, "constant_off": 3.0, "step": 2.0, "step_off": 2.0, "notes": [], "status": "converged"}
    rows = [{**row, "split": s} for s in ("LOO a", "LOO b")]
    for name in ("a", "b"):
        (tmp_path / f"{name}.txt").write_text("part\n")
        (tmp_path / f"{name}.json").write_text(json.dumps(rows))
    rd.merge([tmp_path / "a.txt", tmp_path / "b.txt"], tmp_path / "m.txt")
    merged = json.loads((tmp_path / "m.json").read_text())
    assert len(merged) == 2 and " 2/2 2/2 " in (tmp_path / "m.txt").read_text()


def test_noise_units_and_paired_se_by_hand() -> None:
    """The noise of docs/REAL_DATA.md: each test utterance a unit (its SSE summed over segments and
    channels), compare's heldout_se over them, and the paired SE of a difference, by hand."""
    rd = bench()
    # two cells on the same three test utterances (one channel); segments [utt, i, phoneme, n, table, step, dSSE]
    seg_a = [["u1", 0, "a", 4, 1.0, 2.0, 0.0], ["u1", 1, "b", 4, 3.0, 2.0, 0.0], ["u2", 0, "a", 8, 2.0, 2.0, 0.0],
             ["u3", 0, "a", 4, 1.0, 3.0, 0.0]]
    seg_b = [[u, i, p, n, t + 0.5, s, d] for u, i, p, n, t, s, d in seg_a]
    units = rd.utterance_units([{"split": "rate", "channel": "LA", "segments": seg_a}])
    assert units == {("rate", "u1"): (4 * 1.0 + 4 * 9.0, 8), ("rate", "u2"): (32.0, 8), ("rate", "u3"): (4.0, 4)}
    assert rd.utterance_units([{"split": "rate", "channel": "LA", "segments": seg_a}], model="step")[("rate", "u3")] == (36.0, 4)
    e = np.array([40.0, 32.0, 4.0])
    n = np.array([8.0, 8.0, 4.0])
    m = e.sum() / n.sum()
    se = math.sqrt(3 / 2 * np.sum((e - m * n) ** 2)) / n.sum() / (2 * math.sqrt(m))
    assert rd.unit_se(units) == pytest.approx(se, rel=1e-12)
    other = rd.utterance_units([{"split": "rate", "channel": "LA", "segments": seg_b}])
    assert rd.paired_se(units, units) == 0.0
    eb = np.array([other[("rate", u)][0] for u in ("u1", "u2", "u3")])
    mb = eb.sum() / n.sum()
    d = (e - m * n) / (2 * math.sqrt(m) * n.sum()) - (eb - mb * n) / (2 * math.sqrt(mb) * n.sum())
    assert rd.paired_se(units, other) == pytest.approx(math.sqrt(3 / 2 * np.sum(d**2)), rel=1e-12)
    # only the units both score count; fewer than two: no SE
    assert math.isnan(rd.paired_se(units, {("rate", "u1"): other[("rate", "u1")]}))


def test_markdown_and_noise_lines_name_the_default_against_each_cell() -> None:
    rd = bench()
    common = {"variant": "rate-aware", "split": "rate", "channel": "LA", "unseen": "constant", "starts": 1, "theta0": 30.0,
              "samples": 12, "samples_all": 20, "in_sample": 0.1, "constant": 3.0, "constant_off": 3.0,
              "constant_all": 3.0, "constant_off_all": 3.0, "step": 2.0, "step_off": 2.0, "step_all": 2.0,
              "step_off_all": 2.0, "notes": []}
    segs = [["u1", 0, "a", 6, 1.0, 2.0, 0.0], ["u2", 0, "a", 6, 1.2, 2.0, 0.0]]
    rows = [{**common, "freedom": f, "reg": g, "table": t, "table_off": t, "table_all": t, "table_off_all": t,
             "segments": [[u, i, p, n, x * t, s, d] for u, i, p, n, x, s, d in segs]}
            for f, g, t in (("t+shared", "tprior:0.3", 1.5), ("pooled", "tprior-eb", 1.0), ("tat", "tprior:0.3", 1.2))]
    table = rd.markdown_lines(rows)
    assert table[0] == "| split | ch | shared | pooled (default) | per-phoneme | step | constant |"
    assert table[2].startswith("| rate | LA | 1.500 / 1.500 / 1.500 | 1.000 / 1.000 / 1.000 | 1.200 / 1.200 / 1.200 | 2.000 / 2.000 / 2.000")
    noise = rd.noise_lines(rows)
    assert noise[1].startswith("rate-aware  pooled ")  # lowest first
    against = [x for x in noise if x.startswith("  vs ")]
    assert [x.split(": ")[0] for x in against] == ["  vs rate-aware t+shared tprior:0.3", "  vs rate-aware tat tprior:0.3",
                                                   "  vs step model"]
    # every cell scales one pattern (RMSE 1.1, SE 0.1 over the two utterances), so each difference is
    # (t_a - t_b) times the first and its paired SE (t_a - t_b) times the second: lower, beyond one SE
    assert all(" lower" in x and "noise" not in x for x in against)


def test_the_tinydfg91_bundle_reads_through_the_product() -> None:
    """The copied emuDB bundle as fit/ema_s1em.toml reads it: its sensor tracks through the
    _annot.json, the MAUS phones of the .MAU mapped by german_sampa, the pauses as pauses."""
    trial = load_trial(S1EM / "dfg91_s1em_0666_annot.json", labels=S1EM / "dfg91_s1em_0666.MAU", label_map="german_sampa")
    assert {"ulip", "llip", "jaw"} <= set(trial.marker_names) and np.isfinite(trial.markers).all()
    ch = trial.channels(["LA", "JO"])
    assert ch.times.size == 612  # 3.06 s at 200 Hz
    for c in ("LA", "JO"):
        assert np.isfinite(ch[c]).all() and ch.valid[c].all(), c
    # our LA (the 3-D distance of the lip sensors) follows the lab's own lip-aperture track: the roles
    # guessed from the sensor names are the lips
    cols, rate, _ = parse_ssff((S1EM / "dfg91_s1em_0666.la").read_bytes(), "la")
    lab_la = cols["LipAp"][:, 0]
    assert rate == 200 and lab_la.size == 612
    assert np.corrcoef(lab_la, ch["LA"])[0, 1] > 0.995 and np.abs(lab_la - ch["LA"]).max() < 1.5
    # the .MAU's phones (its first entry, "H#" at 0 s, marks the start and is no segment), then the model's
    raw = ("<p:> m e l a n i: s ? o m i k kh a l I m i t i: 6 aI n l i: t <p:>").split()
    assert trial.meta["raw_labels"] == tuple(raw) and "H#" not in trial.segments.labels
    assert trial.segments.labels == tuple("# m e l a n i s ? o m i k k a l i m i t i a a n l i t #".split())
    assert trial.segments.starts[0] == 0.0 and trial.segments.ends[0] == pytest.approx(0.87994)
    # as the spec fits it (the default pause postures): the initial pause '#', the final one '#end',
    # and nothing else a pause
    (u,) = load_utterances(load_spec(ROOT / "fit" / "ema_s1em.toml"))
    assert [lab for lab in u.labels if is_pause(lab)] == ["#", "#end"]
    assert (u.labels[0], u.labels[-1]) == ("#", "#end")


@pytest.fixture(scope="module")
def speakers() -> list[Utterance]:
    return load_utterances(load_spec(ROOT / "fit" / "ema_speakers.toml").with_options(channels=("JO",)))


def test_the_speaker_split_fits_mo1_and_predicts_s1em(speakers: list[Utterance]) -> None:
    rd = bench()
    ((name, train, test),) = rd.splits(speakers, ("speaker",))
    assert name == "speaker s1em"
    assert [Path(u.meta["file"]).name for u in train] == ["dfgspp_mo1_prosody_0020_ema.csv", "dfgspp_mo1_prosody_0024_ema.csv"]
    assert [Path(u.meta["file"]).name for u in test] == ["dfg91_s1em_0666_annot.json"]
    assert {u.meta["speaker"] for u in train} == {"mo1"} and {u.meta["speaker"] for u in test} == {"s1em"}
    # the split is asked for by name; an utterance with no speaker cannot be placed
    assert all(not n.startswith("speaker") for n, _, _ in rd.splits(speakers, ("loo", "time")))
    nameless = [Utterance(u.labels, u.starts, u.ends, u.times, u.name, u.observed, u.valid, {"file": u.meta["file"]})
                for u in speakers]
    with pytest.raises(ValueError, match="no speaker"):
        rd.splits(nameless, ("speaker",))


def test_the_speaker_split_scores_s1em_against_mo1s_step_model(speakers: list[Utterance]) -> None:
    """What the speaker split scores, by hand: s1em's samples in segments of phonemes mo1's
    utterances have (pauses not), against the step model of mo1's phoneme means, offset removed."""
    rd = bench()
    base = load_spec(ROOT / "fit" / "ema_speakers.toml").with_options(channels=("JO",))
    (r,) = rd.evaluate_cell(base, speakers, "modified", ("target",), "none", ("speaker",), starts=1)
    train, held = speakers[:2], speakers[2]
    seen = {lab for u in train for lab in u.labels}
    seg = held.sample_segments()
    keep = np.array([lab in seen and not is_pause(lab) for lab in held.labels] + [False])[seg] & held.valid["JO"]
    assert r["split"] == "speaker s1em" and r["samples"] == int(keep.sum()) and 0 < int(keep.sum()) < held.times.size
    step = Baselines.fit(train, ["JO"]).step["JO"]
    pred = np.array([step.get(lab, np.nan) for lab in held.labels] + [np.nan])[seg]
    resid = pred[keep] - held.observed["JO"][keep]
    assert r["step"] == pytest.approx(float(np.sqrt(np.mean(resid**2))), rel=1e-9)
    assert r["step_off"] == pytest.approx(float(np.std(resid)), rel=1e-9)
    # the jaw sensors' origins differ by some 60 mm between the speakers: as measured, every model
    # is off by about that; with the offset removed, by millimetres
    assert r["step"] > 30 and r["step_off"] < 5 and r["table_off"] < 5


def test_one_test_utterance_gives_no_se_and_a_speaker_split_says_which_figure_counts() -> None:
    """A corpus of one test utterance (s1em's time split, the speaker split) has no SE: the noise
    section says "no SE", not "lower" or "HIGHER"; a split across speakers gets the note that the
    offset-removed figures are the ones to compare."""
    rd = bench()
    common = {"variant": "rate-aware", "channel": "JO", "unseen": "constant", "starts": 1, "theta0": 30.0,
              "samples": 6, "in_sample": 0.1, "constant": 60.0, "constant_off": 3.0, "step": 60.0, "step_off": 2.0,
              "notes": []}
    rows = [{**common, "split": "speaker s1em", "freedom": f, "reg": g, "table": 61.0, "table_off": t,
             "segments": [["0666", 0, "a", 6, 61.0, 60.0, 12.0]]}
            for f, g, t in (("t+shared", "tprior:0.3", 2.1), ("pooled", "tprior-eb", 2.4))]
    against = [x for x in rd.noise_lines(rows) if x.startswith("  vs ")]
    assert against and all("no SE" in x and "lower" not in x and "HIGHER" not in x for x in against)
    assert rd.speaker_note(rows) and "offset-removed" in rd.speaker_note(rows)[0]
    assert rd.speaker_note([{**r, "split": "time split"} for r in rows]) == []


def test_the_rate_splits_go_both_ways(speakers: list[Utterance]) -> None:
    rd = bench()
    rated = [Utterance(u.labels, u.starts, u.ends, u.times, f"u{k}", u.observed, u.valid,
                       {**u.meta, "rate": rate, "repetition": 1})
             for k, (u, rate) in enumerate(zip(speakers, ("normal", "fast", "normal")))]
    (_, train, test), (_, back_train, back_test) = rd.splits(rated, ("rate", "ratefast"))
    assert [u.name for u in train] == ["u0", "u2"] and [u.name for u in test] == ["u1"]
    assert [u.name for u in back_train] == ["u1"] and [u.name for u in back_test] == ["u0", "u2"]
    assert [n for n, _, _ in rd.splits(rated, ("rate", "ratefast"))] == ["rate", "rate fast"]
