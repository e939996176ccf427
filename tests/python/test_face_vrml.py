"""VRML97 export of the face (coartic.face.vrml): animated with interpolators, and single frames."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.face.deform import default_rig
from coartic.face.vrml import write_face_vrml
from coartic.io.labels import read_labels
from coartic.runtime.animate import target_times
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import read_fap
from coartic.table import ParameterTable

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
LABELS = "start\tend\tlabel\n0.0\t0.20\t#\n0.20\t0.36\ta\n0.36\t0.44\tp\n0.44\t0.60\ta\n0.60\t0.76\t#\n"


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("vrml")
    (tmp / "apa.tsv").write_text(LABELS)
    out = tmp / "out"
    res = CliRunner().invoke(app, ["animate", str(tmp / "apa.tsv"), "-t", str(GROUND_TRUTH), "-o", str(out),
                                   "--preview", "none", "--vrml"])
    assert res.exit_code == 0, res.output
    return out


def block(text: str, start: str) -> np.ndarray:
    """The numbers of the bracketed field that follows `start`."""
    i = text.index(start)
    body = text[text.index("[", i) + 1:text.index("]", i)]
    return np.array([float(x) for x in re.split(r"[\s,]+", body.strip())])


def test_animated_world_keys_every_frame(run: Path) -> None:
    text = (run / "apa.wrl").read_text()
    assert text.startswith("#VRML V2.0 utf8\n")
    faps = read_fap(run / "apa.fap")
    rig = default_rig()
    n_skin = int(rig.mesh.in_part("skin").sum())
    keys = block(text, "DEF skin_motion CoordinateInterpolator")
    assert keys.size == faps.n_frames and keys[0] == 0 and (np.diff(keys) > 0).all() and keys[-1] < 1
    values = block(text, "keyValue").reshape(faps.n_frames, n_skin, 3)
    want = rig.pose(rig.weights(faps))[:, rig.mesh.in_part("skin")] * 0.001
    np.testing.assert_allclose(values, want, atol=1e-6)  # printed to the micrometre
    assert "ROUTE clock.fraction_changed TO skin_motion.set_fraction" in text
    assert "ROUTE skin_motion.value_changed TO skin_coord.set_point" in text
    # the skull does not move: no interpolator for the upper teeth or the eyes
    assert "upper_teeth_motion" not in text and "eyes_motion" not in text
    assert "lower_teeth_motion" in text


def test_single_frames_show_lips_closed_and_open(run: Path) -> None:
    faps = read_fap(run / "apa.fap")
    segs = read_labels(run / "segments.tsv")
    frames = np.rint(target_times(ParameterTable.load(GROUND_TRUTH), segs, "LLO") * 25).astype(int)
    p, a = int(frames[2]), int(frames[1])
    files = write_face_vrml(run / "snap.wrl", faps, frames=[p, a])
    assert [f.name for f in files] == [f"snap_f{p}.wrl", f"snap_f{a}.wrl"]
    rig = default_rig()
    slit = rig.mesh.slit
    gaps = []
    for f in files:
        skin = block(f.read_text(), "coord DEF skin_coord Coordinate").reshape(-1, 3)
        gaps.append((skin[slit[:, 0], 1] - skin[slit[:, 1], 1]) * 1000)
    assert gaps[0].max() <= 0.0  # /p/: lips touch along the whole cut
    assert gaps[1][gaps[1].size // 2] > 8.0  # /a/: open
    with pytest.raises(AnimationError, match="outside"):
        write_face_vrml(run / "x.wrl", faps, frames=[faps.n_frames])


def test_the_loop_lasts_as_long_as_the_sound(run: Path) -> None:
    """With its WAV, the world loops every len(WAV) s (53 frames at 25 fps against 2.109 s of sound
    used to loop every 2.12 s and drift 11 ms a cycle); frames past the sound's end are not keyed."""
    from coartic.face.vrml import vrml_text

    rig = default_rig()
    weights = rig.weights(read_fap(run / "apa.fap"))[:19]
    text = vrml_text(rig, weights, 25.0, "apa", audio="apa.wav", audio_seconds=0.709)
    assert re.search(r"cycleInterval 0\.709 loop TRUE", text)
    keys = block(text, "DEF skin_motion CoordinateInterpolator")
    assert keys.size == 18  # frame 18 starts at 0.72 s, after the sound
    np.testing.assert_allclose(keys, np.arange(18) / 25 / 0.709, atol=1e-6)
    assert 'AudioClip { url [ "apa.wav" ] loop TRUE }' in text
    with pytest.raises(AnimationError, match="sound's length"):
        vrml_text(rig, weights, 25.0, "apa", audio="apa.wav", audio_seconds=0.0)


def test_a_long_animation_is_refused_before_any_text(tmp_path: Path) -> None:
    from coartic.face.vrml import VRML_MAX_FRAMES, vrml_text

    rig = default_rig()
    with pytest.raises(AnimationError, match="export chosen frames"):
        vrml_text(rig, np.zeros((VRML_MAX_FRAMES + 1, rig.targets.shape[0])), 25.0, "long")


def test_castle_engine_reads_the_world(run: Path) -> None:
    """tovrmlx3d (Debian view3dscene) parses VRML97 with its node and field types and converts it to
    X3D; it reports an error in the file (shown here on a broken one) as a warning on stderr."""
    if shutil.which("tovrmlx3d") is None:
        pytest.skip("tovrmlx3d (Debian package view3dscene, installed by scripts/setup.sh) is not on PATH")

    def problems(path: Path) -> list[str]:
        proc = subprocess.run(["tovrmlx3d", str(path), "--encoding", "xml"], capture_output=True, text=True,
                              timeout=60)
        assert proc.returncode == 0
        return [ln for ln in proc.stderr.splitlines() if ln.startswith("tovrmlx3d:")] + (
            [] if "<CoordinateInterpolator" in proc.stdout or "<IndexedFaceSet" in proc.stdout else ["empty"])

    assert problems(run / "apa.wrl") == []
    broken = run / "broken.wrl"
    broken.write_text((run / "apa.wrl").read_text().replace("coordIndex [", "coordIndex [ ]", 1))
    assert problems(broken)
