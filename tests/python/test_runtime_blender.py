"""coartic.runtime.blender_keys: coartic's ARKit and viseme curves keyed onto an existing rig's shape keys.
Its logic (reading the files, matching names, the keys at the scene's rate) in plain Python; the script
itself in Blender (`blender --background --python`) where Blender is installed."""

from __future__ import annotations

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import coartic.runtime.blender_keys as bk
from coartic.runtime.exporters import RigOptions
from coartic.runtime.pipeline import RuntimeOutput, animate_file
from coartic.runtime.rigs import ARKIT_NAMES, RPM_VISEMES, VISEMES, arkit_weights
from coartic.table import ParameterTable
from face_helpers import APAFULA, GROUND_TRUTH


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RuntimeOutput:
    tmp = tmp_path_factory.mktemp("blender")
    (tmp / "apafula.tsv").write_text(APAFULA)
    return animate_file(tmp / "apafula.tsv", ParameterTable.load(GROUND_TRUTH), tmp / "o", preview="none",
                        exports="arkit,visemes")


def test_the_script_needs_only_the_standard_library_and_bpy() -> None:
    """Blender's Python has neither NumPy nor coartic: the script must not import them."""
    tree = ast.parse(Path(bk.__file__).read_text(encoding="utf-8"))
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert names - {"__future__", "bpy"} <= set(sys.stdlib_module_names), names


def test_reads_every_curves_file_coartic_writes(run: RuntimeOutput) -> None:
    ark_json, ark_csv = bk.read_curves(run.files["arkit_json"]), bk.read_curves(run.files["arkit_csv"])
    assert ark_json.names == ark_csv.names == ARKIT_NAMES and ark_json.fps == ark_csv.fps == 25.0
    np.testing.assert_array_equal(np.array(ark_json.weights), arkit_weights(run.animation))
    np.testing.assert_array_equal(np.array(ark_csv.weights), np.array(ark_json.weights))
    vis = bk.read_curves(run.files["visemes_json"])
    assert vis.names == VISEMES and len(vis.weights) == run.animation.n_frames


def test_bad_curves_files_are_named(tmp_path: Path) -> None:
    (tmp_path / "x.json").write_text('{"fps": 25}')
    with pytest.raises(bk.CurvesError, match="x.json: neither coartic's ARKit JSON"):
        bk.read_curves(tmp_path / "x.json")
    (tmp_path / "y.json").write_text('{"visemes": ["a", "b"], "fps": 25, "weights": [[0.1, 0.2], [0.3]]}')
    with pytest.raises(bk.CurvesError, match="frame 1 has 1 weights for 2 shapes"):
        bk.read_curves(tmp_path / "y.json")
    (tmp_path / "z.csv").write_text("a,b\n1,2\n")
    with pytest.raises(bk.CurvesError, match="z.csv, line 1: expected the header 'frame,time,<shape>...'"):
        bk.read_curves(tmp_path / "z.csv")


def test_names_match_the_rigs_conventions() -> None:
    # Meta's names onto Ready Player Me's keys; onto VRChat's; ARKit's onto a rig that capitalises
    rpm_keys = ["Basis_extra", *RPM_VISEMES]
    got, left = bk.match_shape_keys(VISEMES, rpm_keys)
    assert got["sil"] == "viseme_sil" and got["aa"] == "viseme_aa" and got["PP"] == "viseme_PP" and left == []
    assert (got["ih"], got["oh"], got["ou"]) == ("viseme_I", "viseme_O", "viseme_U")
    got, left = bk.match_shape_keys(("aa", "PP"), ["vrc.v_aa", "vrc.v_pp"])
    assert got == {"aa": "vrc.v_aa", "PP": "vrc.v_pp"} and left == []
    got, left = bk.match_shape_keys(("jawOpen", "eyeBlinkLeft"), ["JawOpen", "Blink_L"], {"eyeBlinkLeft": "Blink_L"})
    assert got == {"jawOpen": "JawOpen", "eyeBlinkLeft": "Blink_L"}
    with pytest.raises(bk.CurvesError, match="--map names shape key\\(s\\) Nope"):
        bk.match_shape_keys(("jawOpen",), ["JawOpen"], {"jawOpen": "Nope"})
    with pytest.raises(bk.CurvesError, match="shape key\\(s\\) jawopen matched by several curves"):
        bk.match_shape_keys(("jawOpen", "JAWOPEN"), ["jawopen"])


def test_keys_at_the_scenes_rate_within_tolerance(run: RuntimeOutput) -> None:
    curves = bk.read_curves(run.files["arkit_json"])
    jaw = [row[ARKIT_NAMES.index("jawOpen")] for row in curves.weights]
    keys = bk.keyframes(jaw, 25.0, 24.0, 1.0, tolerance=1e-3)
    xs, ys = np.array([k[0] for k in keys]), np.array([k[1] for k in keys])
    frames = 1.0 + np.arange(len(jaw)) * 24.0 / 25.0  # frame k of 25 fps at its time in a 24-fps scene
    assert xs[0] == 1.0 and xs[-1] == pytest.approx(frames[-1])
    assert np.abs(xs[:, None] - frames[None, :]).min(axis=1).max() < 1e-9  # keys on the curve's frames
    assert np.abs(np.interp(frames, xs, ys) - np.array(jaw)).max() <= 1e-3
    assert len(keys) < len(jaw)  # the straight runs are not keyed frame by frame
    assert bk.keyframes([0.0] * 40, 25.0, 25.0, 1.0) == [(1.0, 0.0), (40.0, 0.0)]
    p = bk.plan(curves, ["jawOpen", "mouthClose", "Other"], 24.0, 1.0)
    assert set(p.keys) == {"jawOpen", "mouthClose"} and len(p.unmatched) == 50
    with pytest.raises(bk.CurvesError, match="no shape key for .* \\(--strict\\)"):
        bk.plan(curves, ["jawOpen"], 24.0, 1.0, strict=True)
    with pytest.raises(bk.CurvesError, match="matches a shape key of the object"):
        bk.plan(curves, ["Key 1"], 24.0, 1.0)
    assert bk.script_args(["blender", "-b", "--python", "x.py", "--", "a.json", "--object", "Face"]) == [
        "a.json", "--object", "Face"]


BLENDER_RIG = """
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_plane_add()
obj = bpy.context.active_object
obj.name = "Face"
obj.shape_key_add(name="Basis")
for n in ("JawOpen", "mouthFunnel", "viseme_aa"):
    obj.shape_key_add(name=n)
bpy.context.scene.render.fps = 24
bpy.ops.wm.save_as_mainfile(filepath=r"{path}")
"""
BLENDER_READ = """
import bpy, json
obj = bpy.data.objects["Face"]
fcs = obj.data.shape_keys.animation_data.action.fcurves
print("KEYS " + json.dumps({fc.data_path: [list(k.co) for k in fc.keyframe_points] for fc in fcs}))
"""


def test_keys_a_rig_in_blender(run: RuntimeOutput, tmp_path: Path) -> None:
    blender = shutil.which("blender")
    if blender is None:
        pytest.skip("Blender is not installed (Debian's blender, optional and not installed by scripts/setup.sh: "
                    "apt-get install blender); the script's logic is tested above in plain Python")
    rig, keyed = tmp_path / "rig.blend", tmp_path / "keyed.blend"
    (tmp_path / "make.py").write_text(BLENDER_RIG.format(path=rig))
    subprocess.run([blender, "--background", "--factory-startup", "--python-exit-code", "1", "--python", str(tmp_path / "make.py")], check=True,
                   capture_output=True, timeout=120)
    res = subprocess.run([blender, "--background", str(rig), "--python-exit-code", "1", "--python", bk.__file__, "--",
                          str(run.files["arkit_json"]), "--object", "Face", "--save", str(keyed)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    (tmp_path / "read.py").write_text(BLENDER_READ)
    out = subprocess.run([blender, "--background", str(keyed), "--python-exit-code", "1", "--python", str(tmp_path / "read.py")],
                         capture_output=True, text=True, timeout=120, check=True).stdout
    keys = json.loads(next(line for line in out.splitlines() if line.startswith("KEYS "))[5:])
    jaw = np.array(keys['key_blocks["JawOpen"].value'])
    curves = bk.read_curves(run.files["arkit_json"])
    truth = [row[ARKIT_NAMES.index("jawOpen")] for row in curves.weights]
    frames = 1.0 + np.arange(len(truth)) * 24.0 / 25.0
    assert np.abs(np.interp(frames, jaw[:, 0], jaw[:, 1]) - np.array(truth)).max() <= 2e-4
    assert 'key_blocks["mouthFunnel"].value' in keys and 'key_blocks["viseme_aa"].value' not in keys
