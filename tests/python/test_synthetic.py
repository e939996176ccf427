"""The synthetic ELITE-style session (corpus-synthetic/): what it writes, and that it is right.

The channels are read back from the written C3D files through the project's readers
(``coartic.io.load_trial``), and compared with the noise-free model trajectories the generator
saved (``truth/*.npz``).
"""

from __future__ import annotations

import csv
import filecmp
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from typer.testing import CliRunner

from coartic import _core
from coartic.cli import app
from coartic.io import load_trial, read_labels
from coartic.synthetic_cli import corpus_dir, load_generator
from coartic.table import CHANNELS, PARAMETERS, TONGUE_CHANNELS, ParameterTable

from conftest import without_overview

F64 = npt.NDArray[np.float64]


@pytest.fixture(scope="module")
def gen() -> ModuleType:
    return load_generator()


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory, gen: ModuleType) -> Path:
    out = tmp_path_factory.mktemp("session")
    gen.generate(out, quick=True, progress=False)
    return out


@pytest.fixture(scope="module")
def manifest(session: Path) -> list[dict[str, str]]:
    with open(session / "manifest.csv", newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def settings(gen: ModuleType) -> dict[str, Any]:
    return dict(gen.load_settings())


@pytest.fixture
def no_overview() -> Iterator[None]:
    """Sessions written without their overview figure (conftest.without_overview) for the tests of
    determinism, staging and interruptions, which never look at it, and the gesture and Italian
    flavours': the module session draws it (plot_overview reads the written C3D files back whatever
    the flavour, which only names the title); each more drew 2.3 of a flavour test's 3.2 CPU-s."""
    with without_overview():
        yield


def truth(session: Path, row: dict[str, str]) -> dict[str, Any]:
    with np.load(session / row["truth"]) as z:
        return {k: z[k] for k in z.files}


def rows_of(manifest: list[dict[str, str]], **kv: str) -> Iterator[dict[str, str]]:
    return (r for r in manifest if all(r[k] == v for k, v in kv.items()))


# ----------------------------------------------------------------------------- the session


def test_manifest_lists_every_trial_once_with_its_files(
    session: Path, manifest: list[dict[str, str]], settings: dict[str, Any]
) -> None:
    reps = settings["quick_repetitions"]
    expected = {
        (v, c, rate, str(rep))
        for v in ("i", "a", "u")
        for c in "p b m f v t d n l r s z ts dz tS dZ S k g J L".split()
        for rate in ("normal", "fast")
        for rep in range(1, reps + 1)
    }
    got = [(r["vowel"], r["consonant"], r["rate"], r["repetition"]) for r in manifest]
    assert len(got) == len(set(got)) == len(expected) == 21 * 3 * 2 * reps
    assert set(got) == expected
    assert list(manifest[0])[:7] == ["file", "labels", "stimulus", "vowel", "consonant", "repetition", "rate"]
    for r in manifest:
        assert r["stimulus"] == f"{r['vowel']} {r['consonant']} {r['vowel']}"
        for col in ("file", "labels", "csv", "lab", "truth"):
            assert (session / r[col]).is_file(), (col, r[col])
    # Distinct even on a case-insensitive file system (S/s, L/l).
    assert len({r["file"].lower() for r in manifest}) == len(manifest)
    assert (session / "ground_truth.json").read_bytes() == (corpus_dir() / "ground_truth.json").read_bytes()


def test_same_seed_same_files_other_seed_other_data(
    session: Path, gen: ModuleType, tmp_path: Path, settings: dict[str, Any], manifest: list[dict[str, str]],
    no_overview: None,
) -> None:
    # The /p/ and /S/ trials again (24 of 252; the whole session's second generation was two thirds
    # of this file's CPU time): each trial draws from its own random stream, so a rerun must give
    # their files bit for bit, and the same manifest rows. Any non-determinism (an unseeded draw, a
    # stream shared across trials, an order that changes) differs here as it would over the session.
    again = tmp_path / "again"
    gen.generate(again, quick=True, progress=False, consonants=["p", "S"])
    with open(again / "manifest.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert rows == [r for r in manifest if r["consonant"] in ("p", "S")] and len(rows) == 2 * 3 * 2 * 2
    for sub in ("c3d", "csv", "labels", "truth"):
        names = sorted(p.name for p in (again / sub).iterdir() if p.is_file())
        assert len(names) == len(rows) * (2 if sub == "labels" else 1), sub  # no file left out
        match, mismatch, errors = filecmp.cmpfiles(session / sub, again / sub, names, shallow=False)
        assert not mismatch and not errors, (sub, mismatch[:3], errors[:3])
    for name in ("ground_truth.json", "session.toml"):
        assert filecmp.cmp(session / name, again / name, shallow=False), name
    plan = gen.plan_trials(settings, quick=True)[0]
    table = ParameterTable.load(corpus_dir() / "ground_truth.json")
    a = gen.make_trial(settings, table, plan, 1, 630)
    b = gen.make_trial(settings, table, plan, 2, 630)
    assert not np.allclose(a.markers[:10], b.markers[:10], equal_nan=True)
    assert not np.array_equal(a.ends, b.ends)


def test_rerun_into_an_earlier_session_replaces_it_and_refuses_foreign_directories(
    tmp_path: Path,
) -> None:
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    result = CliRunner().invoke(app, ["corpus", "synth", str(foreign), "--quick"])
    assert result.exit_code == 2
    said = " ".join(result.output.split())
    assert str(foreign) in said.replace(" ", "") or str(foreign) in said
    assert "no coartic run wrote" in said
    assert (foreign / "thesis.tex").read_text() == "precious"


def test_corpus_synth_is_staged_marked_and_refuses_another_sessions_directory(
    tmp_path: Path, gen: ModuleType, monkeypatch: pytest.MonkeyPatch, no_overview: None
) -> None:
    # What is tested is the command's staging, marking and refusals, which do not depend on how many
    # trials it writes: the command generates the /p/ trials only (12 of the quick session's 252, a
    # tenth of the CPU time; the whole session's generation is tested above).
    original_generate = gen.generate
    monkeypatch.setattr(gen, "generate", lambda *a, **k: original_generate(*a, **k, consonants=["p"]))
    out = tmp_path / "s"
    args = ["corpus", "synth", str(out), "--quick", "--seed", "7"]
    assert CliRunner().invoke(app, args).exit_code == 0
    assert len((out / "manifest.csv").read_text().splitlines()) == 1 + 3 * 2 * 2  # /p/ only: the stand-in worked
    marker = json.loads((out / "coartic_run.json").read_text())
    assert marker["command"] == "corpus synth" and marker["identity"]["seed"] == 7
    first = (out / "manifest.csv").read_bytes()
    assert CliRunner().invoke(app, args).exit_code == 0  # the same session again: replaced
    assert (out / "manifest.csv").read_bytes() == first
    other = CliRunner().invoke(app, ["corpus", "synth", str(out), "--quick", "--seed", "8"])
    assert other.exit_code == 2 and "--force" in other.output  # another seed: refused, nothing mixed
    assert (out / "manifest.csv").read_bytes() == first
    # Ctrl-C half-way: the previous session stays whole, and no staging directory is left behind
    calls = {"n": 0}
    original = gen.write_truth

    def write_then_stop(path: Path, trial: Any) -> None:
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        original(path, trial)

    monkeypatch.setattr(gen, "write_truth", write_then_stop)
    stopped = CliRunner().invoke(app, ["corpus", "synth", str(out), "--quick", "--seed", "8", "--force"])
    assert stopped.exit_code != 0 and calls["n"] == 3
    assert (out / "manifest.csv").read_bytes() == first
    assert json.loads((out / "coartic_run.json").read_text())["identity"]["seed"] == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]
    monkeypatch.setattr(gen, "write_truth", original)
    forced = CliRunner().invoke(app, ["corpus", "synth", str(out), "--quick", "--seed", "8", "--force"])
    assert forced.exit_code == 0 and (out / "manifest.csv").read_bytes() != first


def test_demo_writes_its_outputs_whole_and_refuses_a_foreign_directory(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    assert CliRunner().invoke(app, ["demo", "--out", str(out)]).exit_code == 0
    assert {"demo.png", "table.json", "reached.json", "coartic_run.json"} <= {p.name for p in out.iterdir()}
    assert CliRunner().invoke(app, ["demo", "--out", str(out)]).exit_code == 0  # its own output: replaced
    foreign = tmp_path / "thesis"
    foreign.mkdir()
    (foreign / "chapter.tex").write_text("precious")
    refused = CliRunner().invoke(app, ["demo", "--out", str(foreign)])
    assert refused.exit_code == 2 and "--force" in refused.output
    assert [p.name for p in foreign.iterdir()] == ["chapter.tex"]


def test_an_interrupted_run_is_replaced_by_the_next(
    gen: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_overview: None
) -> None:
    out = tmp_path / "s"
    original = gen.write_truth
    calls = {"n": 0}

    def write_then_stop(path: Path, trial: Any) -> None:
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the session
        original(path, trial)

    with monkeypatch.context() as mp:
        mp.setattr(gen, "write_truth", write_then_stop)
        with pytest.raises(KeyboardInterrupt):
            gen.generate(out, quick=True, progress=False, consonants=["p"])
    assert not (out / "manifest.csv").exists()  # an interrupted run is recognisable
    gen.generate(out, quick=True, progress=False, consonants=["p"])
    with open(out / "manifest.csv", newline="", encoding="utf-8") as fh:
        assert len(list(csv.DictReader(fh))) == 3 * 2 * 2
    with pytest.raises(ValueError, match="non-negative"):
        gen.generate(out, seed=-1, quick=True, progress=False, consonants=["p"])


def test_durations_are_realistic_and_fast_is_about_40_percent_shorter(
    session: Path, manifest: list[dict[str, str]]
) -> None:
    vcv: dict[tuple[str, str], list[float]] = {}
    for r in manifest:
        t = truth(session, r)
        d = t["ends"] - t["starts"]
        assert list(t["labels"]) == ["#", r["vowel"], r["consonant"], r["vowel"], "#"]
        assert 0.25 <= d[0] <= 0.5 and 0.25 <= d[4] <= 0.4, d
        if r["rate"] == "normal":
            assert all(0.10 <= x <= 0.19 for x in (d[1], d[3])), d
            assert 0.06 <= d[2] <= 0.16, d
        vcv.setdefault((r["stimulus"], r["rate"]), []).append(float(d[1:4].sum()))
    ratios = [np.mean(vcv[(s, "fast")]) / np.mean(vcv[(s, "normal")]) for s, rate in vcv if rate == "normal"]
    assert 0.5 < float(np.mean(ratios)) < 0.7


# ----------------------------------------------------------------------------- markers


def expected_noise(head_markers: F64, sigma: float, rest: npt.NDArray[np.bool_]) -> F64:
    """RMS per channel that isotropic marker noise of ``sigma`` gives through MODEL.md §6."""
    rng = np.random.default_rng(0)
    clean = np.asarray(_core.marker_channels(np.ascontiguousarray(head_markers), rest))
    diffs = []
    for _ in range(20):
        noisy = head_markers + rng.normal(0.0, sigma, head_markers.shape)
        diffs.append(np.asarray(_core.marker_channels(np.ascontiguousarray(noisy), rest)) - clean)
    return np.sqrt(np.mean(np.concatenate(diffs) ** 2, axis=0))[:6]


def check_channels_within_noise(session: Path, rows: list[dict[str, str]], sigma: float) -> None:
    """The channels read back from the C3D files are the truth plus noise: right level, no bias."""
    residuals: dict[str, list[F64]] = {ch: [] for ch in CHANNELS}
    expected: list[F64] = []
    moved = []
    for r in rows:
        t = truth(session, r)
        trial = load_trial(session / r["file"], labels=session / r["labels"])
        got = trial.channels()
        rest = trial.rest_frames()
        # y_0 is the first pause's mean lip height: where the lips have started to move before the
        # pause ends, ULO and LLO shift by that mean; take it from the truth over the same frames.
        m = float(np.mean(t["ULO"][rest] - t["LLO"][rest]) / 2.0)
        shift = {"ULO": -m, "LLO": m}
        ok = ~t["dropout_mask"].any(axis=1)
        for ch in CHANNELS:
            residuals[ch].append((got[ch] - (t[ch] + shift.get(ch, 0.0)))[ok])
        expected.append(expected_noise(t["head_markers"], sigma, rest))
        nose = trial.markers[:, 0]
        moved.append(np.nanmax(np.linalg.norm(nose - np.nanmean(nose, axis=0), axis=1)))
    exp = np.mean(expected, axis=0)
    for k, ch in enumerate(CHANNELS):
        res = np.concatenate(residuals[ch])
        rms = float(np.sqrt(np.mean(res**2)))
        assert 0.8 * exp[k] < rms < 1.25 * exp[k], (ch, rms, exp[k])
        assert abs(float(np.mean(res))) < 0.01, (ch, float(np.mean(res)))
    # The head really moves in the lab (so the head frame has work to do), by a few mm.
    assert 1.0 < float(np.median(moved)) < 15.0


def test_channels_from_the_written_markers_match_the_model_within_the_noise(
    session: Path, manifest: list[dict[str, str]], settings: dict[str, Any]
) -> None:
    check_channels_within_noise(session, manifest[::3], settings["noise"]["sigma_mm"])


def test_rest_is_exact_in_the_first_half_of_the_first_pause(
    session: Path, manifest: list[dict[str, str]]
) -> None:
    worst = []
    for r in manifest:
        t = truth(session, r)
        first_half = t["times"] <= (t["starts"][0] + t["ends"][0]) / 2.0
        assert np.all(t["ULO"][first_half] == 0.0) and np.all(t["LLO"][first_half] == 0.0)
        whole = (t["times"] >= t["starts"][0]) & (t["times"] <= t["ends"][0])
        worst.append(abs(float(np.mean(t["ULO"][whole] - t["LLO"][whole]) / 2.0)))
        assert abs(worst[-1] - abs(float(r["y0_offset_mm"]))) < 1e-4
    # Over the whole first pause the anticipation of the first vowel moves y_0 a little.
    assert max(worst) < 0.2


def test_c3d_and_csv_hold_nan_exactly_at_the_dropouts(
    session: Path, manifest: list[dict[str, str]], settings: dict[str, Any]
) -> None:
    lo, hi = settings["noise"]["dropout_frames"]
    with_gaps = 0
    for r in manifest:
        t = truth(session, r)
        mask = t["dropout_mask"]
        if not mask.any():
            continue
        with_gaps += 1
        for key in ("file", "csv"):
            trial = load_trial(session / r[key])
            assert np.array_equal(np.isnan(trial.markers).any(axis=2), mask), (r[key])
            assert np.array_equal(np.isnan(trial.markers).all(axis=2), mask), (r[key])
        for m in range(mask.shape[1]):
            runs = np.diff(np.concatenate([[0], mask[:, m].astype(int), [0]]))
            lengths = np.flatnonzero(runs == -1) - np.flatnonzero(runs == 1)
            assert all(lengths >= lo), lengths  # runs may touch and merge: no upper check
    # A few per marker per session: some trials have gaps, most do not.
    assert 0 < with_gaps < len(manifest) / 2


def test_c3d_header_rate_units_and_residuals(session: Path, manifest: list[dict[str, str]]) -> None:
    import ezc3d

    r = next(r for r in manifest if int(r["dropout_frames"]) > 0)
    c = ezc3d.c3d(str(session / r["file"]))
    point = c["parameters"]["POINT"]
    assert list(point["LABELS"]["value"]) == ["NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN"]
    assert point["RATE"]["value"][0] == 100.0 and point["UNITS"]["value"] == ["mm"]
    res = c["data"]["meta_points"]["residuals"][0]  # [marker, frame]
    mask = truth(session, r)["dropout_mask"].T
    assert np.all(res[mask] < 0) and np.all(res[~mask] >= 0)


def test_labels_round_trip_through_textgrid_and_htk(session: Path, manifest: list[dict[str, str]]) -> None:
    for r in manifest[::7]:
        t = truth(session, r)
        for key in ("labels", "lab"):
            seg = load_trial(session / r["file"], labels=session / r[key]).segments
            assert seg is not None
            assert list(seg.labels) == list(t["labels"]), r[key]
            assert np.array_equal(seg.starts, t["starts"]) and np.array_equal(seg.ends, t["ends"]), r[key]
        raw = read_labels(session / r["lab"])
        assert raw.labels[0] == raw.labels[-1] == "sil"  # pauses spelled as aligners do
        assert abs(t["ends"][-1] - t["times"][-1]) < 1e-9  # the labels end on the last frame


# ----------------------------------------------------------------------------- ground truth


def test_ground_truth_is_valid_complete_and_reasoned(gen: ModuleType) -> None:
    table = ParameterTable.load(corpus_dir() / "ground_truth.json")
    phonemes = ["#", "i", "a", "u", *"p b m f v t d n l r s z ts dz tS dZ S k g J L".split()]
    assert sorted(table.phonemes) == sorted(phonemes)
    assert table.variant == "modified"
    for ch in CHANNELS:
        cs = table.channels[ch]
        assert (cs.reference_phoneme, cs.beta, cs.edge_extent, cs.apex_fraction, cs.unit) == ("a", 1.0, 1.0, 0.5, "mm")
    for ph in phonemes:
        for ch in CHANNELS:
            v = table.values[ph][ch]
            for p in PARAMETERS:
                why = table.reasons[ph][ch][p]
                assert isinstance(why, str) and len(why) > 15, (ph, ch, p)
            assert 0.5 <= v["alpha"] <= 3.0 and 5.0 <= v["theta_bw"] <= 80.0 and 5.0 <= v["theta_fw"] <= 80.0
            assert 0.8 <= v["c_bw"] <= 2.0 and 0.8 <= v["c_fw"] <= 2.0
            assert 200.0 <= v["psi"] <= 2000.0 and abs(v["delta"]) <= 0.08
    # The committed JSON is what ground_truth.py builds (no hand edits drifting from the rules).
    assert json.loads((corpus_dir() / "ground_truth.json").read_text()) == json.loads(
        json.dumps(_build_ground_truth().to_json_dict())
    )


def _build_ground_truth(italian: bool = False) -> ParameterTable:
    import importlib.util

    spec = importlib.util.spec_from_file_location("coartic_gt_rules", corpus_dir() / "ground_truth.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    table: ParameterTable = mod.build(mod.ITALIAN_VOWELS) if italian else mod.build()
    return table


def test_ground_truth_phonetics() -> None:
    v = ParameterTable.load(corpus_dir() / "ground_truth.json").values
    T = {ph: {ch: v[ph][ch]["target"] for ch in CHANNELS} for ph in v}
    for ch in ("ULO", "LLO", "JO"):
        assert T["a"][ch] > T["i"][ch] > T["u"][ch], ch  # open /a/ > /i/ > /u/
    assert T["u"]["ULP"] > T["#"]["ULP"] and T["u"]["LR"] < T["#"]["LR"] < T["i"]["LR"]
    for c in ("S", "tS", "dZ"):
        assert T[c]["ULP"] - T["#"]["ULP"] >= 2.0 and T[c]["LLP"] - T["#"]["LLP"] >= 2.0
    for c in ("f", "v"):
        assert T[c]["LLP"] < T["#"]["LLP"] - 2.0 and T[c]["LLO"] < 0.0
        assert v[c]["LLO"]["k_r"] == v[c]["LLP"]["k_r"] == 1.0
    for c in ("p", "b", "m"):
        assert v[c]["ULO"]["k_r"] == v[c]["LLO"]["k_r"] == 1.0
        assert max(v[c][ch]["k_r"] for ch in ("ULP", "LLP", "LR", "JO")) < 1.0
    assert all(v["#"][ch]["target"] == 0.0 for ch in ("ULO", "LLO"))
    assert 45.0 <= min(T[p]["LR"] for p in T) and max(T[p]["LR"] for p in T) <= 55.0
    assert 110.0 <= min(T[p]["JO"] for p in T) and max(T[p]["JO"] for p in T) <= 125.0


def check_closures(session: Path, rows: list[dict[str, str]], settings: dict[str, Any], margin: float) -> int:
    """Every /p b m/ presses the lips together by ``margin`` mm (truth; measured within the noise),
    /f v/ leave them open; returns the number of trials checked."""
    gap = settings["geometry"]["rest_gap"]
    sigma = settings["noise"]["sigma_mm"]
    checked = 0
    for r in rows:
        c = r["consonant"]
        if c not in ("p", "b", "m", "f", "v"):
            continue
        checked += 1
        t = truth(session, r)
        inside = (t["times"] >= t["starts"][2]) & (t["times"] <= t["ends"][2])
        aperture = t["ULO"] + t["LLO"] + gap
        got = load_trial(session / r["file"], labels=session / r["labels"]).channels()
        measured = got["ULO"] + got["LLO"] + gap
        if c in ("p", "b", "m"):
            assert aperture[inside].min() < -margin, (r["file"], aperture[inside].min())
            assert np.nanmin(measured[inside]) < -margin + 4 * sigma, r["file"]
        else:
            assert aperture[inside].min() > 0.2, (r["file"], aperture[inside].min())
    return checked


def test_bilabials_close_the_lips_and_labiodentals_do_not(
    session: Path, manifest: list[dict[str, str]], settings: dict[str, Any]
) -> None:
    # k_R = 1: the model reaches the bilabial targets (about -4.5 mm of compression) at any rate.
    assert check_closures(session, manifest, settings, margin=1.0) == 5 * 3 * 2 * settings["quick_repetitions"]


# ----------------------------------------------------------------------------- second flavour


def test_gesture_flavour_is_other_data_with_the_same_guarantees(
    tmp_path: Path, gen: ModuleType, session: Path, manifest: list[dict[str, str]], settings: dict[str, Any],
    no_overview: None,
) -> None:
    out = tmp_path / "gestures"
    gen.generate(out, quick=True, progress=False, flavour="gestures", consonants=["p", "m", "f", "S"])
    with open(out / "manifest.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["consonant"] for r in rows} == {"p", "m", "f", "S"} and len(rows) == 4 * 3 * 2 * 2
    assert json.loads((out / "session.json").read_text())["flavour"] == "gestures"
    check_channels_within_noise(out, rows[::2], settings["noise"]["sigma_mm"])
    # Gestures undershoot in short segments, but the stiff bilabial gesture still closes the lips.
    assert check_closures(out, rows, settings, margin=0.5) == 3 * 3 * 2 * 2
    # Same segments and noise draws as the model flavour, but other trajectories.
    model_rows = {r["file"]: r for r in manifest}
    diffs = []
    for r in rows:
        g, m = truth(out, r), truth(session, model_rows[r["file"]])
        assert np.array_equal(g["ends"], m["ends"])
        diffs.append(np.sqrt(np.mean((g["LLO"] - m["LLO"]) ** 2)))
    assert float(np.median(diffs)) > 0.3


def test_bad_settings_name_the_file_and_the_setting(gen: ModuleType, tmp_path: Path) -> None:
    text = (corpus_dir() / "session.toml").read_text()
    broken = tmp_path / "session.toml"
    broken.write_text(text.replace("[noise]", "[noise_]"))
    with pytest.raises(ValueError, match=rf"{broken}: missing setting 'noise'"):
        gen.load_settings(broken)
    broken.write_text(text.replace("L = 0.140", ""))
    with pytest.raises(ValueError, match=r"\[durations.consonant\] has no duration for consonant 'L'"):
        gen.load_settings(broken)
    broken.write_text(text.replace("seed = ", "seed == "))
    with pytest.raises(ValueError, match=rf"{broken}: invalid TOML"):
        gen.load_settings(broken)


def test_bad_flavour_or_consonant_is_refused_before_writing(gen: ModuleType, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown flavour 'spline'"):
        gen.generate(tmp_path / "a", quick=True, progress=False, flavour="spline")
    with pytest.raises(ValueError, match=r"consonant\(s\) \['x'\]"):
        gen.generate(tmp_path / "b", quick=True, progress=False, consonants=["p", "x"])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


# ----------------------------------------------------------------------------- Italian flavour

ITALIAN_VOWELS = ("i", "e", "E", "a", "O", "o", "u")


@pytest.fixture(scope="module")
def italian(tmp_path_factory: pytest.TempPathFactory, gen: ModuleType) -> tuple[Path, list[dict[str, str]]]:
    out = tmp_path_factory.mktemp("italian")
    with without_overview():  # the module session draws the figure (no_overview)
        gen.generate(out, quick=True, progress=False, flavour="italian", consonants=["p", "f"])
    with open(out / "manifest.csv", newline="", encoding="utf-8") as fh:
        return out, list(csv.DictReader(fh))


def test_italian_flavour_has_every_vowel_in_vcv_cv_and_vc(
    italian: tuple[Path, list[dict[str, str]]], settings: dict[str, Any]
) -> None:
    out, rows = italian
    assert json.loads((out / "session.json").read_text())["flavour"] == "italian"
    assert settings["italian"]["consonants"] == [*settings["consonants"], "j", "w"]
    assert len(rows) == 3 * 7 * 2 * 2 * settings["italian"]["quick_repetitions"]
    assert {r["vowel"] for r in rows} == set(ITALIAN_VOWELS)
    # file names stay distinct where case is not (E/e, O/o): lower-case ASCII spellings
    names = [Path(r["file"]).stem for r in rows]
    assert len({n.lower() for n in names}) == len(rows) and all(n == n.lower() for n in names)
    for r in rows:
        labels = read_labels(out / r["labels"]).labels
        v, c = r["vowel"], r["consonant"]
        expected = {"VCV": ("sil", v, c, v, "sil"), "CV": ("sil", c, v, "sil"), "VC": ("sil", v, c, "sil")}[r["context"]]
        assert labels == expected and r["stimulus"] == " ".join(expected[1:-1]), r["file"]
    assert {r["file"] for r in rows if r["stimulus"] == "E p E"} == {"c3d/ehpeh_normal_01.c3d", "c3d/ehpeh_fast_01.c3d"}
    assert filecmp.cmp(out / "ground_truth.json", corpus_dir() / "ground_truth_italian.json", shallow=False)
    # the channels read back are the model's with the Italian truth, within the noise
    check_channels_within_noise(out, rows[::6], settings["noise"]["sigma_mm"])


def test_italian_flavour_writes_the_tongue_as_ema(
    italian: tuple[Path, list[dict[str, str]]], settings: dict[str, Any]
) -> None:
    """Each trial again as an EMA CSV (the manifest's `ema` column): read through coartic.io as EMA
    sensors, its tongue channels are the truth's within the sensor noise."""
    out, rows = italian
    sigma = settings["ema"]["sigma_mm"]
    for r in rows[::5]:
        trial = load_trial(out / r["ema"], out / r["labels"])
        assert trial.kind == "ema" and not [n for n in trial.meta["notes"] if "look wrong" in n]
        got = trial.channels(list(TONGUE_CHANNELS))
        t = truth(out, r)
        for ch in TONGUE_CHANNELS:
            err = got[ch] - t[ch]
            # the rest (the first half of the pause) is averaged from noisy samples: its error adds a little
            assert float(np.sqrt(np.mean(err**2))) < 1.6 * sigma and abs(float(np.mean(err))) < 0.1, (r["ema"], ch)
    k = next(r for r in rows if r["stimulus"] == "a p a" and r["rate"] == "normal")
    assert truth(out, k)["TTH"].min() < -8.0  # the tongue lowers with the jaw at /a/


def test_changed_channels_finds_the_channels_whose_data_differ(
    italian: tuple[Path, list[dict[str, str]]], tmp_path: Path
) -> None:
    """fit/changed_channels.py compares two sessions channel by channel, bit for bit: a copy is
    unchanged; moving one lip corner in one trial changes LR there and nothing else."""
    import shutil

    sys.path.insert(0, str(corpus_dir().parent / "fit"))
    import changed_channels

    out, rows = italian
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    same = changed_channels.compare(out, copy)
    assert same["changed"] == [] and same["trials"] == len(rows)
    import ezc3d

    name = rows[3]["file"]
    c = ezc3d.c3d(str(copy / name))
    labels = c["parameters"]["POINT"]["LABELS"]["value"]
    pts = c["data"]["points"]
    pts[0, labels.index("LC_L"), 40] += 0.5
    c["data"]["points"] = pts
    c.write(str(copy / name))
    moved = changed_channels.compare(out, copy)
    assert moved["changed"] == ["LR"] and moved["trials_changed"]["LR"] == 1, moved
    (copy / rows[0]["labels"]).write_text((copy / rows[0]["labels"]).read_text().replace("sil", "#", 1))
    assert changed_channels.compare(out, copy)["changed"] == list(CHANNELS)


def test_italian_flavour_closes_the_lips_in_every_context(italian: tuple[Path, list[dict[str, str]]]) -> None:
    out, rows = italian
    checked = 0
    for r in rows:
        if r["consonant"] not in ("p", "f"):
            continue
        t = truth(out, r)
        k = list(t["labels"]).index(r["consonant"])
        inside = (t["times"] >= t["starts"][k]) & (t["times"] <= t["ends"][k])
        aperture = t["ULO"] + t["LLO"] + 1.0
        if r["consonant"] == "p":
            assert aperture[inside].min() < -1.0, r["file"]  # k_R = 1: closed in CV and VC too, at any rate
        else:
            assert aperture[inside].min() > 0.2, r["file"]
        checked += 1
    assert checked == 2 * 3 * 7 * 2


def test_italian_ground_truth_is_reasoned_and_follows_the_literature() -> None:
    table = ParameterTable.load(corpus_dir() / "ground_truth_italian.json")
    phonemes = ["#", *ITALIAN_VOWELS, *"p b m f v t d n l r s z ts dz tS dZ S k g J L j w".split()]
    assert sorted(table.phonemes) == sorted(phonemes)
    assert tuple(table.channels) == CHANNELS + TONGUE_CHANNELS
    for ph in phonemes:
        for ch in table.channels:
            for p in PARAMETERS:
                assert len(table.reasons[ph][ch][p]) > 15, (ph, ch, p)
    for source in ("Magno Caldognetto", "Fromkin", "Farnetani 1990", "Recasens"):
        assert source in table.metadata["literature"], source
    assert json.loads((corpus_dir() / "ground_truth_italian.json").read_text()) == json.loads(
        json.dumps(_build_ground_truth(italian=True).to_json_dict()))
    # the default session's phonemes keep their lip and jaw values (the flavours share every rule),
    # except the width of the rounded sounds, which the Italian flavour narrows (ITALIAN_LR)
    default = ParameterTable.load(corpus_dir() / "ground_truth.json")
    rounded = {"u", "S", "tS", "dZ"}
    for ph in default.phonemes:
        for ch in CHANNELS:
            mine = dict(table.values[ph][ch])
            if ph in rounded and ch == "LR":
                assert mine.pop("target") < default.values[ph][ch]["target"] - 0.9, ph
                assert mine == {k: v for k, v in default.values[ph][ch].items() if k != "target"}, ph
            else:
                assert mine == default.values[ph][ch], (ph, ch)
    T = {ph: {ch: table.values[ph][ch]["target"] for ch in table.channels} for ph in phonemes}
    # rounding: /u/ at most 80 % of the rest width (the face shows it from the front: test_view.py)
    assert T["u"]["LR"] <= 0.8 * T["#"]["LR"] and T["w"]["LR"] < T["u"]["LR"] < T["o"]["LR"] < T["O"]["LR"]
    assert all(T[c]["LR"] < T["#"]["LR"] - 4 for c in ("S", "tS", "dZ"))
    # the tongue: the tip highest at the dental and alveolar contacts, the body at the velar and
    # palatal ones (k_R = 1 there), both lowest at /a/; the body forwards at /i/, back at /u/
    tip = sorted(phonemes, key=lambda p: -T[p]["TTH"])[:6]
    assert set(tip) <= {"t", "d", "n", "l", "ts", "dz"}, tip
    body = sorted(phonemes, key=lambda p: -T[p]["TBH"])[:6]
    assert set(body) <= {"k", "g", "J", "L", "j", "i"}, body
    assert min(phonemes, key=lambda p: T[p]["TTH"]) == "a" and min(phonemes, key=lambda p: T[p]["TBH"]) == "a"
    assert T["i"]["TBA"] > T["a"]["TBA"] > T["u"]["TBA"]
    for ph, ch in (("t", "TTH"), ("d", "TTH"), ("n", "TTH"), ("k", "TBH"), ("g", "TBH"), ("J", "TBH"), ("L", "TBH")):
        assert table.values[ph][ch]["k_r"] == 1.0 and table.values[ph][ch]["alpha"] >= 2.0, (ph, ch)
    assert all(T["#"][ch] == 0.0 for ch in TONGUE_CHANNELS)
    order = lambda ch: sorted(ITALIAN_VOWELS, key=lambda v: -T[v][ch])  # noqa: E731
    assert order("LLO") == ["a", "E", "O", "e", "o", "i", "u"]  # lip opening (Magno Caldognetto et al.)
    assert order("LR") == ["i", "e", "E", "a", "O", "o", "u"]  # mouth width: spread to rounded
    assert order("JO") == ["a", "E", "O", "e", "o", "i", "u"]  # jaw opening grows with openness
    assert T["u"]["ULP"] > T["o"]["ULP"] > T["O"]["ULP"] > T["#"]["ULP"] > T["E"]["ULP"] > T["e"]["ULP"] > T["i"]["ULP"]
    assert T["w"]["LR"] < T["u"]["LR"] and T["j"]["LR"] > T["#"]["LR"]
    # rounding dominates the lip-shape channels, graded /u/ > /o/ > /O/, anticipated likewise
    for ch in ("ULP", "LLP", "LR"):
        a = {v: table.values[v][ch]["alpha"] for v in ("u", "o", "O")}
        assert a["u"] > a["o"] > a["O"] > 1.0
        assert table.values["u"][ch]["delta"] < table.values["o"][ch]["delta"] < table.values["O"][ch]["delta"] < 0


def test_italian_flavour_refuses_consonants_it_lacks(gen: ModuleType, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"consonant\(s\) \['h'\]"):
        gen.generate(tmp_path / "a", quick=True, progress=False, flavour="italian", consonants=["p", "h"])
    with pytest.raises(ValueError, match=r"consonant\(s\) \['j'\]"):  # the default session has no glides
        gen.generate(tmp_path / "b", quick=True, progress=False, consonants=["j"])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
