"""The rigs people have: ARKit blendshape weights, Meta visemes and Rhubarb mouth cues from one animation,
and the glTF's ARKit morph set (read back, and driven in three.js in headless Chromium)."""

from __future__ import annotations

import base64
import csv
import json
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.face.deform import default_rig
from coartic.face.gltf import arkit_morphs, read_glb
from coartic.runtime.animate import Animation, target_times
from coartic.runtime.errors import AnimationError
from coartic.runtime.exporters import parse_exports
from coartic.runtime.pipeline import RuntimeOutput, animate_file, speaker_face
from coartic.runtime.fap import animation_faps, blink_profile
from coartic.runtime.rigs import (
    ARKIT_BASIS,
    ARKIT_DRIVEN,
    ARKIT_NAMES,
    JAW_OPEN_MM,
    VISEMES,
    arkit_channels,
    arkit_weights,
    viseme_weights,
)
from coartic.runtime.rhubarb import shape_at
from coartic.table import ParameterTable
from face_helpers import APAFULA, GROUND_TRUTH, THREE



@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RuntimeOutput:
    tmp = tmp_path_factory.mktemp("rigs")
    (tmp / "apafula.tsv").write_text(APAFULA)
    return animate_file(tmp / "apafula.tsv", ParameterTable.load(GROUND_TRUTH), tmp / "o", preview="none",
                        exports="arkit,visemes,rhubarb", gltf=True, gltf_morphs="arkit")


def _frame_at_target(anim: Animation, phoneme: str, channel: str = "LLO", nth: int = 0) -> int:
    assert anim.table is not None
    i = [k for k, p in enumerate(anim.segments.labels) if p == phoneme][nth]
    return int(round(target_times(anim.table, anim.segments, channel)[i] * anim.fps))


def test_arkit_csv_and_json_carry_all_52_names(run: RuntimeOutput) -> None:
    with run.files["arkit_csv"].open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["frame", "time", *ARKIT_NAMES]
    assert len(rows) == run.animation.n_frames + 1
    doc = json.loads(run.files["arkit_json"].read_text())
    assert doc["facsNames"] == list(ARKIT_NAMES) and doc["numPoses"] == 52
    assert doc["numFrames"] == run.animation.n_frames and doc["exportFps"] == 25.0
    w = np.array(doc["weightMat"])
    np.testing.assert_array_equal(w, np.array([[float(x) for x in r[2:]] for r in rows[1:]]))
    assert w.min() >= 0.0 and w.max() <= 1.0
    # what coartic does not drive stays at 0; what it drives moves
    driven = [ARKIT_NAMES.index(n) for n in ARKIT_DRIVEN]
    others = [k for k in range(52) if k not in driven]
    assert not w[:, others].any()
    # the blinks are the FAP file's: the same schedule (the first comes 0.6 s in)
    np.testing.assert_array_equal(w[:, ARKIT_NAMES.index("eyeBlinkLeft")], blink_profile(run.animation.times))
    for name in ("jawOpen", "mouthPressLeft", "mouthRollLower", "mouthPucker", "mouthLowerDownLeft", "eyeBlinkRight"):
        assert w[:, ARKIT_NAMES.index(name)].max() > 0.1, name


def test_arkit_weights_at_the_phonemes(run: RuntimeOutput) -> None:
    anim = run.animation
    w = arkit_weights(anim)
    col = {n: w[:, k] for k, n in enumerate(ARKIT_NAMES)}
    p, a = _frame_at_target(anim, "p"), _frame_at_target(anim, "a", nth=2)
    f, u = _frame_at_target(anim, "f"), _frame_at_target(anim, "u", "LR")
    assert col["mouthPressLeft"][p] > 0.5 and col["mouthPressLeft"][a] == 0.0
    assert col["jawOpen"][a] > 0.3 > col["jawOpen"][p]
    assert col["mouthRollLower"][f] == 1.0  # the lower lip drawn under the teeth, fully as the rig rolls it
    # an open vowel's lips are drawn back a little but do not roll (issue 26: 0.27 at /a/ before)
    assert col["mouthRollLower"][a] == 0.0 and col["mouthRollUpper"][a] == 0.0
    # /f/ lifts the lower lip to the teeth on its own, no press of both lips (which hid the incisors)
    assert col["mouthShrugLower"][f] > 0.05 and col["mouthPressLeft"][f] < 0.05
    assert col["mouthPucker"][u] + col["mouthFunnel"][u] > 0.3 > col["mouthPucker"][a] + col["mouthFunnel"][a]
    np.testing.assert_array_equal(col["mouthStretchLeft"], col["mouthStretchRight"])  # symmetric channels


def test_arkit_weights_decompose_jaw_and_lip_opening(run: RuntimeOutput) -> None:
    """The basis rebuilds the jaw and the lips' opening exactly wherever no weight saturates."""
    anim = run.animation
    w = arkit_weights(anim)
    back = arkit_channels(w)
    d = {c: anim.channels[c] - anim.neutral[c] for c in anim.channels}
    ok = (w < 1.0).all(axis=1) & (d["JO"] >= 0.0)
    assert ok.sum() > anim.n_frames // 2
    np.testing.assert_allclose(back["JO"][ok], d["JO"][ok], atol=1e-9)
    np.testing.assert_allclose((back["ULO"] + back["LLO"])[ok], (d["ULO"] + d["LLO"])[ok], atol=1e-9)
    # a wide mouth that is not rounded (no protrusion either) is all stretch
    rounded = w[:, ARKIT_NAMES.index("mouthPucker")] + w[:, ARKIT_NAMES.index("mouthFunnel")]
    wide = (d["LR"] > 0) & ok & (rounded == 0)
    assert wide.sum() > 5
    np.testing.assert_allclose(back["LR"][wide], d["LR"][wide], atol=1e-9)
    # the jaw saturates at JAW_OPEN_MM
    loud = anim.channels["JO"] + 3 * JAW_OPEN_MM
    big = Animation(anim.fps, anim.times, {**anim.channels, "JO": loud}, anim.segments, neutral=anim.neutral,
                    table=anim.table)
    assert arkit_weights(big)[:, ARKIT_NAMES.index("jawOpen")].min() == 1.0


def test_visemes_from_dominance(run: RuntimeOutput) -> None:
    anim = run.animation
    doc = json.loads(run.files["visemes_json"].read_text())
    assert doc["visemes"] == list(VISEMES) == ["sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa",
                                               "E", "ih", "oh", "ou"]
    w = np.array(doc["weights"])
    np.testing.assert_allclose(w, viseme_weights(anim))
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    assert w.min() >= 0.0

    def top(k: int) -> str:
        return VISEMES[int(np.argmax(w[k]))]

    assert top(0) == "sil" and top(anim.n_frames - 1) == "sil"
    assert top(_frame_at_target(anim, "p")) == "PP"
    assert top(_frame_at_target(anim, "f")) == "FF"
    assert top(_frame_at_target(anim, "a", nth=1)) == "aa"
    assert top(_frame_at_target(anim, "u")) == "ou"
    # coarticulation: the /p/ is already in the frames of the /a/ before it
    a0 = _frame_at_target(anim, "a")
    assert 0.0 < w[a0, VISEMES.index("PP")] < w[a0, VISEMES.index("aa")]


def test_rhubarb_shapes_at_the_phonemes(run: RuntimeOutput) -> None:
    """The default files (TSV, JSON) are written; the formats: test_runtime_rhubarb.py."""
    anim = run.animation
    assert {"rhubarb_tsv", "rhubarb_json"} <= set(run.files)
    times = anim.times
    shapes = shape_at(anim, times)
    assert shapes[0] == "X" and shapes[-1] == "X"
    assert shapes[_frame_at_target(anim, "p")] == "A"
    assert shapes[_frame_at_target(anim, "f")] == "G"
    assert shapes[_frame_at_target(anim, "u", "LR")] in ("E", "F")
    assert shapes[_frame_at_target(anim, "a", nth=2)] in ("C", "D")
    assert "H" in shapes


def test_a_phoneme_without_viseme_is_named(run: RuntimeOutput) -> None:
    anim = run.animation
    labels = list(anim.segments.labels)
    labels[labels.index("l")] = "@@"
    odd = Animation(anim.fps, anim.times, anim.channels, anim.segments.with_labels(labels), neutral=anim.neutral,
                    table=anim.table)
    with pytest.raises(AnimationError, match="'@@' has no Meta viseme"):
        viseme_weights(odd)


def test_long_utterances_take_the_nearby_segments(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Shares from the segments within SHARE_MARGIN_S of a block of frames equal those from all of
    them (to 1e-6), block by block: a long file costs frames x nearby segments."""
    import coartic.runtime.animate as animate_mod
    import coartic.runtime.rigs as rigs_mod

    rng = np.random.default_rng(3)
    phones = ["a", "p", "i", "f", "u", "t", "a", "m", "l", "s"]
    t, rows = 0.0, ["0.0 0.3 #"]
    t = 0.3
    for k in range(60):  # 60 phones, about 6 s of speech
        d = float(rng.uniform(0.06, 0.16))
        rows.append(f"{t:.4f} {t + d:.4f} {phones[k % len(phones)]}")
        t += d
    rows.append(f"{t:.4f} {t + 0.3:.4f} #")
    (tmp_path / "long.tsv").write_text("\n".join(rows) + "\n")
    anim = animate_file(tmp_path / "long.tsv", ParameterTable.load(GROUND_TRUTH), tmp_path / "o", preview="none").animation
    near = viseme_weights(anim)
    assert anim.segment_shares("LLO", 0, 10)[:, 40:].max() == 0.0  # far segments are not computed
    monkeypatch.setattr(animate_mod, "SHARE_MARGIN_S", 1e9)
    monkeypatch.setattr(rigs_mod, "SHARE_FRAMES", 7)
    every = viseme_weights(anim)
    np.testing.assert_allclose(near, every, atol=1e-6)


def test_export_names_are_checked() -> None:
    assert parse_exports("rhubarb, arkit") == ("arkit", "rhubarb")
    assert parse_exports(None) == ()
    with pytest.raises(AnimationError, match="--export fbx: unknown; choose among arkit, visemes, rhubarb"):
        parse_exports("arkit,fbx")


def test_cli_export_and_arkit_gltf(tmp_path: Path) -> None:
    (tmp_path / "l.tsv").write_text(APAFULA)
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "l.tsv"), "-t", str(GROUND_TRUTH), "-o",
                                   str(tmp_path / "o"), "--preview", "none", "--export", "rhubarb",
                                   "--gltf-morphs", "arkit"])
    assert res.exit_code == 0, res.output
    names = {p.name for p in (tmp_path / "o").iterdir()}
    assert {"l.rhubarb.json", "l.rhubarb.tsv", "l.glb"} <= names and "l.arkit.csv" not in names
    assert "channels.png" not in names  # --preview none: no pictures, no matplotlib
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "l.tsv"), "-t", str(GROUND_TRUTH), "-o",
                                   str(tmp_path / "p"), "--preview", "none", "--gltf-morphs", "blendshapes"])
    assert res.exit_code == 2 and "--gltf-morphs 'blendshapes': choose fap, arkit, eight" in res.output


def test_arkit_gltf_morph_set(run: RuntimeOutput) -> None:
    doc, _ = read_glb(run.files["gltf"])
    assert doc["meshes"][0]["extras"]["targetNames"] == list(ARKIT_NAMES)
    gl = pygltflib.GLTF2().load(str(run.files["gltf"]))
    assert gl is not None and len(gl.meshes[0].primitives[0].targets) == 52
    rig = default_rig()
    neutral = run.animation.neutral
    names, fields = arkit_morphs(rig, neutral, speaker_face(ParameterTable.load(GROUND_TRUTH)))
    chin = rig.mesh.feature_points["2.1"]
    jaw = fields[names.index("jawOpen")]
    assert jaw[chin, 1] < -10.0  # mm: the chin drops
    assert not fields[names.index("eyeLookUpLeft")].any()
    lid = fields[names.index("eyeBlinkLeft")]
    assert np.linalg.norm(lid, axis=1).max() > 5.0  # the lid shuts (mm)
    # a Left/Right pair adds up to the symmetric movement, each side mostly on its own half
    left, right = fields[names.index("mouthStretchLeft")], fields[names.index("mouthStretchRight")]
    corner_l, corner_r = rig.mesh.feature_points["2.4"], rig.mesh.feature_points["2.5"]
    assert left[corner_l, 0] > 5.0 and abs(left[corner_r, 0]) < 1e-9
    assert right[corner_r, 0] < -5.0 and abs(right[corner_l, 0]) < 1e-9


def test_arkit_face_follows_the_fap_face(run: RuntimeOutput) -> None:
    """Posed by its ARKit weights, the ARKit-named face is where the FAP face is: the same lips,
    jaw and blinks up to the linear blend of the jaw's, lids' and lower lip's turns and what a
    blendshape cannot follow (the lip roll that fades as the lip opens). The tongue is left out:
    ARKit has no shape for it inside the mouth."""
    anim = run.animation
    table = ParameterTable.load(GROUND_TRUTH)
    rig = default_rig()
    face = speaker_face(table)
    names, fields = arkit_morphs(rig, anim.neutral, face)
    fap_pose = rig.pose(rig.weights(animation_faps(anim, face, "x")))
    ark_pose = rig.mesh.vertices + np.tensordot(arkit_weights(anim), fields, axes=(1, 0))
    for part, within in (("skin", 3.0), ("lower_teeth", 1.0), ("eyelids", 2.0)):
        sel = rig.mesh.in_part(part)
        moved = np.linalg.norm(fap_pose[:, sel] - rig.mesh.vertices[sel], axis=2).max()
        off = np.linalg.norm(fap_pose[:, sel] - ark_pose[:, sel], axis=2)
        assert moved > 5.0, part  # a part that moves ...
        assert off.max() < within, part  # ... and the ARKit face follows it (mm)
        assert np.median(off.max(axis=1)) < 0.5 * within, part


def test_three_js_retargets_the_arkit_glb_by_name(run: RuntimeOutput, tmp_path: Path) -> None:
    """three.js (Debian libjs-three) in headless Chromium: the morph targets carry ARKit's names,
    and setting jawOpen to 1 by name moves the chin down (three.js's own morph arithmetic)."""
    from coartic.face.viewer import chromium_program

    if not (THREE / "examples/js/loaders/GLTFLoader.js").is_file():
        pytest.skip("three.js (Debian package libjs-three, installed by scripts/setup.sh) is not installed")
    chromium = chromium_program()
    b64 = base64.b64encode(run.files["gltf"].read_bytes()).decode()
    page = tmp_path / "arkit.html"
    page.write_text(f"""<html><body><pre id="out">pending</pre>
<script src="{(THREE / 'three.min.js').as_uri()}"></script>
<script src="{(THREE / 'examples/js/loaders/GLTFLoader.js').as_uri()}"></script>
<script>
const buf = Uint8Array.from(atob("{b64}"), c => c.charCodeAt(0)).buffer;
new THREE.GLTFLoader().parse(buf, "", gltf => {{
  const out = {{}};
  gltf.scene.traverse(o => {{
    if (!o.isMesh) return;
    const g = o.geometry, pos = g.attributes.position, k = o.morphTargetDictionary["jawOpen"];
    const morph = g.morphAttributes.position[k], rel = g.morphTargetsRelative === true;
    o.morphTargetInfluences.fill(0);
    o.morphTargetInfluences[k] = 1.0;
    // three.js's morph arithmetic on the CPU: relative targets add, absolute ones blend
    let lowest0 = Infinity, lowest1 = Infinity, moved = 0;
    for (let i = 0; i < pos.count; i++) {{
      const y0 = pos.getY(i);
      const y1 = rel ? y0 + o.morphTargetInfluences[k] * morph.getY(i)
                     : y0 + o.morphTargetInfluences[k] * (morph.getY(i) - y0);
      lowest0 = Math.min(lowest0, y0); lowest1 = Math.min(lowest1, y1);
      moved = Math.max(moved, Math.abs(y1 - y0));
    }}
    out[o.name || Object.keys(out).length] = {{names: Object.keys(o.morphTargetDictionary), lowest0, lowest1, moved}};
  }});
  document.getElementById("out").textContent = JSON.stringify(out);
}}, err => {{ document.getElementById("out").textContent = "ERROR " + err; }});
</script></body></html>""")
    dom = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'p'}",
                          "--virtual-time-budget=5000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=60).stdout
    text = dom[dom.index('<pre id="out">') + len('<pre id="out">'):dom.index("</pre>")]
    assert not text.startswith(("ERROR", "pending")), text
    meshes = json.loads(text)
    assert meshes
    for got in meshes.values():
        assert got["names"] == list(ARKIT_NAMES)
    # the skin (the mesh reaching lowest: the chin) drops by more than a centimetre
    skin = min(meshes.values(), key=lambda m: m["lowest0"])
    assert skin["lowest1"] < skin["lowest0"] - 0.01
    assert skin["moved"] > 0.01


def test_a_table_without_pause_is_named_before_any_export(tmp_path: Path) -> None:
    from coartic.runtime.errors import MissingPhonemeError
    from coartic.runtime.fap import FaceUnits

    table = ParameterTable.load(GROUND_TRUTH)
    del table.values["#"]
    (tmp_path / "l.tsv").write_text("0 0.2 a\n0.2 0.3 p\n0.3 0.5 a\n")
    with pytest.raises(MissingPhonemeError, match="has no pause phoneme '#': its targets are the neutral face"):
        animate_file(tmp_path / "l.tsv", table, tmp_path / "o", preview="none", face=FaceUnits(30.0, 50.0),
                     exports="arkit")
