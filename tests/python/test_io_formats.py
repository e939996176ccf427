"""The corpora people have, read as distributed (docs/DATA.md): MOCHA-TIMIT EST tracks (binary and
ASCII) with their .lab, X-ray Microbeam .txy, mview .mat, EMA CSV with lab sensor names,
midsagittal data, MFA TextGrids, and the built-in label maps mocha, timit and english_arpabet.

The files are written by tests/python/format_fixtures.py in the exact formats; every format holds
the same motion, so each reader is checked against the motion it was given."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import format_fixtures as ff
from coartic.cli import app
from coartic.io import DataError, LabelMap, load_trial, read_labels
from coartic.io.errors import DataWarning
from coartic.io.registry import reader_for

from fit_helpers import PAPER_TOML

COLUMNS = {"COLUMNS": "200"}


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path, str]]:
    return ff.write_all(tmp_path_factory.mktemp("formats"))


def _expected(m: ff.Motion, rest: np.ndarray) -> dict[str, np.ndarray]:
    """The channels of docs/DATA.md computed from the motion itself (a = anterior, v = up)."""
    s = m.sensors
    y0 = np.mean(0.5 * (s["UL"][rest, 1] + s["LL"][rest, 1]))
    out = {"ULO": s["UL"][:, 1] - y0, "LLO": y0 - s["LL"][:, 1], "ULP": s["UL"][:, 0],
           "LLP": s["LL"][:, 0], "LA": np.hypot(*(s["UL"] - s["LL"]).T), "JO": -s["JAW"][:, 1]}
    for sensor, (h, a) in {"TT": ("TTH", "TTA"), "TB": ("TBH", "TBA")}.items():
        out[h] = s[sensor][:, 1] - s[sensor][rest, 1].mean()
        out[a] = s[sensor][:, 0] - s[sensor][rest, 0].mean()
    return out


@pytest.mark.parametrize(("name", "motion", "tol"), [
    ("mocha-binary", lambda: ff.motion(500.0), 1e-3),  # 1/100 mm in 4-byte floats
    ("mocha-ascii", lambda: ff.motion(500.0), 1e-3),
    ("xrmb", ff.xrmb_motion, 2e-3),  # whole micrometres
    ("mview", lambda: ff.motion(100.0), 1e-9),
    ("carstens", lambda: ff.motion(250.0), 1e-4),  # 4-byte floats in mm
    ("lab-csv", lambda: ff.motion(200.0), 1e-9),
])
def test_each_format_gives_the_channels_of_its_motion(files, name, motion, tol) -> None:  # type: ignore[no-untyped-def]
    data, labels, label_map = files[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # right axes, right units: no warning
        if name in ("xrmb", "carstens"):  # frame grids that stop before the labels' end
            warnings.filterwarnings("ignore", ".*the last label", DataWarning)
        trial = load_trial(data, labels=labels, label_map=label_map)
        ch = trial.channels()
    m = motion()
    assert trial.kind == "ema" and trial.segments is not None
    assert trial.segments.labels == ff.PHONEMES
    assert dict(trial.roles.roles).keys() >= {"UL", "LL", "JAW", "TT", "TB"}
    want = _expected(m, trial.rest_frames())
    for c, v in want.items():
        ok = ch.valid[c]
        if c in ("ULP", "LLP", "JO"):  # relative to the system's origin: compare the motion
            np.testing.assert_allclose(ch[c][ok] - ch[c][ok][0], v[ok] - v[ok][0], atol=tol, err_msg=c)
        else:
            np.testing.assert_allclose(ch[c][ok], v[ok], atol=tol, err_msg=c)
    notes = " ".join(trial.meta["notes"])
    assert "sensors guessed by name" in notes
    if name in ("mocha-binary", "mocha-ascii", "xrmb"):
        # midsagittal: the lip width needs the lateral axis, refused by name; the rest computed
        assert trial.planar_axis == 2 and "midsagittal data (x and y only)" in notes
        assert "third (lateral) axis" in ch.unavailable["LR"]
        with pytest.raises(DataError, match=r"channel LR cannot be computed: it needs the third "
                                            r"\(lateral\) axis, and this file is midsagittal"):
            trial.channels(["LA", "LR"])
    if name != "lab-csv":
        assert "axes guessed from the sensors" in notes


def test_est_reader_details(tmp_path: Path) -> None:
    m = ff.motion(500.0)
    big = ff.write_mocha_est(tmp_path / "big.ema", m, byte_order="10", breaks=(10, 11))
    little = load_trial(ff.write_mocha_est(tmp_path / "little.ema", m))
    t = load_trial(big)
    assert reader_for(big).name == "est" and t.rate == 500.0 and t.n_frames == m.times.size
    assert t.marker_names == ("ui", "li", "ul", "ll", "tt", "tb", "td", "v", "bn")
    assert np.isnan(t.markers[10:12]).all() and "2 break frames (no data) set to NaN" in t.meta["notes"]
    keep = np.ones(t.n_frames, bool)
    keep[10:12] = False
    np.testing.assert_array_equal(t.markers[keep], little.markers[keep])
    # an EST file without its extension is found by its first line
    plain = tmp_path / "track.dat"
    plain.write_bytes(big.read_bytes())
    assert reader_for(plain).name == "est"
    raw = big.read_bytes()
    (tmp_path / "short.ema").write_bytes(raw[:-40])
    with pytest.raises(DataError, match=r"short\.ema: truncated: NumFrames \d+ x \(20 channels"):
        load_trial(tmp_path / "short.ema")
    (tmp_path / "order.ema").write_bytes(raw.replace(b"ByteOrder 10", b"ByteOrder 42"))
    with pytest.raises(DataError, match=r"ByteOrder '42': expected 01"):
        load_trial(tmp_path / "order.ema")
    (tmp_path / "noend.ema").write_bytes(raw.replace(b"EST_Header_End", b"EST_Header_Fnd"))
    with pytest.raises(DataError, match=r"noend\.ema.*(no EST_Header_End|non-ASCII)"):
        load_trial(tmp_path / "noend.ema")
    asc = ff.write_mocha_est(tmp_path / "a.ema", m, binary=False)
    lines = asc.read_text().splitlines()
    k = lines.index("EST_Header_End") + 4
    lines[k] = lines[k].replace(" ", " x", 1)
    asc.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=rf"a\.ema, line {k + 1}: 'x"):
        load_trial(asc)


def test_est_mngu0_style_is_3d_in_mm(tmp_path: Path) -> None:
    m = ff.motion(200.0)
    t = load_trial(ff.write_mngu0_est(tmp_path / "mngu0_s1_0001.ema", m))
    assert t.marker_names == ("T1", "T2", "T3", "jaw", "upperlip", "lowerlip")
    assert t.planar_axis is None and "positions read in mm" in " ".join(t.meta["notes"])
    assert dict(t.roles.roles) == {"UL": "upperlip", "LL": "lowerlip", "JAW": "jaw", "TT": "T1",
                                   "TB": "T3"}
    assert "up = +z, forwards = -x" in " ".join(t.meta["notes"])
    ch = t.channels()
    want = _expected(m, t.rest_frames())
    for c in ("LA", "ULO", "TTH", "TBA"):
        np.testing.assert_allclose(ch[c], want[c], atol=1e-4, err_msg=c)


def test_txy_reader_details(tmp_path: Path) -> None:
    m = ff.xrmb_motion()
    p = ff.write_txy(tmp_path / "tp002.txy", m, lost={"LL": (0, 1), "T3": (50,)})
    t = load_trial(p)
    assert t.marker_names == ("UL", "LL", "T1", "T2", "T3", "T4", "MI", "MM")
    assert np.isnan(t.markers[:2, 1]).all() and np.isnan(t.markers[50, 4]).all()
    assert "pellet samples marked lost (1000000) set to NaN: LL 2, T3 1" in t.meta["notes"]
    np.testing.assert_allclose(t.markers[5, 0, :2], np.round(m.sensors["UL"][5] * 1000) / 1000)
    ch = t.channels()
    assert ch.valid["TBH"][49] and ch.valid["TBH"][51]  # a one-frame gap is filled
    lines = p.read_text().splitlines()
    lines[3] = lines[3] + " 7"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"tp002\.txy, line 4: 18 fields where the time and x, y of "
                                        r"the pellets UL LL T1 T2 T3 T4 MI MM make 17"):
        load_trial(p)


def test_mview_reader_details_and_a_swapped_sensor(tmp_path: Path) -> None:
    import scipy.io

    m = ff.motion(100.0)
    flat = load_trial(ff.write_mview(tmp_path / "flat.mat", m, planar=True))
    assert flat.planar_axis == 1 and "midsagittal data (x and z only)" in " ".join(flat.meta["notes"])
    assert "LA" in flat.channels() and "LR" in flat.channels().unavailable
    # F01 of the Haskins rate database: the jaw and lower-lip sensors swapped. Named as a swap,
    # with the role map that undoes it, not as an axis problem.
    swapped = ff.write_mview(tmp_path / "F01_swapped.mat", m, swap_ll_jaw=True)
    with pytest.warns(DataWarning, match=r"F01_swapped\.mat: the LL and JAW sensors look swapped "
                                         r".*\{\"LL\": \"JAW\", \"JAW\": \"LL\"\}") as rec:
        load_trial(swapped, role_map={"UL": "UL", "LL": "LL", "JAW": "JAW", "TT": "TT",
                                      "axes": {"vertical": "+z", "anterior": "+x"}}).channels()
    assert not any("axes look wrong" in str(w.message) for w in rec)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        load_trial(swapped, role_map={"UL": "UL", "LL": "JAW", "JAW": "LL", "TT": "TT",
                                      "axes": {"vertical": "+z", "anterior": "+x"}}).channels()
    # not an mview struct: the variables are listed
    scipy.io.savemat(tmp_path / "other.mat", {"x": np.zeros((3, 3))})
    with pytest.raises(DataError, match=r"other\.mat: no struct array with the fields NAME, SRATE, "
                                        r"SIGNAL \(mview format\); the file holds \{'x'"):
        load_trial(tmp_path / "other.mat")
    (tmp_path / "v73.mat").write_bytes(b"MATLAB 7.3 MAT-file, Platform: x" + bytes(200))
    with pytest.raises(DataError, match=r"v73\.mat: a MATLAB v7\.3 \(HDF5\) file"):
        load_trial(tmp_path / "v73.mat")


def test_mview_labels_embedded_as_in_the_haskins_files(files, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The Haskins IEEE rate database keeps its alignment in the audio element (WORDS, PHONES of
    LABEL and OFFS): read as the file's own labels, as an EMU bundle's are."""
    import scipy.io

    # imported here: importing a reader module registers it, and test_registry_... expects the
    # registry's own order
    from coartic.io.mview import read_mview_labelled

    m = ff.motion(100.0)
    p = ff.write_mview(tmp_path / "M01_B01_S01_R01_F.mat", m, phones=ff.ARPABET_LABELS)
    seg = read_mview_labelled(p)[1]
    assert seg is not None and seg.tier == "PHONES" and seg.labels == ff.ARPABET_LABELS
    np.testing.assert_allclose(seg.starts, m.starts)
    np.testing.assert_allclose(seg.ends, m.ends)
    trial = load_trial(p, label_map="english_arpabet")
    assert trial.segments is not None and trial.segments.labels == ff.PHONEMES
    assert "labels: the 8 PHONES embedded in the file" in trial.meta["notes"]
    words = read_mview_labelled(p, tier="words")[1]
    assert words is not None and words.labels == ("PAMITU",) and words.tier == "WORDS"
    # a label file given beside it wins; a file without label fields has no labels of its own
    other = ff.write_tsv_labels(tmp_path / "other.tsv", m, ff.PHONEMES)
    segs = load_trial(p, labels=other).segments
    assert segs is not None and segs.labels == ff.PHONEMES
    assert load_trial(files["mview"][0]).segments is None
    with pytest.raises(DataError, match=r"M01_B01_S01_R01_F\.mat: no label field 'SYLLABLES' in "
                                        r"'M01_B01_S01_R01_F'; its label fields are \['WORDS', 'PHONES'\]"):
        load_trial(p, tier="SYLLABLES")
    with pytest.raises(DataError, match=r"no label field 'PHONES' in 'plain'; its label fields are none"):
        load_trial(ff.write_mview(tmp_path / "plain.mat", m), tier="PHONES")
    # a malformed entry is named: field, entry, element and label
    bad = scipy.io.loadmat(p, squeeze_me=False, struct_as_record=True)["M01_B01_S01_R01_F"]
    bad[0, 0]["PHONES"][0, 3]["OFFS"] = np.array([[0.5]])
    scipy.io.savemat(tmp_path / "bad.mat", {"bad": bad})
    with pytest.raises(DataError, match=r"bad\.mat: PHONES entry 4 of element 'AUDIO' \('M'\): OFFS "
                                        r"is \[0\.5\], not \[start end\] in seconds"):
        load_trial(tmp_path / "bad.mat")
    # inspect and score read the file's own labels: no label file needed
    r = CliRunner().invoke(app, ["inspect", str(p), "--label-map", "english_arpabet"], env=COLUMNS)
    assert r.exit_code == 0, r.output
    assert "8 PHONES embedded" in r.output and "AA1" in r.output
    spec = tmp_path / "spec.toml"
    tsv = ff.write_tsv_labels(tmp_path / "M01.tsv", m, ff.ARPABET_LABELS)
    spec.write_text(
        "[corpus]\n"
        f"files = {json.dumps([str(p)])}\n"
        f"labels = {json.dumps([str(tsv)])}\n"
        'label_map = "english_arpabet"\n'
        '[model]\nchannels = ["LA"]\nreference_phoneme = "a"\n'
        '[parameters]\nfree = ["target"]\n')
    r = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "fit"), "--no-report"], env=COLUMNS)
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["score", str(tmp_path / "fit" / "table.json"), str(p)], env=COLUMNS)
    assert r.exit_code == 0, r.output
    assert "LA" in r.output


def test_ema_csv_with_lab_names_is_ema_not_face_markers(tmp_path: Path) -> None:
    m = ff.motion(200.0)
    p = ff.write_lab_csv(tmp_path / "jw.csv", m, names={"UL": "UL", "LL": "LL", "JAW": "JW",
                                                         "TT": "TT", "TB": "TB"})
    t = load_trial(p)
    assert t.kind == "ema" and dict(t.roles.roles) == {"UL": "UL", "LL": "LL", "JAW": "JW",
                                                       "TT": "TT", "TB": "TB"}
    assert {"LA", "JO", "TTH", "TBA"} <= set(t.channels())
    # midsagittal CSV (y and z only): read, LR refused by name
    flat = load_trial(ff.write_lab_csv(tmp_path / "flat.csv", m, planar=True))
    assert flat.planar_axis == 0 and "LA" in flat.channels()
    # a role map whose axes use the missing axis is refused
    with pytest.raises(DataError, match=r"flat\.csv: this file is midsagittal \(axes y and z only\), but the role map"):
        load_trial(tmp_path / "flat.csv", role_map={"axes": {"vertical": "+z", "anterior": "+x"}})
    # face markers stay face markers
    face = tmp_path / "face.csv"
    face.write_text("time_s,NOSE_x,NOSE_y,NOSE_z,UL_x,UL_y,UL_z,LL_x,LL_y,LL_z\n0,0,0,0,1,1,1,2,2,2\n"
                    "0.01,0,0,0,1,1,1,2,2,2\n")
    assert load_trial(face).kind == "markers"


def test_mfa_textgrid_phones_tier_and_tier_names_in_errors(files) -> None:  # type: ignore[no-untyped-def]
    _, tg, _ = files["lab-csv"]
    segs = read_labels(tg)
    assert segs.tier == "phones" and segs.tiers == ("words", "phones")
    assert segs.labels[1:3] == ("P", "AA1")
    words = read_labels(tg, tier="words")
    with pytest.raises(DataError, match=r"phone 'pamitu' \(segment 2, tier 'words' of \['words', "
                                        r"'phones'\]\) has no mapping in builtin map 'english_arpabet'"):
        LabelMap.builtin("english_arpabet").apply(words)


def test_last_label_within_a_frame_or_a_final_pause_is_clipped_speech_beyond_is_an_error(tmp_path: Path) -> None:
    m = ff.motion(200.0)
    data = ff.write_lab_csv(tmp_path / "u.csv", m)
    end = m.times[-1] + 1 / 200.0
    lab = tmp_path / "u.tsv"
    starts, ends = m.starts.copy(), m.ends.copy()
    ends[-1] = end + 0.004  # 4 ms past the data, less than a 5 ms frame
    lab.write_text("".join(f"{float(s)!r}\t{float(e)!r}\t{p}\n" for s, e, p in zip(starts, ends, ff.PHONEMES)))
    with pytest.warns(DataWarning, match=r"u\.tsv: the last label '#' ends at .* within one frame "
                                         r"after the data of .*u\.csv end"):
        t = load_trial(data, labels=lab)
    assert t.segments is not None and t.segments.ends[-1] == pytest.approx(end)
    # a final pause labelled on the longer audio (MOCHA: sil 1.67-2.2 s against 1.932 s of EMA) is
    # clipped, and a pause that starts after the data left out
    ends[-1] = end + 0.27
    rows = [*zip(starts, ends, ff.PHONEMES), (end + 0.27, end + 0.4, "sil")]
    lab.write_text("".join(f"{float(s)!r}\t{float(e)!r}\t{p}\n" for s, e, p in rows))
    with pytest.warns(DataWarning, match=r"u\.tsv: the final pause '#' \(.*\) runs past the end of the data "
                                         r"of .*u\.csv .*clipped to .*, and the 1 pause label\(s\) after the data left out"):
        t = load_trial(data, labels=lab)
    assert t.segments is not None and t.segments.labels == tuple(ff.PHONEMES)
    assert t.segments.ends[-1] == pytest.approx(end) and len(t.segments.lines) == len(ff.PHONEMES)
    # a speech label past the data is still refused, naming it
    lab.write_text("".join(f"{float(s)!r}\t{float(e if p != 'u' else end + 0.05)!r}\t{p}\n"
                           for s, e, p in list(zip(starts, ends, ff.PHONEMES))[:-1]))
    with pytest.raises(DataError, match=r"u\.tsv, line 7: label 'u' .* lies beyond the data"):
        load_trial(data, labels=lab)


def test_a_speech_label_far_longer_than_a_phone_is_named_with_the_fix(tmp_path: Path) -> None:
    # an aligner that ran the last phone into the rest after the sentence (the German EMA's final /n/
    # lasts 1.3 and 1.8 s): a warning naming the file, line and label; the labels are kept as given
    data = ff.write_lab_csv(tmp_path / "u.csv", ff.motion(200.0))
    lab = tmp_path / "u.tsv"
    bounds = (0.0, 0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 1.13)
    lab.write_text("".join(f"{s!r}\t{e!r}\t{p}\n" for s, e, p in zip(bounds, bounds[1:], ff.ARPABET_LABELS)))
    with pytest.warns(DataWarning, match=r"u\.tsv, line 7: the label 'UW1' \(0\.3-1\.13 s, segment 7\) lasts "
                                         r"0\.83 s, 17 times the recording's median speech label \(50 ms\).* "
                                         r"label that part as a pause; the model fits it as /u/ throughout") as rec:
        t = load_trial(data, labels=lab, label_map="english_arpabet")
    assert len(rec) == 1 and t.segments is not None and t.segments.labels[-1] == "u"
    # slow or sustained speech, every label long: no phone stands out
    lab.write_text("0.0\t0.1\tsil\n0.1\t0.65\tAA1\n0.65\t1.13\tIY1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        load_trial(data, labels=lab, label_map="english_arpabet")


def test_label_maps_mocha_timit_arpabet_and_their_fallbacks(tmp_path: Path) -> None:
    mocha, timit, arpa = (LabelMap.builtin(n) for n in ("mocha", "timit", "english_arpabet"))
    assert [mocha.map_label(x) for x in ("@", "@@", "ii", "uu", "oo", "ou", "ai", "e@", "uh",
                                         "breath", "dh", "jh")] == \
        ["e", "e", "i", "u", "O", "o", "a", "E", "a", "#", "d", "dZ"]
    assert [timit.map_label(x) for x in ("h#", "pcl", "p", "ax-h", "ix", "ux", "dx", "q", "em",
                                         "epi")] == ["#", "p", "p", "e", "i", "u", "d", "#", "m", "#"]
    # every ARPAbet vowel, with or without stress, and TIMIT's reduced ones
    vowels = ("AA AE AH AO AW AY EH ER EY IH IY OW OY UH UW AX AXR IX UX").split()
    assert all(arpa.map_label(v + d) is not None for v in vowels[:15] for d in ("", "0", "1", "2"))
    assert all(arpa.map_label(v) is not None for v in vowels)
    # phonetic-class fallbacks, recorded with the map in a table and read back
    for lm in (mocha, timit, arpa):
        assert lm.fallbacks["E"] == ("e", "a") and lm.fallbacks["h"] == ("#",)
    assert LabelMap.from_record(arpa.to_record()).fallbacks == arpa.fallbacks
    own = tmp_path / "own.tsv"
    # a map file extends the built-in phonetic classes: its own line replaces one phoneme's list
    own.write_text("x\ta\nfallback:a\tO\n")
    extended = LabelMap.from_file(own).fallbacks
    assert extended["a"] == ("O",) and extended["E"] == ("e", "a") and extended["p"] == ("b", "m")
    assert LabelMap.from_record(LabelMap.from_file(own).to_record()).fallbacks == extended
    # ... unless it says otherwise; the table's record keeps that too
    own.write_text("x\ta\nfallback:a\tO\nfallback:*\tnone\n")
    alone = LabelMap.from_file(own)
    assert alone.fallbacks == {"a": ("O",)} and LabelMap.from_record(alone.to_record()).fallbacks == {"a": ("O",)}
    assert LabelMap.from_dict({"x": "a"}).fallbacks == extended | {"a": ("E", "O")}
    assert LabelMap.from_record(LabelMap.model().to_record()).fallbacks == {}
    own.write_text("x\ta\nfallback:*\tO\n")
    with pytest.raises(DataError, match=r"own\.tsv, line 2: 'fallback:\*' may only say 'none'"):
        LabelMap.from_file(own)
    own.write_text("x\ta\nfallback:\tO\n")
    with pytest.raises(DataError, match=r"own\.tsv, line 2: 'fallback:' names no phoneme"):
        LabelMap.from_file(own)


def test_every_built_in_symbol_has_a_fallback() -> None:
    """Every phoneme a built-in map gives (kept labels such as the glottal stops `Q` and `?`
    included) has a phonetic-class fallback, so a table that lacks it can still score or animate it;
    MOCHA's ARPAbet-style `iy` is mapped."""
    assert LabelMap.builtin("mocha").map_label("iy") == "i"
    for name in ("german_sampa", "english_arpabet", "mocha", "timit"):
        lm = LabelMap.builtin(name)
        given = {label if p == "=" else p for label, p in lm.mapping.items()}
        given |= {p for _, p in lm.patterns if p != "="}
        lacking = sorted(p for p in given - {"#"} if not lm.fallbacks.get(p))
        assert not lacking, (name, lacking)
        assert all(f in lm.fallbacks or f == "#" for chain in lm.fallbacks.values() for f in chain), name
    sampa = LabelMap.builtin("german_sampa")
    assert sampa.map_label("Q") == "Q" and sampa.fallbacks["Q"] == ("#",) and sampa.fallbacks["?"] == ("#",)


def test_inspect_fit_and_score_read_every_format(files, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    for name, (data, labels, label_map) in files.items():
        r = CliRunner().invoke(app, ["inspect", str(data), "--labels", str(labels),
                                     "--label-map", label_map], env=COLUMNS)
        assert r.exit_code == 0, (name, r.output)
        assert "TTH" in r.output and "axes" in r.output, name
    # one fit over every format (one label map for all: the corpora's labels differ)
    both = tmp_path / "all.tsv"
    pairs = {c: p for labels in (ff.MOCHA_LABELS, ff.ARPABET_LABELS, ff.TIMIT_LABELS)
             for c, p in zip(labels, ff.PHONEMES) if c not in ("sil", "h#")}
    both.write_text("".join(f"{c}\t{p}\n" for c, p in pairs.items()))
    spec = tmp_path / "spec.toml"
    names = [n for n in files if n != "mocha-ascii"]
    spec.write_text(
        "[corpus]\n"
        f"files = {json.dumps([str(files[n][0]) for n in names])}\n"
        f"labels = {json.dumps([str(files[n][1]) for n in names])}\n"
        f'label_map = "{both}"\n'
        '[model]\nchannels = ["LA", "TTH", "TBA"]\nreference_phoneme = "a"\n' + PAPER_TOML[0] +
        '[parameters]\nfree = ["target", "alpha"]\n' + PAPER_TOML[1])  # the model the files are made with
    out = tmp_path / "fit"
    r = CliRunner().invoke(app, ["fit", str(spec), "--out", str(out), "--no-report"], env=COLUMNS)
    assert r.exit_code == 0, r.output
    table = json.loads((out / "table.json").read_text())
    assert set(table["channels"]) == {"LA", "TTH", "TBA"}
    assert all(v < 0.6 for v in table["metadata"]["rmse"].values()), table["metadata"]["rmse"]
    rec = [str(files[n][0]) for n in files]
    lab = [x for n in files for x in ("--labels", str(files[n][1]))]
    r = CliRunner().invoke(app, ["score", str(out / "table.json"), *rec, *lab], env=COLUMNS)
    assert r.exit_code == 0, r.output
    assert "TTH" in r.output and "TBA" in r.output


def test_registry_unknown_format_and_a_new_reader(tmp_path: Path) -> None:
    from coartic.io.registry import Reader, ReadRequest, readers, register
    from coartic.io.trial import Trial

    p = tmp_path / "x.weird"
    p.write_bytes(b"\x00\x01nothing known")
    with pytest.raises(DataError, match=r"x\.weird: cannot tell the format of this file \(extension "
                                        r"'\.weird'\); coartic reads C3D \(\.c3d\); .*MOCHA-TIMIT"):
        load_trial(p)
    names = [r.name for r in readers()]
    assert {"c3d", "carstens-pos", "ema-csv", "markers-csv", "emu", "est", "xrmb", "mview"} <= set(names)
    assert names.index("ema-csv") < names.index("markers-csv")  # the generic sniffer asks last
    # the order does not depend on which reader module a caller imported first (a test importing
    # the EMU reader before any file was read put it before C3D, in this message and the sniffing)
    order = "from coartic.io.registry import readers; print([r.name for r in readers()])"
    first = [subprocess.run([sys.executable, "-c", pre + order], capture_output=True, text=True, check=True).stdout
             for pre in ("", "import coartic.io.emu, coartic.io.xrmb; ")]
    assert first[0] == first[1] == f"{names}\n"

    def read(path: Path, req: ReadRequest) -> tuple[Trial, None]:
        m = np.zeros((3, 2, 3))
        m[:, 1, 2] = -10.0
        return Trial(m, ("UL", "LL"), 100.0, source=path, kind="ema", meta={"notes": []}), None

    try:
        register(Reader("weird", "weird test format", (".weird",), read))
        t = load_trial(p)
        assert t.marker_names == ("UL", "LL") and "sensors" not in " ".join(t.meta["notes"])
    finally:
        from coartic.io import registry

        registry._READERS[:] = [r for r in registry._READERS if r.name != "weird"]


def test_a_recorded_role_map_without_axes_keeps_the_formats_axes(files) -> None:  # type: ignore[no-untyped-def]
    from types import SimpleNamespace

    from coartic.io.roles import RoleMap

    rec = RoleMap.from_dict({"UL": "ul", "LL": "ll", "JAW": "li", "TT": "tt"}).to_record()
    assert "axes" not in rec  # the fit's map gave none: the guess applies again when scoring
    table = SimpleNamespace(metadata={"role_map": rec}, source="t.json")
    back = RoleMap.recorded(table)
    assert back is not None and not back.axes_given
    data, labels, lmap = files["mocha-binary"]
    t = load_trial(data, labels=labels, label_map=lmap, role_map=back)
    assert (t.roles.vertical, t.roles.anterior) == ("+y", "-x") and "LA" in t.channels()
    given = RoleMap.from_dict({"UL": "ul", "axes": {"vertical": "+y", "anterior": "-x"}})
    assert RoleMap.recorded(SimpleNamespace(metadata={"role_map": given.to_record()},
                                            source="t.json")).axes_given  # type: ignore[union-attr]


def test_c3d_of_ema_sensors_is_read_as_ema(tmp_path: Path) -> None:
    import ezc3d

    m = ff.motion(200.0)
    names = ("UL", "LL", "JAW", "TT", "TB")
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [200.0]
    c["parameters"]["POINT"]["LABELS"]["value"] = names
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    pts = np.ones((4, len(names), m.times.size))
    for j, n in enumerate(names):  # x forwards, y lateral, z up
        pts[0, j], pts[1, j], pts[2, j] = m.sensors[n][:, 0], 0.1, m.sensors[n][:, 1]
    c["data"]["points"] = pts
    c.write(str(tmp_path / "wave.c3d"))
    t = load_trial(tmp_path / "wave.c3d")
    notes = " ".join(t.meta["notes"])
    assert t.kind == "ema" and "read as EMA sensors" in notes and "up = +z, forwards = +x" in notes
    ch = t.channels()
    want = _expected(m, t.rest_frames())
    for c_ in ("LA", "LLO", "TTH", "TBA"):
        np.testing.assert_allclose(ch[c_], want[c_], atol=1e-3, err_msg=c_)
