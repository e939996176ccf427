"""Recordings and label files that used to read silently wrong or fail with a message blaming the
wrong thing (issue 28): each is now read right or refused naming the file, the key and the fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import format_fixtures as ff
from coartic.cli import app
from coartic.io import DataError, load_trial, read_labels

from test_io_markers import ROLES, face_markers, true_channels

EMU = Path(__file__).resolve().parents[1] / "data" / "realdata" / "emu-ema-german"


def run(*args: object) -> tuple[int, str]:
    r = CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "300"})
    assert "Traceback" not in r.output
    return r.exit_code, " ".join(r.output.split())


# ------------------------------------------------------------------------------------- EST
def test_an_est_track_with_the_wrong_byte_order_says_so(tmp_path: Path) -> None:
    big = ff.write_mocha_est(tmp_path / "big.ema", ff.motion(500.0), byte_order="10")
    wrong = tmp_path / "wrong.ema"
    wrong.write_bytes(big.read_bytes().replace(b"ByteOrder 10", b"ByteOrder 01"))
    with pytest.raises(DataError, match=r"wrong\.ema: ByteOrder 01 says the frames are little-endian, but their "
                                        r"times read so are not a clock .* the header's ByteOrder is wrong, set "
                                        r"it to 10") as e:
        load_trial(wrong)
    assert e.value.item == "ByteOrder"


def test_one_mngu0_channel_name_does_not_rescale_a_mocha_file(tmp_path: Path) -> None:
    m = ff.motion(500.0)
    good = ff.write_mocha_est(tmp_path / "good.ema", m)
    mixed = tmp_path / "mixed.ema"
    mixed.write_bytes(good.read_bytes().replace(b"Channel_18 bn_x", b"Channel_18 bn_px"))
    with pytest.raises(DataError, match=r"mixed\.ema: the channels mix MOCHA-TIMIT's names in 1/100 mm .* and "
                                        r"mngu0's in mm \(bn_px\), so their unit cannot be told.*--units"):
        load_trial(mixed)
    # told the unit, it reads
    as_mm = load_trial(mixed, units="mm")
    np.testing.assert_allclose(as_mm.markers, 100 * load_trial(good).markers, rtol=1e-6)


# ------------------------------------------------------------------------------------ mview
def _rewrite_mview(path: Path, change) -> Path:  # type: ignore[no-untyped-def]
    """``change(name, signal, srate)`` -> (signal, srate) for each element of the file's struct."""
    import scipy.io

    var = path.stem
    arr = scipy.io.loadmat(path, squeeze_me=False, struct_as_record=True)[var]
    for k in range(arr.shape[1]):
        name = str(np.asarray(arr["NAME"][0, k]).ravel()[0]).strip()
        arr["SIGNAL"][0, k], arr["SRATE"][0, k] = change(name, arr["SIGNAL"][0, k], arr["SRATE"][0, k])
    scipy.io.savemat(path, {var: arr})
    return path


def test_an_mview_file_with_every_signal_transposed_reads_the_same(tmp_path: Path) -> None:
    m = ff.motion(100.0)
    want = load_trial(ff.write_mview(tmp_path / "a.mat", m))
    p = ff.write_mview(tmp_path / "t.mat", m)

    def transpose(name, sig, rate):  # type: ignore[no-untyped-def]
        return np.ascontiguousarray(sig.T), rate

    got = load_trial(_rewrite_mview(p, transpose))
    assert got.n_frames == m.times.size == want.n_frames and got.marker_names == want.marker_names
    np.testing.assert_allclose(got.markers, want.markers)
    assert any("stored as coordinates x frames (transposed)" in n for n in got.meta["notes"])


def test_mview_rate_and_length_errors_name_the_sensor_at_fault(tmp_path: Path) -> None:
    m = ff.motion(100.0)

    def nan_rate(name, sig, rate):  # type: ignore[no-untyped-def]
        return sig, (np.array([[np.nan]]) if name == "TR" else rate)  # TR: the first sensor

    with pytest.raises(DataError, match=r"sensor 'TR': SRATE nan is not a frame rate") as e:
        load_trial(_rewrite_mview(ff.write_mview(tmp_path / "r.mat", m), nan_rate))
    assert e.value.item == "TR"

    def short_first(name, sig, rate):  # type: ignore[no-untyped-def]
        return (sig[:-3] if name == "TR" else sig), rate

    with pytest.raises(DataError, match=r"sensor 'TR' \(\d+ frames at 100 Hz\) differ from the other 5 ") as e:
        load_trial(_rewrite_mview(ff.write_mview(tmp_path / "s.mat", m), short_first))
    assert e.value.item == "TR"


# ------------------------------------------------------------------------------ face markers
def _two_axis_csv(path: Path, markers: np.ndarray, axes: tuple[int, int]) -> Path:
    cols = ["time_s"] + [f"{n}_{a}" for n in ROLES for a in "xy"]
    rows = [",".join(cols)]
    for f in range(markers.shape[0]):
        rows.append(",".join([f"{f / 100:.4f}", *(repr(float(markers[f, j, k])) for j in range(len(ROLES))
                                                  for k in axes)]))
    path.write_text("\n".join(rows) + "\n")
    return path


def test_two_axis_face_markers_seen_from_the_front_are_refused(tmp_path: Path) -> None:
    # face_markers's head frame: x ear to ear, y up, z forwards (before its rigid motion)
    ch = true_channels(120)
    still = face_markers(ch, seed=1)
    head = np.zeros_like(still)
    head[:, 0] = (0.0, 0.0, 100.0)
    head[:, 1], head[:, 2] = (70.0, 0.0, 0.0), (-70.0, 0.0, 0.0)
    head[:, 3] = np.stack([np.zeros(120), -40 + ch["ULO"], ch["ULP"]], axis=1)
    head[:, 4] = np.stack([np.zeros(120), -40 - ch["LLO"], ch["LLP"]], axis=1)
    head[:, 5] = np.stack([ch["LR"] / 2, np.full(120, -40.0), np.full(120, 95.0)], axis=1)
    head[:, 6] = np.stack([-ch["LR"] / 2, np.full(120, -40.0), np.full(120, 95.0)], axis=1)
    head[:, 7] = np.stack([np.zeros(120), -ch["JO"], np.full(120, 100.0)], axis=1)
    front = load_trial(_two_axis_csv(tmp_path / "front.csv", head, (0, 1)))
    with pytest.raises(DataError, match=r"front\.csv: LC_L \(LC_L\) and LC_R \(LC_R\) are 50 mm apart in the "
                                        r"file's x and y plane: the markers were seen from the front"):
        front.channels()
    side = load_trial(_two_axis_csv(tmp_path / "side.csv", head, (2, 1)))  # forwards and up: a side view
    assert "JO" in side.channels()
    # a side view of a head turned 20 degrees: left and right no longer on one another, still a side view
    a = np.deg2rad(20.0)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    turned = load_trial(_two_axis_csv(tmp_path / "turned.csv", head @ turn.T, (2, 1)))
    assert "JO" in turned.channels()


# ------------------------------------------------------------------------------------ labels
def test_label_times_before_the_recording_are_refused(tmp_path: Path) -> None:
    p = tmp_path / "l.tsv"
    p.write_text("-0.5\t0.1\tsil\n0.1\t0.3\ta\n")
    with pytest.raises(DataError, match=r"l\.tsv, line 1: label 'sil' starts at -0.5 s: label times are seconds "
                                        r"from the start of the recording, never negative"):
        read_labels(p)


def test_an_mfa_textgrid_of_two_speakers_asks_which(tmp_path: Path) -> None:
    a = [(0.0, 0.2, ""), (0.2, 0.4, "P"), (0.4, 0.6, "AA1")]
    b = [(0.0, 0.3, ""), (0.3, 0.6, "M")]
    p = ff.write_textgrid(tmp_path / "two.TextGrid", [("spk1 - words", a), ("spk1 - phones", a),
                                              ("spk2 - words", b), ("spk2 - phones", b)])
    with pytest.raises(DataError, match=r"two\.TextGrid: 2 phone tiers \('spk1 - phones', 'spk2 - phones'; one "
                                        r"per speaker.*--tier 'spk1 - phones'"):
        read_labels(p)
    assert read_labels(p, tier="spk2 - phones").labels == ("", "M")


def test_an_empty_phones_tier_says_so(tmp_path: Path) -> None:
    p = ff.write_textgrid(tmp_path / "empty.TextGrid", [("words", [(0.0, 1.0, "")]), ("phones", [(0.0, 1.0, "")])])
    with pytest.raises(DataError, match=r"empty\.TextGrid: tier 'phones' holds no label \(1 empty interval"):
        read_labels(p)
    none = ff.write_textgrid(tmp_path / "none.TextGrid", [("words", [(0.0, 1.0, "")]), ("phones", [])])
    with pytest.raises(DataError, match=r"none\.TextGrid: tier 'phones' holds no label \(no interval\)"):
        read_labels(none)


# ------------------------------------------------------------------------ C3D and EMU hints
def test_c3d_point_scale_zero_is_named(tmp_path: Path) -> None:
    import ezc3d

    from test_io_markers import write_c3d

    p = tmp_path / "zero.c3d"
    write_c3d(p, face_markers(true_channels(50)), ROLES)
    c = ezc3d.c3d(str(p))
    c["parameters"]["POINT"]["SCALE"]["value"] = [0.0]
    c.write(str(p))
    with pytest.raises(DataError, match=r"zero\.c3d: POINT:SCALE is 0: .*fix POINT:SCALE") as e:
        load_trial(p)
    assert e.value.item == "POINT:SCALE"


def test_inspect_suggests_the_label_map_of_an_emu_bundle() -> None:
    code, text = run("inspect", EMU / "dfgspp_mo1_prosody_0020_bndl.json")
    assert code == 2 and "--label-map german_sampa" in text, text
    code, text = run("inspect", EMU / "dfgspp_mo1_prosody_0020_bndl.json", "--label-map", "german_sampa")
    assert code == 0, text


def test_speak_refuses_a_stretch_festival_would_ignore(tmp_path: Path) -> None:
    for stretch in ("0.05", "1e-300", "0.099"):
        code, text = run("speak", "ciao", "--stretch", stretch, "--out", tmp_path / "o")
        assert code == 2 and f"--stretch {float(stretch):g}" in text and "at least 0.1" in text, text
    assert not (tmp_path / "o").exists()


def test_a_folder_given_as_a_recording_is_named(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"is a folder, not a recording: give a file in it$"):
        load_trial(tmp_path)
    (tmp_path / "b_bndl").mkdir()
    (tmp_path / "b_bndl" / "b_annot.json").write_text("{}")
    with pytest.raises(DataError, match=r"b_bndl: is a folder, not a recording: give a file in it \(.*b_annot\.json "
                                        r"for this emuDB bundle\)"):
        load_trial(tmp_path / "b_bndl")


def test_a_tier_without_labels_to_take_it_from_is_refused() -> None:
    ema = EMU / "derived" / "dfgspp_mo1_prosody_0020_ema.csv"
    with pytest.raises(DataError, match=r"tier 'phones' was asked for, but no label file was given and this file "
                                        "carries no labels of its own"):
        load_trial(ema, tier="phones")
    code, text = run("inspect", ema, "--units", "furlong")
    assert code == 2 and "--units mm" in text, text
