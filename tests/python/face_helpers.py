"""What the face and rig tests share: the synthetic ground-truth table, Debian's three.js (r111,
the one the viewer and the glTF checks load) and one utterance that shows every kind of mouth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
THREE = Path("/usr/share/javascript/three")
# "# a p a f u l a #": a closure, a labiodental, a rounded vowel, a lateral, an open vowel (and a
# blink: the face's first is at 0.6 s)
APAFULA = """0.00 0.30 #
0.30 0.45 a
0.45 0.55 p
0.55 0.70 a
0.70 0.82 f
0.82 0.98 u
0.98 1.06 l
1.06 1.24 a
1.24 1.60 #
"""


def mouth_pixels(png: Path) -> dict[str, np.ndarray]:
    """Masks of lip-coloured, tooth-coloured and dark (mouth cavity) pixels."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    return {"lip": (img[..., 0] - img[..., 1] > 70) & (img[..., 0] > 100),
            "teeth": (img.min(axis=-1) > 170) & (img.max(axis=-1) - img.min(axis=-1) < 45),
            "dark": img.max(axis=-1) < 70}


def mouth_opening(png: Path) -> float:
    """Median over the central columns of the lips of the non-lip pixels between the top and the
    bottom lip pixel: 0 when the lips touch, the mouth's height in pixels when open."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    lip = (img[..., 0] - img[..., 1] > 70) & (img[..., 0] > 100)
    ys, xs = np.nonzero(lip)
    assert xs.size > 200, "no lips in the picture"
    x0, x1 = int(xs.min()), int(xs.max())
    centre, half = (x0 + x1) // 2, (x1 - x0) // 6
    gaps = []
    for x in range(centre - half, centre + half + 1):
        col = np.nonzero(lip[:, x])[0]
        gaps.append(0 if col.size == 0 else int(col.max() - col.min() + 1 - col.size))
    return float(np.median(gaps))


def upper_face(png: Path, eyes: tuple[int, int, int] | None = None) -> dict[str, float]:
    """The brows' height and the eyes' opening in a front view of the face (`coartic view
    --face-only`, the whole head in the picture): `sclera`, the eye-white pixels above the nose (the
    lids cover more of the eyes, fewer); `brow`, the mean row of the dark (brow-coloured) pixels in a
    band above the eyes (smaller: higher), its inner and outer thirds as `brow_inner`, `brow_outer`.
    `eyes` = (left eye's column, right eye's, the eyes' top row) of a reference picture (the
    neutral face's, `eyes_of`), so that every picture is measured in the same band; the band reaches
    30 mm above the eyes (the pixels' scale from the eyes' 64 mm apart) and the brows' 30 mm across."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    white = _eye_white(img)  # the teeth are white too
    cl, cr, top = eyes if eyes is not None else eyes_of(png)
    mm = abs(cl - cr) / 64.0
    dark = img.max(axis=-1) < 130
    rows = np.arange(img.shape[0])[:, None]
    band = (rows >= top - 30 * mm) & (rows <= top - 1.5 * mm)
    out: dict[str, float] = {"sclera": float(white.sum())}
    cols = np.arange(img.shape[1])[None, :]
    sides = [(c, 1 if c > (cl + cr) / 2 else -1) for c in (cl, cr)]
    for name, lo, hi in (("brow", -15.0, 15.0), ("brow_inner", -15.0, -5.0), ("brow_outer", 5.0, 15.0)):
        # the brow's inner third is the one nearer the other eye
        near = np.zeros(img.shape[:2], dtype=bool)
        for c, s in sides:
            off = (cols - c) * s  # mm... in pixels, outwards from the face's midline positive
            near |= (off >= lo * mm) & (off <= hi * mm)
        ys, _ = np.nonzero(dark & band & near)
        assert ys.size > 20 or name != "brow", f"{png}: no brows above the eyes"
        out[name] = float(ys.mean()) if ys.size else float("nan")  # a third may be too pale in a small picture
    return out


def _eye_white(img: np.ndarray) -> np.ndarray:
    """Eye-white pixels in the upper part of the picture (the teeth are white too, lower down; the
    viewer's background is a bluish grey: blue above red; the eyes are 20-30 % down a face-only
    picture at zoom 1.1-1.4)."""
    white: np.ndarray = (img.min(axis=-1) > 170) & (img.max(axis=-1) - img.min(axis=-1) < 45) & (img[..., 0] >= img[..., 2])
    white[int(0.45 * img.shape[0]):] = False
    white[:int(0.12 * img.shape[0])] = False  # the hair's edge against the background, at the top
    # nor the head's outline, where the background blends into the skin: 4 pixels off the background
    near = background = (img[..., 2] - img[..., 0] >= 4) & (img.min(axis=-1) > 200)
    for axis in (0, 1):
        for shift in range(-4, 5):
            near = near | np.roll(background, shift, axis=axis)
    return white & ~near


def eyes_of(png: Path) -> tuple[int, int, int]:
    """(left eye's column, right eye's column, the eyes' top row) in a front view: where the eye
    whites are, each side of the picture's middle."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    white = _eye_white(img)
    ys, xs = np.nonzero(white)
    assert xs.size > 40, f"{png}: no eyes in the picture"
    mid = img.shape[1] / 2
    return int(xs[xs > mid].mean()), int(xs[xs < mid].mean()), int(ys.min())
