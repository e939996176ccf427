"""Rhubarb Lip Sync's cues from the animation at 100 cues a second, whatever the frame rate: read back by a
parser written from Rhubarb's README (rhubarb_format.py), its minimum durations and tweens kept at 24,
30 and 60 fps, the sound's duration, the extended shapes chosen, TSV/JSON/XML/DAT."""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.runtime.errors import AnimationError
from coartic.runtime.exporters import RigOptions
from coartic.runtime.pipeline import RuntimeOutput, animate_file
from coartic.runtime.rhubarb import (
    MIN_CUE_CS,
    TWEENS,
    MouthCue,
    hold_minimum,
    insert_tweens,
    mouth_cues,
    parse_extended_shapes,
    parse_rhubarb_formats,
    rhubarb_dat,
)
from coartic.table import ParameterTable
from face_helpers import APAFULA, GROUND_TRUTH
from rhubarb_format import read_dat, read_json, read_tsv, read_xml

SOUND_S = 1.6137  # the WAV: Rhubarb's duration is 1.61, the frame grid's 1.625 at 24 fps, 1.6 at 30


def _wav(path: Path, seconds: float) -> Path:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes((2000 * np.sin(np.arange(int(seconds * 16000)) * 0.05)).astype("<i2").tobytes())
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[int, RuntimeOutput]:
    tmp = tmp_path_factory.mktemp("rhubarb")
    (tmp / "apafula.tsv").write_text(APAFULA)
    wav = _wav(tmp / "rec.wav", SOUND_S)
    table = ParameterTable.load(GROUND_TRUTH)
    return {fps: animate_file(tmp / "apafula.tsv", table, tmp / f"o{fps}", fps=fps, preview="none", audio=wav,
                              exports="rhubarb", rig=RigOptions(rhubarb_formats=("tsv", "json", "xml", "dat")))
            for fps in (24, 30, 60)}


def _is_tween(cues: list[MouthCue], k: int) -> bool:
    if not 0 < k < len(cues) - 1:
        return False
    rule = TWEENS.get((cues[k - 1].value, cues[k + 1].value))
    return rule is not None and rule[0] == cues[k].value


@pytest.mark.parametrize("fps", [24, 30, 60])
def test_rhubarb_files_keep_its_minimum_durations(runs: dict[int, RuntimeOutput], fps: int) -> None:
    files = runs[fps].files
    cues = read_tsv(files["rhubarb_tsv"].read_text(), 161)
    sound, duration, from_json = read_json(files["rhubarb_json"].read_text())
    assert (sound, duration) == ("apafula.wav", 161)  # the sound's 1.6137 s truncated, not the frames'
    sound_x, duration_x, from_xml = read_xml(files["rhubarb_xml"].read_text())
    assert (sound_x, duration_x) == (sound, duration)
    assert cues == from_json == from_xml
    for k, c in enumerate(cues):
        length = c.end_cs - c.start_cs
        # Rhubarb's minimum (7 cs), its in-betweens 4-8 cs; never a frame of 60 fps (1-2 cs)
        assert length >= MIN_CUE_CS or (_is_tween([MouthCue(x.start_cs, x.end_cs, x.value) for x in cues], k)
                                        and 4 <= length <= 8), (fps, k, c)
    dat = read_dat(files["rhubarb_dat"].read_text(), fps)
    firsts = {}
    for c in cues:
        firsts.setdefault(1 + int(fps * c.start_cs / 100 + 1e-9), c.value)
    assert dat[:-1] == list(firsts.items()) and dat[-1][1] == "X"
    # the shapes at the phonemes: idle before and after, closed at /p/, teeth on the lip at /f/
    # (0.70-0.82 s: most of it, not the frame or two where /f/ out-dominates the /u/ after it),
    # rounded at /u/, the tongue at /l/
    def at(cs: int) -> str:
        return next(c.value for c in cues if c.start_cs <= cs < c.end_cs)

    assert at(0) == "X" and at(160) == "X" and at(50) == "A" and at(90) in "EF" and at(102) == "H"
    g = sum(min(c.end_cs, 82) - max(c.start_cs, 70) for c in cues if c.value == "G" and c.end_cs > 70 and c.start_cs < 82)
    assert g >= 8, cues


def test_the_cues_do_not_follow_the_frame_grid(runs: dict[int, RuntimeOutput]) -> None:
    """At 24, 30 and 60 fps the same cues, centisecond for centisecond: the model is evaluated at
    every centisecond (Animation.resampled), not the frames interpolated (at 24 fps, whose frames
    are 4.2 cs apart, the /p/'s closure was measured at 0.48-0.59 s against 0.41-0.52 s)."""
    cues = {fps: mouth_cues(r.animation) for fps, r in runs.items()}
    assert cues[24] == cues[30] == cues[60]
    seg = runs[60].animation.segments

    def at(cs: int) -> str:
        return next(c.value for c in cues[24] if c.start_cs <= cs < c.end_cs)

    middles = [int((s + e) * 50) for s, e in zip(seg.starts, seg.ends)]
    assert [at(m) for m in middles] == list("XDADGFHDXX")[:len(middles)]
    files = {fps: runs[fps].files["rhubarb_tsv"].read_text() for fps in runs}
    assert files[24] == files[30] == files[60]


def test_resampling_evaluates_the_model_as_the_speaker_says_it(tmp_path: Path) -> None:
    # at its own rate without snapping, the resampled animation is the animation, a speaker's too
    (tmp_path / "apafula.tsv").write_text(APAFULA)
    table = ParameterTable.load(GROUND_TRUTH)
    table.metadata = {**(table.metadata or {}), "speakers": {"mode": "offset_scale", "column": "speaker",
                                                             "coefficients": {
        c: {"s1": {"offset_mm": 0.0, "scale": 1.0}, "s2": {"offset_mm": 0.5, "scale": 1.2}} for c in table.channels}}}
    for speaker in (None, "s2"):
        anim = animate_file(tmp_path / "apafula.tsv", table, tmp_path / f"o{speaker}", fps=25.0, preview="none",
                            snap_contacts=False, speaker=speaker).animation
        again = anim.resampled(25.0)
        assert again.neutral == anim.neutral and again.n_frames == anim.n_frames
        for c in anim.channels:
            np.testing.assert_allclose(again.channels[c], anim.channels[c], rtol=0, atol=1e-12)
        fine = anim.resampled(100.0)
        assert fine.n_frames == round(anim.sound_duration * 100) and fine.speaker is anim.speaker


def test_extended_shapes_as_rhubarb_chooses_them(runs: dict[int, RuntimeOutput]) -> None:
    anim = runs[30].animation
    basic = mouth_cues(anim, "")
    assert {c.value for c in basic} <= set("ABCDEF")
    assert basic[0].value == "A"  # X becomes A
    gx = mouth_cues(anim, "GX")
    assert "H" not in {c.value for c in gx} and "G" in {c.value for c in gx}
    assert parse_extended_shapes("xg") == "GX" and parse_extended_shapes("") == ""
    with pytest.raises(AnimationError, match="--extended-shapes 'GQ': Q is no extended shape"):
        parse_extended_shapes("GQ")
    with pytest.raises(AnimationError, match="--rhubarb-formats 'tsv,pdf': choose among tsv, json, xml, dat"):
        parse_rhubarb_formats("tsv,pdf")
    with pytest.raises(AnimationError, match="Rhubarb's DAT .* takes 24 to 100 fps; this animation has 12"):
        rhubarb_dat(basic, 161, 12.0, "")
    text = rhubarb_dat(basic, 161, 24.0, "", preston_blair=True)
    assert read_dat(text, 24.0, "", preston_blair=True)[-1][1] == "A" and "MBP" in text


def test_minimum_hold_and_tweens_by_rhubarb_rules() -> None:
    # a 3-cs closure between long open shapes takes 4 cs from them, the one before first
    held = hold_minimum([MouthCue(0, 20, "C"), MouthCue(20, 23, "A"), MouthCue(23, 40, "C")])
    assert held == [MouthCue(0, 16, "C"), MouthCue(16, 23, "A"), MouthCue(23, 40, "C")]
    # with no time to spare it joins the longer neighbour, and shapes alike merge
    held = hold_minimum([MouthCue(0, 8, "B"), MouthCue(8, 10, "A"), MouthCue(10, 16, "B")])
    assert held == [MouthCue(0, 16, "B")]
    # time is taken from the one after when the one before cannot spare it
    held = hold_minimum([MouthCue(0, 8, "B"), MouthCue(8, 10, "A"), MouthCue(10, 30, "B")])
    assert held == [MouthCue(0, 7, "B"), MouthCue(7, 14, "A"), MouthCue(14, 30, "B")]
    # D -> A: C early (a third of the D, at most 8 cs); D -> B: C centred; too short: none
    assert insert_tweens([MouthCue(0, 18, "D"), MouthCue(18, 40, "A")]) == [
        MouthCue(0, 12, "D"), MouthCue(12, 18, "C"), MouthCue(18, 40, "A")]
    assert insert_tweens([MouthCue(0, 40, "D"), MouthCue(40, 80, "B")]) == [
        MouthCue(0, 36, "D"), MouthCue(36, 44, "C"), MouthCue(44, 80, "B")]
    assert insert_tweens([MouthCue(0, 10, "D"), MouthCue(10, 40, "A")]) == [MouthCue(0, 10, "D"), MouthCue(10, 40, "A")]


def test_cli_writes_the_chosen_formats(tmp_path: Path) -> None:
    (tmp_path / "l.tsv").write_text(APAFULA)
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "l.tsv"), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "o"),
                                   "--preview", "none", "--export", "rhubarb", "--rhubarb-formats", "xml,dat",
                                   "--extended-shapes", "GX", "--preston-blair"])
    assert res.exit_code == 0, res.output
    names = {p.name for p in (tmp_path / "o").iterdir()}
    assert {"l.rhubarb.xml", "l.rhubarb.dat"} <= names and "l.rhubarb.tsv" not in names
    _, duration, cues = read_xml((tmp_path / "o" / "l.rhubarb.xml").read_text(), "GX")
    assert duration == 160 and "H" not in {c.value for c in cues}
    read_dat((tmp_path / "o" / "l.rhubarb.dat").read_text(), 25.0, "GX", preston_blair=True)
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "l.tsv"), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "p"),
                                   "--preview", "none", "--export", "rhubarb", "--extended-shapes", "Z"])
    assert res.exit_code == 2 and "--extended-shapes 'Z': Z is no extended shape" in res.output
