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
