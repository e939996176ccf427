"""Marker readers (C3D through ezc3d and the c3d fallback, CSV/TSV), gaps, resampling, Trial."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from coartic.io import DataError, Segments, Trial, load_trial
from coartic.io.c3d import read_c3d
from coartic.io.gaps import fill_gaps, resample, runs

ROLES = ("NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN")
RATE = 100.0


def true_channels(n: int) -> dict[str, NDArray[np.float64]]:
    """Smooth lip and jaw movements with a still rest at the start (ULO = LLO = 0 there)."""
    t = np.arange(n) / RATE
    move = np.clip((t - 0.3) / 0.2, 0, 1) ** 2
    return {
        "ULO": move * (2.0 * np.sin(6 * t)),
        "LLO": move * (8.0 + 4.0 * np.sin(9 * t)),
        "ULP": 12.0 + move * np.sin(5 * t),
        "LLP": 10.0 + move * 2.0 * np.cos(7 * t),
        "LR": 50.0 + move * 3.0 * np.sin(4 * t),
        "JO": 118.0 + move * 5.0 * np.sin(3 * t),
    }


def face_markers(ch: dict[str, NDArray[np.float64]], seed: int = 0) -> NDArray[np.float64]:
    """Markers (F, 8, 3) giving exactly `ch` in the head frame of MODEL.md §6, then moved rigidly."""
    n = ch["ULO"].size
    lip_y = -40.0
    m = np.zeros((n, 8, 3))
    m[:, 0] = (0.0, 0.0, 100.0)  # NOSE on the head z axis, so the frame is the one built here
    m[:, 1] = (70.0, 0.0, 0.0)
    m[:, 2] = (-70.0, 0.0, 0.0)
    m[:, 3] = np.stack([np.zeros(n), lip_y + ch["ULO"], ch["ULP"]], axis=1)
    m[:, 4] = np.stack([np.zeros(n), lip_y - ch["LLO"], ch["LLP"]], axis=1)
    m[:, 5] = np.stack([ch["LR"] / 2, np.full(n, lip_y), np.full(n, 95.0)], axis=1)
    m[:, 6] = np.stack([-ch["LR"] / 2, np.full(n, lip_y), np.full(n, 95.0)], axis=1)
    m[:, 7] = np.stack([np.zeros(n), -ch["JO"], np.full(n, 100.0)], axis=1)
    # slow rigid head motion: a few degrees about a tilted axis, a few mm
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    t = np.arange(n) / RATE
    out = np.empty_like(m)
    for f in range(n):
        a = np.deg2rad(4.0) * np.sin(1.3 * t[f])
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rot = np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k
        out[f] = m[f] @ rot.T + np.array([300.0, 1200.0, -50.0]) + 3.0 * np.sin(t[f])
    return out


def write_csv(path: Path, markers: NDArray[np.float64], names: tuple[str, ...], delim: str = ",",
              t0: float = 0.0) -> None:
    cols = ["time_s"] + [f"{n}_{a}" for n in names for a in "xyz"]
    with open(path, "w") as f:
        f.write(delim.join(cols) + "\n")
        for i in range(markers.shape[0]):
            vals = ["" if np.isnan(v) else repr(float(v)) for v in markers[i].ravel()]
            f.write(delim.join([f"{t0 + i / RATE:.4f}", *vals]) + "\n")


def write_c3d(path: Path, markers: NDArray[np.float64], names: tuple[str, ...],
              unit: str = "mm", invalid: NDArray[np.bool_] | None = None) -> None:
    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [RATE]
    c["parameters"]["POINT"]["LABELS"]["value"] = names
    c["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    pts = np.ones((4, len(names), markers.shape[0]))
    pts[:3] = np.transpose(np.nan_to_num(markers), (2, 1, 0))
    c["data"]["points"] = pts
    res = np.zeros((1, len(names), markers.shape[0]))
    flagged = np.isnan(markers).any(axis=2) if invalid is None else invalid | np.isnan(markers).any(axis=2)
    res[0] = np.where(flagged.T, -1.0, 0.0)  # occluded: residual -1, as capture systems write
    c["data"]["meta_points"] = {"residuals": res,
                                "camera_masks": np.zeros((7, len(names), markers.shape[0]), bool)}
    c.write(str(path))


@pytest.fixture(scope="module")
def face() -> tuple[dict[str, NDArray[np.float64]], NDArray[np.float64]]:
    ch = true_channels(150)
    return ch, face_markers(ch)


def test_csv_reads_markers_rate_and_missing(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    _, m = face
    m = m.copy()
    m[40:43, 3, :] = np.nan
    p = tmp_path / "t.tsv"
    write_csv(p, m, ROLES, delim="\t", t0=1.5)
    t = load_trial(p)
    assert t.marker_names == ROLES and t.rate == RATE and t.start_time == 1.5
    assert np.isnan(t.markers[40:43, 3]).all() and np.isfinite(t.markers[43, 3]).all()
    np.testing.assert_allclose(t.markers[~np.isnan(m)], m[~np.isnan(m)], rtol=1e-12)


def test_csv_errors_name_line_and_column(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    _, m = face
    p = tmp_path / "t.csv"
    write_csv(p, m[:10], ROLES)
    lines = p.read_text().splitlines()
    fields = lines[4].split(",")
    fields[1 + 3 * ROLES.index("UL") + 1] = "abc"
    lines[4] = ",".join(fields)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"t\.csv, line 5: column 'UL_y': 'abc' is not a number"):
        load_trial(p)
    write_csv(p, m[:10], ROLES)
    lines = p.read_text().splitlines()
    del lines[6]  # a dropped frame
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"line 7: time column 'time_s' is not evenly spaced"):
        load_trial(p)
    # midsagittal data gives the same two axes for every marker; mixed is an error naming the marker
    p.write_text("time_s,LL_x,LL_y,LL_z,UL_x,UL_y\n0,1,2,3,4,5\n")
    with pytest.raises(DataError, match=r"marker 'UL' has no column UL_z \(midsagittal data"):
        load_trial(p)
    p.write_text("# units: furlong\ntime_s,UL_x,UL_y,UL_z\n0,1,2,3\n0.01,1,2,3\n")
    with pytest.raises(DataError, match=r"unit 'furlong'"):
        load_trial(p)
    p.write_text("# units: cm\ntime_s,UL_x,UL_y,UL_z\n0,1,2,3\n0.01,1,2,3\n")
    t = load_trial(p)
    assert t.markers[0, 0, 2] == 30.0 and "cm to mm" in t.meta["notes"][0]


def test_c3d_round_trip_invalid_samples_and_units(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    _, m = face
    invalid = np.zeros(m.shape[:2], bool)
    invalid[10:14, 4] = True
    p = tmp_path / "t.c3d"
    write_c3d(p, m / 1000.0, ROLES, unit="m", invalid=invalid)
    for backend in ("ezc3d", "c3d"):
        t = read_c3d(p, backend=backend)
        assert t.marker_names == ROLES and t.rate == RATE and t.units == "mm"
        assert np.isnan(t.markers[10:14, 4]).all()
        assert not np.isnan(t.markers[~invalid]).any()
        # C3D stores float32
        np.testing.assert_allclose(t.markers[~invalid], m[~invalid], atol=1e-3)
        assert any("m to mm" in n for n in t.meta["notes"])


def test_c3d_unnamed_and_duplicate_markers(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    _, m = face
    p = tmp_path / "u.c3d"
    write_c3d(p, m[:, :3], ("NOSE", "", "EAR_R"))
    t = read_c3d(p)
    assert t.marker_names == ("NOSE", "Marker_2", "EAR_R") and "unlabelled" in t.meta["notes"][0]
    write_c3d(p, m[:, :3], ("UL", "LL", "UL"))
    with pytest.raises(DataError, match=r"u\.c3d: marker name 'UL' appears twice in POINT:LABELS "
                                        r"\(markers 1 and 3\)"):
        read_c3d(p)


def test_c3d_truncated_and_garbage(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    _, m = face
    p = tmp_path / "t.c3d"
    write_c3d(p, m, ROLES)
    data = p.read_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(data[: len(data) - 300])
    with pytest.raises(DataError, match=r"cut\.c3d: truncated C3D: the header declares 150 frames"):
        read_c3d(cut)
    part = read_c3d(cut, allow_truncated=True)
    assert 140 < part.n_frames < 150 and "truncated" in part.meta["notes"][-1]
    head = tmp_path / "head.c3d"
    head.write_bytes(data[:600])
    with pytest.raises(DataError, match=r"head\.c3d: parameter section: .* run past the end of the file"):
        read_c3d(head)
    junk = tmp_path / "junk.c3d"
    junk.write_bytes(b"hello world" * 100)
    with pytest.raises(DataError, match=r"junk\.c3d: not a C3D file"):
        load_trial(junk)


def test_c3d_corrupt_parameter_section_is_refused_before_ezc3d(tmp_path: Path) -> None:
    # one byte: the number of dimensions of POINT:LABELS set to 255 made ezc3d segfault
    data = bytearray((Path(__file__).parents[1] / "data/realdata/c3d-optotrak/Optotrak.c3d").read_bytes())
    at = data.index(b"LABELS") + len("LABELS") + 3  # after the name: 2 bytes offset, 1 data type
    assert data[at] == 2
    data[at] = 255
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(bytes(data))
    for backend in ("auto", "ezc3d", "c3d"):
        with pytest.raises(DataError, match=r"bad\.c3d: parameter POINT:LABELS: 255 dimensions \(C3D "
                                            r"allows at most 7\)"):
            read_c3d(bad, backend=backend, allow_truncated=True)  # type: ignore[arg-type]
    data[at] = 3  # three dimensions of the labels' sizes: more bytes than the entry holds
    bad.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"POINT:LABELS: dimensions \[40, 54, \d+\] of 1-byte values"):
        read_c3d(bad, allow_truncated=True)


def test_c3d_truncated_block_padding_is_not_read_as_frames(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    import c3d

    _, m = face
    p = tmp_path / "t.c3d"
    write_c3d(p, m[:, :2], ROLES[:2])  # 2 markers: 32 bytes a frame, so a block pads several
    data = p.read_bytes()
    with p.open("rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # c3d's "No analog data found in file.": this file has none, by design
        start = (c3d.Reader(f).header.data_block - 1) * 512
    cut = start + 10 * 32
    padded = tmp_path / "padded.c3d"
    padded.write_bytes(data[:cut] + bytes(-cut % 512))  # 10 frames, then zeros to the block end
    for backend in ("ezc3d", "c3d"):
        t = read_c3d(padded, backend=backend, allow_truncated=True)
        assert t.n_frames == 10, backend
        np.testing.assert_allclose(t.markers, m[:10, :2], atol=1e-3)
        assert "6 all-zero frames of block padding" in t.meta["notes"][-1]


def test_real_optotrak_c3d() -> None:
    p = Path(__file__).parents[1] / "data/realdata/c3d-optotrak/Optotrak.c3d"
    # The file stops after 29 of the 1149 frames its header declares (README.txt).
    with pytest.raises(DataError, match="header declares 1149 frames of POINT data, the file holds 29"):
        read_c3d(p)
    for backend in ("ezc3d", "c3d"):
        t = read_c3d(p, backend=backend, allow_truncated=True)
        assert t.rate == 30.0 and t.units == "mm" and t.markers.shape == (29, 54, 3)
        assert t.marker_names[0] == "Marker_1" and t.marker_names[-1] == "Marker_54"
        frac = float(np.isnan(t.markers[:, :, 0]).mean())
        assert 0.03 < frac < 0.05  # README: about 4 % invalid
        # a sample is missing in all three coordinates or in none
        assert (np.isnan(t.markers).any(axis=2) == np.isnan(t.markers).all(axis=2)).all()
    t = load_trial(p, allow_truncated=True)
    with pytest.raises(DataError, match=r"required marker\(s\) \['NOSE'.*the file has \['Marker_1'"):
        t.channels()


# --- gaps and resampling ------------------------------------------------------------------------


def test_fill_gaps_short_filled_long_left_and_reported() -> None:
    n = 200
    t = np.arange(n) / RATE
    x = np.stack([np.sin(3 * t), np.cos(2 * t), t**2], axis=1)[:, None, :]
    m = x.copy()
    m[50:55, 0] = np.nan  # 50 ms: filled
    m[100:106, 0, 1] = np.nan  # 60 ms, one coordinate: the marker is missing, left
    m[:3, 0] = np.nan  # at the start: left
    filled, gaps = fill_gaps(m, ["UL"], RATE, start_time=0.0, max_gap=0.05)
    assert [(g.frames, g.filled, g.reason) for g in gaps] == [
        (3, False, "at the start"), (5, True, "filled"), (6, False, "too long")]
    assert gaps[1].start == pytest.approx(0.50) and gaps[1].end == pytest.approx(0.54)
    np.testing.assert_allclose(filled[50:55, 0], x[50:55, 0], atol=1e-4)
    assert np.isnan(filled[100:106, 0]).all() and np.isnan(filled[:3, 0]).all()
    assert "left missing (too long)" in str(gaps[2])


@settings(max_examples=60, deadline=None, derandomize=True)
@given(missing=st.lists(st.booleans(), min_size=8, max_size=60),
       max_gap=st.sampled_from([0.0, 0.02, 0.05, 0.1]))
def test_fill_gaps_properties(missing: list[bool], max_gap: float) -> None:
    n = len(missing)
    x = np.stack([np.sin(np.arange(n) / 7.0)] * 3, axis=1)[:, None, :]
    m = x.copy()
    m[np.array(missing)] = np.nan
    filled, gaps = fill_gaps(m, ["UL"], RATE, start_time=0.0, max_gap=max_gap)
    ok = ~np.array(missing)
    assert np.array_equal(filled[ok], m[ok])  # measured samples are never touched
    # the gaps are exactly the missing runs, in order, and only interior short ones are filled
    assert [(round(g.start * RATE), round(g.end * RATE) + 1) for g in gaps] == runs(np.array(missing))
    for g in gaps:
        a, b = round(g.start * RATE), round(g.end * RATE) + 1
        interior = a > 0 and b < n
        assert g.filled == (interior and g.frames / RATE <= max_gap + 1e-9 and ok.sum() >= 2)
        assert np.isfinite(filled[a:b]).all() == g.filled


def test_resample_never_bridges_a_gap() -> None:
    n = 300
    t = np.arange(n) / 200.0
    x = np.stack([np.sin(4 * t)] * 3, axis=1)[:, None, :]
    x[100:130] = np.nan
    y = resample(x, 200.0, 100.0)
    tn = np.arange(y.shape[0]) / 100.0
    gap = (tn > t[99]) & (tn < t[130])
    assert np.isnan(y[gap]).all()
    ok = ~np.isnan(y[:, 0, 0])
    np.testing.assert_allclose(y[ok, 0, 0], np.sin(4 * tn[ok]), atol=2e-3)
    assert runs(np.isnan(y[:, 0, 0])) == [(50, 65)]


def test_resample_down_filters_before_it_decimates() -> None:
    # 3 Hz movement plus a 90 Hz jitter at 200 Hz; at 100 Hz the jitter would alias to 10 Hz
    t = np.arange(400) / 200.0
    slow = 5.0 * np.sin(2 * np.pi * 3 * t)
    x = np.repeat((slow + 0.5 * np.sin(2 * np.pi * 90 * t))[:, None, None], 3, axis=2)
    y = resample(x, 200.0, 100.0)[:, 0, 0]
    tn = np.arange(y.size) / 100.0
    inner = slice(20, -20)  # away from the filter's edge transients
    err = y[inner] - 5.0 * np.sin(2 * np.pi * 3 * tn[inner])
    assert np.max(np.abs(err)) < 0.05  # the 0.5 mm jitter is gone, not folded to 10 Hz


# --- Trial and channels -------------------------------------------------------------------------


def test_labels_beyond_data_and_rest_frames(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    _, m = face
    p = tmp_path / "t.csv"
    write_csv(p, m, ROLES)
    lab = tmp_path / "t.lab"
    lab.write_text("0 2500000 sil\n2500000 14000000 a\n14000000 16000000 p\n")
    with pytest.raises(DataError, match=r"t\.lab, line 3: label 'p' \(1\.4-1\.6 s\) lies beyond "
                                        r"the data"):
        load_trial(p, labels=lab)
    lab.write_text("0 2500000 sil\n2500000 14000000 a\n14000000 15000000 p\n")
    t = load_trial(p, labels=lab)
    assert t.segments is not None and t.segments.labels == ("#", "a", "p")
    rest = t.rest_frames()
    assert rest.sum() == 13 and rest[:13].all()  # the pause's first half, 0 to 0.125 s, at 100 Hz


def test_channels_recover_geometry_through_head_motion(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("coartic._core")
    ch, m = face
    m = m.copy()
    m[60:63, 3] = np.nan  # 30 ms: filled
    m[90:100, 4] = np.nan  # 100 ms: masked
    p = tmp_path / "t.c3d"
    write_c3d(p, m, ROLES)
    rest = Segments(("#", "a"), np.array([0.0, 0.25]), np.array([0.25, 1.5]))
    t = load_trial(p, labels=rest)
    out = t.channels()
    assert list(out) == ["ULO", "LLO", "ULP", "LLP", "LR", "JO", "LA"]
    for name, truth in ch.items():
        ok = out.valid[name]
        np.testing.assert_allclose(out[name][ok], truth[ok], atol=2e-3, err_msg=name)
    la = ch["ULO"] + ch["LLO"]  # |UL - LL| with both on the midline and the rest gap 0
    ok = out.valid["LA"]
    np.testing.assert_allclose(out["LA"][ok], np.hypot(la, ch["ULP"] - ch["LLP"])[ok], atol=2e-3)
    assert not out.valid["LLO"][90:100].any() and out.valid["LLO"][60:63].all()
    assert out.valid["ULP"][90:100].all()  # ULP needs only UL
    assert out.weights("LLO").sum() == 140
    assert [(g.marker, g.filled) for g in out.gaps] == [("UL", True), ("LL", False)]


def test_channels_role_map_and_missing_marker(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("coartic._core")
    ch, m = face
    names = ("nose_tip", "ear_l", "ear_r", "ul", "ll", "lcl", "lcr", "chin")
    t = Trial(m.copy(), names, RATE)
    with pytest.raises(DataError, match=r"required marker\(s\) \['NOSE', 'LC_L', 'LC_R'\]"):
        t.channels(["ULO", "LR"])
    p = tmp_path / "t.csv"
    write_csv(p, m, names)
    t = load_trial(p, role_map={"NOSE": "nose_tip", "LC_L": "lcl", "LC_R": "lcr"})
    out = t.channels(["LR", "JO"])
    np.testing.assert_allclose(out["LR"], ch["LR"], atol=1e-6)
    np.testing.assert_allclose(out["JO"], ch["JO"], atol=1e-6)
    # without the corners, LR is unavailable (and says why) but the rest is computed
    t2 = Trial(m[:, :5].copy(), ROLES[:5], RATE)
    out2 = t2.channels()
    assert "LR" not in out2 and "LC_L" in out2.unavailable["LR"] and "JO" in out2.unavailable
    # y_0 needs the lips in the rest frames
    m3 = m.copy()
    m3[:30, 4] = np.nan
    with pytest.raises(DataError, match=r"never all present in the rest frames "
                                        r"\(0\.000-0\.190 s\): y_0 is undefined, and so are ULO"):
        Trial(m3, ROLES, RATE).channels(["ULO", "LA"])
    out3 = Trial(m3, ROLES, RATE).channels()
    assert "y_0 is undefined" in out3.unavailable["ULO"] and "LLO" not in out3
    np.testing.assert_allclose(out3["ULP"], ch["ULP"], atol=1e-6)


def test_common_rate(face) -> None:  # type: ignore[no-untyped-def]
    from coartic.io import common_rate

    _, m = face
    a = Trial(m.copy(), ROLES, RATE)
    b = Trial(np.repeat(m, 2, axis=0)[:-1].copy(), ROLES, 2 * RATE)
    a2, b2 = common_rate([a, b])
    assert a2 is a and b2.rate == RATE and b2.n_frames == a.n_frames


def test_la_without_head_markers_and_markers_differing_in_case(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    ch, m = face
    p = tmp_path / "lips.csv"
    write_csv(p, m[:, 3:5], ("UL", "LL"))  # the lips only: no head frame, but LA is a distance
    la = load_trial(p).channels(["LA"])["LA"]
    np.testing.assert_allclose(la, np.linalg.norm(m[:, 3] - m[:, 4], axis=1), atol=1e-9)
    c = load_trial(p).channels()
    assert list(c) == ["LA"] and "no marker for role(s) ['NOSE', 'EAR_L', 'EAR_R']" in c.unavailable["ULO"]
    with pytest.raises(DataError, match=r"channel ULO cannot be computed|required marker"):
        load_trial(p).channels(["ULO"])
    q = tmp_path / "case.csv"
    write_csv(q, m[:, 3:6], ("ul", "LL", "UL"))
    with pytest.raises(DataError, match=r"case\.csv: markers \['ul', 'UL'\] differ only in case: which is UL"):
        load_trial(q).channels(["LA"])
    la2 = load_trial(q, role_map={"UL": "UL"}).channels(["LA"])["LA"]  # named exactly: no doubt
    np.testing.assert_allclose(la2, np.linalg.norm(m[:, 5] - m[:, 4], axis=1), atol=1e-9)


def test_csv_time_columns_overflow_and_implausible_values(tmp_path: Path, face) -> None:  # type: ignore[no-untyped-def]
    from coartic.io.errors import DataWarning

    _, m = face
    p = tmp_path / "two_times.csv"
    write_csv(p, m[:20], ROLES)
    lines = p.read_text().splitlines()
    p.write_text("\n".join([lines[0] + ",time"] + [ln + f",{i * 10}" for i, ln in enumerate(lines[1:])]) + "\n")
    with pytest.raises(DataError, match=r"two_times\.csv, line 1: 2 time columns \['time_s', 'time'\]"):
        load_trial(p)
    q = tmp_path / "metres.csv"
    big = m[:20] / 1000.0
    big[7, 4, 1] = 1e306  # LL_y: finite in m, inf in mm
    write_csv(q, big, ROLES)
    q.write_text("# units: m\n" + q.read_text())
    with pytest.raises(DataError, match=r"metres\.csv: marker positions: 1e\+306 m \(frame 7, marker 'LL', "
                                        r"y\) overflows when converted to mm"):
        load_trial(q)
    r = tmp_path / "huge.csv"
    huge = m[:60].copy()
    huge[30, 0, 0] = 1e308
    write_csv(r, huge, ROLES)
    with pytest.warns(DataWarning, match=r"huge\.csv: marker 'NOSE' is at 1e\+308 mm \(x, frame 30"):
        load_trial(r)
    s = tmp_path / "wide.csv"
    wide = m[:60].copy()
    wide[40:, 4, :] -= 1300.0 * (wide[40:, 0, :] - wide[40:, 3, :]) / np.linalg.norm(
        wide[40:, 0, :] - wide[40:, 3, :], axis=1)[:, None]  # the lower lip 1.3 m below the upper
    write_csv(s, wide, ROLES)
    with pytest.warns(DataWarning, match=r"wide\.csv: channel LA reaches 13\d\d(\.\d+)? mm \(beyond 150 mm"):
        load_trial(s).channels(["LA"])
