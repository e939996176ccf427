"""The runtime's limits and refusals: frame counts, FAP value range, face units, control characters
in text, and output paths that ffmpeg would misread (docs/LIMITS.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.runtime.animate import MAX_FRAMES, frame_times
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import FaceUnits, channels_to_faps
from coartic.runtime.pipeline import animate_file, speak_text
from coartic.table import CHANNELS

from test_runtime_animate import make_table

LABELS = "0\t0.1\tsil\n0.1\t0.2\ta\n0.2\t0.3\tsil\n"


def _run(args: list[str]) -> tuple[int, str]:
    r = CliRunner().invoke(app, args, env={"COLUMNS": "300"})
    return r.exit_code, " ".join(r.output.split())


def test_frame_count_limit(tmp_path: Path) -> None:
    assert frame_times(1.0, float(MAX_FRAMES)).size == MAX_FRAMES
    with pytest.raises(AnimationError, match=r"1 s at 1e\+09 fps is 1e\+09 frames, more than the 1000000"):
        frame_times(1.0, 1e9)
    table = tmp_path / "t.json"
    make_table().save(table)
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    code, out = _run(["animate", str(labels), "--table", str(table), "--out", str(tmp_path / "o"),
                      "--fps", "1e9", "--preview", "none"])
    assert code == 2 and "error:" in out and "more than the 1000000 an animation may have" in out
    labels.write_text("0\t0.1\tsil\n0.1\t1000000\ta\n")
    code, out = _run(["animate", str(labels), "--table", str(table), "--out", str(tmp_path / "p"),
                      "--preview", "none"])
    assert code == 2 and "1e+06 s at 25 fps is 2.5e+07 frames" in out


def test_fap_values_out_of_range_and_face_units(tmp_path: Path) -> None:
    neutral = {c: 0.0 for c in CHANNELS}
    chans = {c: np.zeros(3) for c in CHANNELS}
    chans["ULO"] = np.array([0.0, 1e20, 0.0])  # a target of 1e20 mm reached: wrapped to INT64_MIN before
    with pytest.raises(AnimationError, match=r"FAP 4 \(lower_t_midlip\) would be -3\.413e\+21 FAPU at frame 1 "
                                             r"\(ULO \+1e\+20 mm from the neutral face"):
        channels_to_faps(chans, neutral, FaceUnits(), "n", 25.0)
    with pytest.raises(AnimationError, match=r"face unit mns_mm = 1e-300 mm is not a face's"):
        FaceUnits(mns_mm=1e-300)
    table = tmp_path / "t.json"
    make_table().save(table)
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    code, out = _run(["animate", str(labels), "--table", str(table), "--out", str(tmp_path / "o"),
                      "--mns", "1e-300", "--preview", "none"])
    assert code == 2 and "error: face unit mns_mm = 1e-300 mm" in out


def test_speak_refuses_control_characters_before_festival(tmp_path: Path) -> None:
    with pytest.raises(AnimationError, match=r"control character '\\x00' at position 5"):
        speak_text("ciao\x00 mondo", make_table(), tmp_path / "o", festival="/nonexistent/festival")
    assert not (tmp_path / "o").exists()


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is installed by scripts/setup.sh")
@pytest.mark.parametrize("out", ["-odd", "take:2"])
def test_mp4_preview_into_paths_ffmpeg_would_misread(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     out: str) -> None:
    monkeypatch.chdir(tmp_path)  # relative names, as typed: "-odd" is an option to ffmpeg, "take:2" a protocol
    Path("l.tsv").write_text(LABELS)
    result = animate_file("l.tsv", make_table(), out, fps=10.0, preview="mp4")
    mp4 = Path(out) / "preview.mp4"
    assert result.files["preview"] == mp4
    assert mp4.stat().st_size > 1000 and mp4.read_bytes()[4:8] == b"ftyp"


def test_channels_png_work_is_bounded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from coartic.io.labels import Segments
    from coartic.runtime import raster
    from coartic.runtime.animate import Animation
    from coartic.runtime.preview import plot_channels

    lines: list[int] = []  # segment boundaries drawn, per call
    texts: list[str] = []
    vlines, text = raster.Tile.vlines, raster.text

    def counting_vlines(tile: raster.Tile, xs: np.ndarray, *args: object) -> None:
        lines.append(len(xs))
        vlines(tile, xs, *args)  # type: ignore[arg-type]

    def recording_text(draw: object, at: object, s: str, *args: object, **kw: object) -> None:
        texts.append(s)
        text(draw, at, s, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(raster.Tile, "vlines", counting_vlines)
    monkeypatch.setattr(raster, "text", recording_text)
    for n in (12, 3000):
        lines.clear()
        texts.clear()
        edges = np.linspace(0.0, n * 0.05, n + 1)
        seg = Segments(tuple("a" if i % 2 else "#" for i in range(n)), edges[:-1], edges[1:])
        times = np.arange(int(n * 0.05 * 25)) / 25
        anim = Animation(25.0, times, {c: np.sin(times) for c in CHANNELS}, seg)
        plot_channels(anim, tmp_path / f"c{n}.png", title="t")
        if n == 12:  # 11 boundaries on each of the 6 axes, the 6 labels /a/ above the first
            assert lines == [11] * 6 and texts.count("a") == 6 and "t" in texts
        else:
            assert lines == [] and "a" not in texts and "t   (3000 segments: boundaries and labels not drawn)" in texts


def test_a_frame_rate_at_which_no_phoneme_lasts_a_frame_is_refused(tmp_path: Path) -> None:
    # issue 21: --fps 1e-9 turned 0.8 s of speech into one frame "lasting" 1e9 s
    table = tmp_path / "t.json"
    make_table().save(table)
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    code, out = _run(["animate", str(labels), "--table", str(table), "--out", str(tmp_path / "o"),
                      "--fps", "1e-9", "--preview", "none"])
    assert code == 2 and "at 1e-09 fps a frame lasts 1e+09 s, longer than every phoneme" in out
    assert not (tmp_path / "o").exists()
