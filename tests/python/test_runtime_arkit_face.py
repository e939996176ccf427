"""The ARKit-named glTF, posed by coartic's own ARKit weights, looks like the FAP glTF at every viseme:
both rendered by `coartic view` in real headless Chromium (software WebGL), close up on the mouth,
at the target frame of a phoneme of each of Meta's visemes that Italian has (TH has none)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from coartic.face.viewer import write_page
from coartic.runtime.animate import Animation, animate, target_times
from coartic.runtime.exporters import ExportSettings, run_exports
from coartic.runtime.pipeline import speaker_face
from coartic.runtime.rigs import PHONEME_VISEME
from coartic.runtime.shipped import load_shipped_table
from coartic.io.labels import Segments
from face_helpers import Chromium, mouth_opening, mouth_pixels, shared_chromium

# one phoneme of every viseme but TH, each between /a/s (the shipped table has every Italian phoneme)
PHONES = "# a p a f a t a k a tS a s a n a r a e i o u l a v a m u f u #".split()
# the first of each viseme's phonemes is photographed; /v/ and /f/ after /u/ too (the lip's roll
# out of a rounded vowel)
SHOTS = ("p", "f", "t", "k", "tS", "s", "n", "r", "a", "e", "i", "o", "u", "l", "v")
SIZE = 300


def utterance() -> Segments:
    starts, ends, t = [], [], 0.0
    for p in PHONES:
        d = 0.3 if p == "#" else 0.16 if p in "aeiou" else 0.1
        starts.append(t)
        ends.append(t + d)
        t += d
    return Segments(tuple(PHONES), np.array(starts), np.array(ends))


browser = pytest.fixture(scope="module")(shared_chromium)


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory, browser: Chromium) -> dict[str, dict[str, Path]]:
    tmp = tmp_path_factory.mktemp("arkit_face")
    table = load_shipped_table()
    anim: Animation = animate(table, utterance(), 25.0)
    pages = {}
    for morphs in ("fap", "arkit"):  # one animation, handed to the exporters twice
        out = tmp / morphs
        run_exports(anim, ExportSettings(out=out, name="v", face=speaker_face(table), table=table, gltf_morphs=morphs),
                    ["channels", "fap", "segments", "gltf"])
        pages[morphs] = write_page(out)
    frames = np.rint(target_times(table, anim.segments, "LLO") * anim.fps).astype(int)
    labels = list(anim.segments.labels)
    wanted = {ph: int(frames[labels.index(ph)]) for ph in SHOTS}
    wanted["f_after_u"] = int(frames[len(labels) - 3])
    # one page's pictures after the other: the shared Chromium draws each next frame of the page on
    # the screen without loading it again
    png = {m: {ph: browser.screenshot(pages[m], tmp / f"{m}_{ph}.png", frame=k, face_only=SIZE, size=(SIZE, SIZE),
                                      zoom=2.5) for ph, k in wanted.items()} for m in pages}
    return {ph: {m: png[m][ph] for m in pages} for ph in wanted}


def test_every_viseme_of_the_arkit_face_is_the_fap_face(shots: dict[str, dict[str, Path]]) -> None:
    """Measured (300 x 300 close-ups): pixels off by more than 40 of 255 at most 0.68 % (0.2 % median),
    tooth pixels within 11 %, cavity pixels within 15 px or 3 %, the lips' opening within 6 px. The
    mapping before (every lip retraction a roll, presses from either lip alone, rounding from the
    narrowing alone) failed each: 1.6 % of the pixels off at /f/ after /u/, the cavity of /f v/
    halved (the incisors hidden), /o u/ 22 and 14 % fewer teeth and 9 and 8 px less open.

    /f/ after /u/: its corners are still narrowed while the lower lip rolls in under the incisors.
    ARKit has no narrowing without protrusion, so the rounding gives way to the roll: the incisors
    show as on the FAP face (7 % fewer tooth pixels, the slit 4 px open against 7; with the rounding
    kept, 17 % fewer and 1 px), the corners are wider (182 cavity pixels at the corners against 16,
    1.1 % of the pixels off)."""
    for ph, pair in shots.items():
        img = {m: np.asarray(Image.open(p).convert("RGB"), dtype=np.int16) for m, p in pair.items()}
        assert img["fap"].std() > 10, ph  # a face, not a blank canvas
        differ = float((np.abs(img["arkit"] - img["fap"]).max(axis=2) > 40).mean())
        assert differ < (0.012 if ph == "f_after_u" else 0.008), (ph, differ)
        px = {m: {k: int(v.sum()) for k, v in mouth_pixels(p).items()} for m, p in pair.items()}
        fap, ark = px["fap"], px["arkit"]
        assert abs(ark["teeth"] - fap["teeth"]) <= 0.12 * fap["teeth"], (ph, px)
        if ph != "f_after_u":  # the wider corners show the mouth's inside there (above)
            assert abs(ark["dark"] - fap["dark"]) <= max(20, 0.15 * fap["dark"]), (ph, px)
        opening = {m: mouth_opening(p) for m, p in pair.items()}
        assert abs(opening["arkit"] - opening["fap"]) <= max(3.0, 0.35 * opening["fap"]), (ph, opening)
    # the labiodentals show the upper incisors over the lower lip in both faces
    for ph in ("f", "v"):
        for m in ("fap", "arkit"):
            assert mouth_pixels(shots[ph][m])["teeth"].sum() > 1100, (ph, m)
