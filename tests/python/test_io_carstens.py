"""Carstens AG500/AG501 `.pos` files (coartic.io.carstens), written byte by byte from the format's
description by tests/python/format_fixtures.py: the header, the AG500 layout and its `.amp`
header, sensor names and role maps, unsolved samples, and every way such a file goes wrong."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import format_fixtures as ff
from coartic.cli import app
from coartic.io import DataError, load_trial
from coartic.io.registry import reader_for

ROLE_MAP = {"UL": "ch3", "LL": "ch4", "JAW": "ch5", "TT": "ch6", "TB": "ch7"}


def _channels(trial):  # type: ignore[no-untyped-def]
    ch = trial.channels()
    return {c: ch[c] for c in ("LA", "ULO", "LLO", "JO", "TTH")}


def test_ag501_header_names_rate_and_unplugged_channels(tmp_path: Path) -> None:
    m = ff.motion(250.0)
    p = ff.write_carstens_pos(tmp_path / "0001.pos", m)
    assert reader_for(p).name == "carstens-pos"
    t = load_trial(p)
    assert t.rate == 250.0 and t.n_frames == m.times.size and t.kind == "ema"
    assert t.marker_names[:6] == ("ch1", "ch2", "UL", "LL", "JAW", "TT") and len(t.marker_names) == 16
    notes = " ".join(t.meta["notes"])
    assert f"sensor names from {p.with_suffix('.sensors')}" in notes
    assert "not connected): ch1, ch2, ch9" in notes
    assert "sensors guessed by name (UL=UL, LL=LL, JAW=JAW" in notes
    assert "axes guessed from the sensors: up = +z, forwards = -x" in notes
    np.testing.assert_allclose(t.markers[:, 2, 2], m.sensors["UL"][:, 1], atol=1e-5)
    # the same file renamed (no extension) is found by its header
    plain = tmp_path / "sweep"
    plain.write_bytes(p.read_bytes())
    assert reader_for(plain).name == "carstens-pos"


def test_ag500_without_header_and_its_amp(tmp_path: Path) -> None:
    m = ff.motion(200.0)
    session = tmp_path / "session"
    (session / "pos").mkdir(parents=True)
    p = ff.write_carstens_pos(session / "pos" / "0007.pos", m, header=False, channels=12,
                              sensor_file=False)
    t = load_trial(p, role_map=ROLE_MAP)
    assert t.rate == 200.0 and len(t.marker_names) == 12
    assert "read as an AG500 file (12 channels at 200 Hz)" in " ".join(t.meta["notes"])
    with_names = load_trial(ff.write_carstens_pos(tmp_path / "named.pos", m, header=False,
                                                   channels=12))
    for c, v in _channels(with_names).items():  # role map or sensor file: the same channels
        np.testing.assert_allclose(_channels(t)[c], v, err_msg=c)
    # an AG501 sweep exported without its header: the .amp in ../amps/ gives channels and rate
    m250 = ff.motion(250.0)
    q = ff.write_carstens_pos(session / "pos" / "0008.pos", m250, header=False, channels=16,
                              sensor_file=False)
    (session / "amps").mkdir()
    amp = ff.write_carstens_pos(session / "amps" / "0008.amp", m250, channels=16, sensor_file=False)
    t = load_trial(q, role_map=ROLE_MAP)
    assert t.rate == 250.0 and len(t.marker_names) == 16
    assert f"16 channels at 250 Hz, from the header of {amp}" in " ".join(t.meta["notes"])
    with pytest.raises(DataError, match=r"0008\.amp: a Carstens amplitude file: .*give the \.pos "
                                        r"file of the same sweep \(0008\.pos"):
        load_trial(amp)


def test_unnamed_channels_say_how_to_name_them(tmp_path: Path) -> None:
    p = ff.write_carstens_pos(tmp_path / "0002.pos", ff.motion(250.0), sensor_file=False)
    with pytest.raises(DataError, match=r"0002\.pos: Carstens \.pos files do not name their "
                                        r"channels: write the names in .*0002\.sensors .*role map"):
        load_trial(p)
    r = CliRunner().invoke(app, ["inspect", str(p)], env={"COLUMNS": "200"})
    assert r.exit_code != 0 and "0002.sensors" in r.output and "Traceback" not in r.output
    t = load_trial(p, role_map=ROLE_MAP)
    assert "LA" in t.channels()


def test_unsolved_positions_become_gaps(tmp_path: Path) -> None:
    m = ff.motion(250.0)
    p = ff.write_carstens_pos(tmp_path / "0003.pos", m)
    raw = bytearray(p.read_bytes())
    head = raw.index(b"\x00\x1a") + 2
    frame = 16 * 7 * 4
    nan = np.array([np.nan] * 3, "<f4").tobytes()
    raw[head + 10 * frame + 2 * 28: head + 10 * frame + 2 * 28 + 12] = nan  # UL, frame 10: NaN
    raw[head + 11 * frame + 3 * 28: head + 11 * frame + 3 * 28 + 12] = bytes(12)  # LL, frame 11: 0
    p.write_bytes(bytes(raw))
    t = load_trial(p)
    assert np.isnan(t.markers[10, 2]).all() and np.isnan(t.markers[11, 3]).all()
    assert "positions not solved (NaN or all zero) set to NaN: UL 1, LL 1" in " ".join(t.meta["notes"])
    assert t.channels().valid["LA"][10:12].all()  # one-frame gaps filled as in every format


@pytest.mark.parametrize(("edit", "message"), [
    (lambda b: b[:-10], r"0004\.pos: \d+ bytes of frames are not whole frames of 16 channels x 7 "
                        r"values x 4 bytes = 448 bytes \(\d+ frames and 438 bytes; layout from its "
                        r"V002 header\): the file is cut short .*--allow-truncated"),
    (lambda b: b.replace(b"00000070", b"0000007x"), r"line 2: .*header's length in bytes"),
    (lambda b: b.replace(b"00000070", b"99999999"), r"line 2: .*length 99999999 bytes does not fit"),
    (lambda b: b.replace(b"NumberOfChannels=16", b"NumberOfChannels=0 "),
     r"NumberOfChannels=0 is not a channel count"),
    (lambda b: b.replace(b"SamplingFrequencyHz=250", b"SamplingFrequencyHz=nan"),
     r"SamplingFrequencyHz=nan is not finite"),
    (lambda b: b.replace(b"SamplingFrequencyHz=250", b"SamplingRateHz=250     "),
     r"no SamplingFrequencyHz= line"),
    (lambda b: b.replace(b"SamplingFrequencyHz=250", b"SamplingFrequencyHz 250"),
     r"line 4: .*is not KEY=VALUE"),
    (lambda b: b[:70], r"no frames \(layout from its V002 header\)"),
])
def test_broken_files_are_refused_by_name(tmp_path: Path, edit, message) -> None:  # type: ignore[no-untyped-def]
    p = ff.write_carstens_pos(tmp_path / "0004.pos", ff.motion(250.0))
    raw = p.read_bytes()
    assert raw.startswith(b"AG50xDATA_V002\n00000070\n")  # the header Carstens writes
    p.write_bytes(edit(raw))
    with pytest.raises(DataError, match=message):
        load_trial(p)


def test_truncated_file_read_on_request(tmp_path: Path) -> None:
    m = ff.motion(250.0)
    p = ff.write_carstens_pos(tmp_path / "0005.pos", m)
    p.write_bytes(p.read_bytes()[:-100])
    t = load_trial(p, allow_truncated=True)
    assert t.n_frames == m.times.size - 1
    assert "truncated: 348 bytes after the last whole frame left out" in t.meta["notes"]


@pytest.mark.parametrize(("text", "message"), [
    ("3 UL\n4 LL\n3 JAW\n", r"line 3: channel 3 is named twice \('UL' and 'JAW'\)"),
    ("3 UL\n40 LL\n", r"line 2: channel 40 is not one of the recording's channels 1 to 16"),
    ("3 UL\nLL\n", r"line 2: mixes numbered lines"),
    ("3 UL lip\n", r"line 1: '3 UL lip': write '<channel number> <name>'"),
    ("3 UL\n4 ul\n", r"sensor name 'UL' is given to two channels"),
    ("\n".join(f"s{k}" for k in range(17)) + "\n", r"line 17: 17 names for 16 channels"),
])
def test_sensor_file_errors(tmp_path: Path, text: str, message: str) -> None:
    p = ff.write_carstens_pos(tmp_path / "0006.pos", ff.motion(250.0))
    p.with_suffix(".sensors").write_text(text)
    with pytest.raises(DataError, match=re.escape("0006.sensors") + ".*" + message):
        load_trial(p)


def test_sensor_names_in_order_and_session_file(tmp_path: Path) -> None:
    m = ff.motion(250.0)
    (tmp_path / "pos").mkdir()
    p = ff.write_carstens_pos(tmp_path / "pos" / "0009.pos", m, sensor_file=False)
    (tmp_path / "sensors.txt").write_text("ref1 ref2 UL LL JAW TT TB TD".replace(" ", "\n") + "\n")
    t = load_trial(p)
    assert t.marker_names[:8] == ("ref1", "ref2", "UL", "LL", "JAW", "TT", "TB", "TD")
    assert t.marker_names[8:] == tuple(f"ch{k}" for k in range(9, 17))
