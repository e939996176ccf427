"""The runtime's pictures drawn with Pillow alone (coartic.runtime.raster, preview): no matplotlib
in `animate` / `speak` with their default pictures, ticks as matplotlib places them, and faces
that show what the channels say."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from coartic.io.labelmap import LabelMap
from coartic.io.labels import read_labels
from coartic.runtime import raster
from coartic.runtime.animate import animate
from coartic.runtime.preview import SKIN, _frames, _front_box, _grid, face_frames, mouth_shape
from coartic.table import CHANNELS

from test_runtime_animate import LABELS, make_table

ROOT = Path(__file__).resolve().parents[2]


def test_default_pictures_import_no_matplotlib(tmp_path: Path) -> None:
    # matplotlib's import alone cost speak 0.3 s of CPU for 2 s of speech (bench/results/speak_pictures.txt)
    (tmp_path / "l.tsv").write_text(LABELS)
    make_table().save(tmp_path / "t.json")
    code = ("import sys; from coartic.runtime.pipeline import animate_file; from coartic.table import ParameterTable; "
            f"r = animate_file({str(tmp_path / 'l.tsv')!r}, ParameterTable.load({str(tmp_path / 't.json')!r}), "
            f"{str(tmp_path / 'o')!r}, preview='gif'); "
            "assert {'plot', 'strip', 'preview'} <= set(r.files), r.files; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(ROOT / "python"), "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
    for name in ("channels.png", "strip.png", "preview.gif"):
        with Image.open(tmp_path / "o" / name) as im:
            assert im.size[0] > 300


@pytest.mark.parametrize("lo, hi, room", [(-2.2, 2.6, 5), (-3.5, 13.2, 5), (114.5, 125.5, 5), (97.0, 100.3, 5),
                                         (-0.104, 2.184, 9), (0.0, 2.1, 9), (41.0, 53.5, 4), (0.0, 1e-3, 9),
                                         (-5.9, 16.4, 3), (1234.0, 1236.0, 6)])
def test_ticks_are_matplotlibs(lo: float, hi: float, room: int) -> None:
    ticker = pytest.importorskip("matplotlib.ticker")
    expect = ticker.MaxNLocator(nbins=room, steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
    expect = expect[(expect >= lo - 1e-9) & (expect <= hi + 1e-9)]
    np.testing.assert_allclose(raster.ticks(lo, hi, room), expect, atol=1e-12)


def test_tick_labels() -> None:
    assert raster.tick_labels(np.array([-2.0, -1.0, 0.0, 1.0])) == ["\u22122", "\u22121", "0", "1"]
    assert raster.tick_labels(np.array([115.0, 117.5, 120.0])) == ["115.0", "117.5", "120.0"]
    assert raster.tick_labels(np.array([0.0, 0.25, 0.5])) == ["0.00", "0.25", "0.50"]
    assert raster.tick_labels(np.array([0.0, 0.5, 1.0])) == ["0.0", "0.5", "1.0"]


def _mouth_pixels(frame: Image.Image, box: tuple[int, int, int, int]) -> int:
    # the mouth opening's dark red-brown (MOUTH) within the front view
    a = np.asarray(frame.crop(box)).astype(int)
    return int(((a[..., 0] < 80) & (a[..., 1] < 40) & (a[..., 2] < 50)).sum())


def test_the_face_opens_at_a_and_closes_at_p(tmp_path: Path) -> None:
    (tmp_path / "l.tsv").write_text(LABELS)
    anim = animate(make_table(), LabelMap.model().apply(read_labels(tmp_path / "l.tsv")), 25.0)
    frames = list(_frames(anim, anim.neutral, "t"))
    assert len(frames) == anim.n_frames and frames[0].size == (512, 320)
    gap = np.array([mouth_shape({c: float(anim.channels[c][k]) for c in CHANNELS}, anim.neutral).aperture
                    for k in range(anim.n_frames)])
    box = _front_box(_grid((512, 320))[0], anim.neutral)
    front = (round(box.x0) + 1, round(box.y0) + 1, round(box.x1) - 1, round(box.y1) - 1)  # inside the spines
    dark = np.array([_mouth_pixels(f, front) for f in frames])
    assert (gap <= 0).any() and (gap > 5).any()
    assert (dark[gap <= 0] == 0).all()  # lips together (the pause, /p/): no opening drawn
    assert (dark[gap > 5] > 300).all()  # /a/: a wide one
    k_open = int(np.argmax(gap))
    # the skin and the lips are drawn in their colours, anti-aliased edges in between
    a = np.asarray(frames[k_open])
    skin = np.array(raster.rgb(SKIN))
    assert (np.abs(a - skin).sum(axis=2) == 0).sum() > 20000
    alone = next(face_frames(anim, anim.neutral, 200))
    assert alone.size == (400, 200)
