"""glTF 2.0 export of the animated face: structure, validation, read-back (coartic.face.gltf) and the
runtime's --gltf, --audio, --fap-name and frame-rate warnings."""

from __future__ import annotations

import shutil
import subprocess
import wave
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.face.deform import TARGET_NAMES, default_rig
from coartic.face.gltf import (
    GltfError,
    accessor_array,
    check_glb_bytes,
    glb_bytes,
    read_glb,
    split_signs,
    write_face_glb,
)
from coartic.face.mesh import PART_NAMES
from coartic.runtime.fap import read_fap
from coartic.runtime.festival import wav_duration

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
LABELS = "start\tend\tlabel\n0.0\t0.20\t#\n0.20\t0.36\ta\n0.36\t0.44\tp\n0.44\t0.60\ta\n0.60\t0.68\tm\n0.68\t0.86\ta\n0.86\t1.00\t#\n"


def write_wav(path: Path, seconds: float, rate: int = 16000) -> Path:
    t = np.arange(int(seconds * rate)) / rate
    samples = (8000 * np.sin(2 * np.pi * 220 * t)).astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(samples.tobytes())
    return path


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`coartic animate LABELS --audio WAV --fap-name base --gltf` once for the module."""
    tmp = tmp_path_factory.mktemp("gltf")
    labels = tmp / "apama.tsv"
    labels.write_text(LABELS)
    wav = write_wav(tmp / "recording.wav", 1.1)
    out = tmp / "out"
    res = CliRunner().invoke(app, ["animate", str(labels), "--table", str(GROUND_TRUTH), "--out", str(out),
                                   "--preview", "none", "--audio", str(wav), "--fap-name", "base", "--gltf"])
    assert res.exit_code == 0, res.output
    return out


def test_animate_writes_fap_wav_and_glb_under_one_name(run: Path) -> None:
    assert {"base.fap", "base.wav", "base.glb"} <= {p.name for p in run.iterdir()}
    assert not list(run.glob(".*.tmp-*"))
    faps = read_fap(run / "base.fap")
    assert faps.name == "base"
    # the animation lasts as long as the recording, not the labels (1.0 s)
    assert faps.n_frames == round(wav_duration(run / "base.wav") * 25) == 28
    doc, _ = read_glb(run / "base.glb")
    assert doc["asset"]["extras"]["audio"] == "base.wav"
    assert doc["asset"]["extras"]["fap_file"] == "base.fap"
    assert doc["asset"]["extras"]["fps"] == 25.0


def test_glb_reads_back_with_pygltflib(run: Path) -> None:
    """An independent reader sees one mesh with a primitive per part, a morph target per FAP (and
    two for the jaw), and a weights animation that reproduces the face of every frame."""
    g = pygltflib.GLTF2().load(str(run / "base.glb"))
    assert g.asset.version == "2.0"
    (mesh,) = g.meshes
    assert [p.extras["part"] for p in mesh.primitives] == list(PART_NAMES)
    rig = default_rig()
    faps = read_fap(run / "base.fap")
    names, _, expected = split_signs(TARGET_NAMES, rig.targets, rig.weights(faps))
    assert mesh.extras["targetNames"] == names
    assert names[:3] == ["lower_t_midlip", "lower_t_midlip_neg", "raise_b_midlip"]
    # every signed field twice, the four turns' 1 - cos θ once
    assert len(names) == 2 * len(TARGET_NAMES) - 6 and "raise_tongue_tip" in names and "close_t_l_eyelid_sin" in names
    # pygltflib's document as a dict, once: each to_dict() rebuilds it (0.3 CPU-s)
    blob = g.binary_blob()
    doc: dict[str, Any] = g.to_dict()
    for p in mesh.primitives:  # smooth normals, unit length
        normals = accessor_array(doc, blob, p.attributes.NORMAL)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert all(len(p.targets) == len(names) for p in mesh.primitives)
    (anim,) = g.animations
    (channel,) = anim.channels
    assert channel.target.path == "weights" and channel.target.node == 0
    sampler = anim.samplers[channel.sampler]
    assert sampler.interpolation == "LINEAR"
    times = accessor_array(doc, blob, sampler.input)
    weights = accessor_array(doc, blob, sampler.output).reshape(times.size, len(names))
    np.testing.assert_allclose(times, np.arange(faps.n_frames) / 25.0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(weights, expected, atol=1e-6)
    assert weights.min() >= 0.0 and weights.max() <= 1.0  # what Blender's importer keeps unclamped
    # sparse targets: a lip FAP moves a few hundred of the skin's vertices
    moved = doc["accessors"][mesh.primitives[0].targets[0]["POSITION"]]["sparse"]["count"]
    assert 50 < moved < 0.5 * doc["accessors"][mesh.primitives[0].attributes.POSITION]["count"]
    # the skin at the /a/ of 0.28 s, rebuilt from the file: base positions + Σ weight × target (metres)
    skin = mesh.primitives[0]
    k = 7
    pos = accessor_array(doc, blob, skin.attributes.POSITION).astype(float)
    for j, target in enumerate(skin.targets):
        pos += weights[k, j] * accessor_array(doc, blob, target["POSITION"])
    want = rig.pose(rig.weights(faps)[k])[rig.mesh.in_part("skin")] * 0.001
    np.testing.assert_allclose(pos, want, atol=2e-7)
    # and the lips are apart there (upper minus lower copy on the cut, mm)
    slit = rig.mesh.slit
    assert (pos[slit[:, 0], 1] - pos[slit[:, 1], 1]).max() * 1000 > 8.0


def test_glb_passes_gltfpack_validation(run: Path, tmp_path: Path) -> None:
    """Debian's gltfpack loads through cgltf's validator and refuses invalid files (checked below)."""
    if shutil.which("gltfpack") is None:
        pytest.skip("gltfpack (Debian package, installed by scripts/setup.sh) is not on PATH")
    ok = subprocess.run(["gltfpack", "-i", str(run / "base.glb"), "-o", str(tmp_path / "ok.glb")],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    doc, blob = read_glb(run / "base.glb")
    doc["accessors"][doc["meshes"][0]["primitives"][0]["indices"]]["count"] += 3  # indices overrun their view
    bad = tmp_path / "bad.glb"
    bad.write_bytes(glb_bytes(doc, blob))
    refused = subprocess.run(["gltfpack", "-i", str(bad), "-o", str(tmp_path / "no.glb")], capture_output=True, text=True)
    assert refused.returncode != 0
    with pytest.raises(GltfError, match="overrun"):
        check_glb_bytes(bad.read_bytes(), "bad.glb")


def _mutations() -> list[tuple[str, Any]]:
    def drop_target(d: dict[str, Any]) -> None:
        d["meshes"][0]["primitives"][2]["targets"].pop()

    def bad_index(d: dict[str, Any]) -> None:
        d["meshes"][0]["primitives"][0]["indices"] = 10_000

    def wrong_bounds(d: dict[str, Any]) -> None:
        d["accessors"][d["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["max"][1] += 0.01

    def weights_count(d: dict[str, Any]) -> None:
        d["accessors"][d["animations"][0]["samplers"][0]["output"]]["count"] -= 1

    def path(d: dict[str, Any]) -> None:
        d["animations"][0]["channels"][0]["target"]["path"] = "morph"

    def version(d: dict[str, Any]) -> None:
        d["asset"]["version"] = "1.0"

    return [("morph targets", drop_target), ("does not exist", bad_index), ("min/max", wrong_bounds),
            ("weights for", weights_count), ("unknown path", path), ("version", version)]


@pytest.mark.parametrize(("message", "mutate"), _mutations(), ids=[m for m, _ in _mutations()])
def test_structural_check_names_each_breach(run: Path, message: str, mutate: Any) -> None:
    doc, blob = read_glb(run / "base.glb")
    mutate(doc)
    with pytest.raises(GltfError, match=message):
        check_glb_bytes(glb_bytes(doc, blob), "x.glb")


def test_structural_check_refuses_a_truncated_file(run: Path) -> None:
    data = (run / "base.glb").read_bytes()
    with pytest.raises(GltfError, match="header says"):
        check_glb_bytes(data[:-4], "cut.glb")


def test_write_face_glb_from_a_fap_file(run: Path, tmp_path: Path) -> None:
    faps = read_fap(run / "base.fap")
    path = write_face_glb(tmp_path / "again.glb", faps)
    doc, _ = read_glb(path)
    assert doc["asset"]["extras"]["audio"] is None
    assert (tmp_path / "again.glb").read_bytes() == path.read_bytes()


def test_labels_longer_than_the_audio_are_refused(tmp_path: Path) -> None:
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    wav = write_wav(tmp_path / "short.wav", 0.5)
    res = CliRunner().invoke(app, ["animate", str(labels), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "o"),
                                   "--preview", "none", "--audio", str(wav)])
    assert res.exit_code == 2
    assert "labels run to 1.000 s" in res.output and "short.wav" in res.output


def test_audio_that_is_not_a_wav_is_refused(tmp_path: Path) -> None:
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    fake = tmp_path / "speech.wav"
    fake.write_bytes(b"ID3 not a wav at all")
    res = CliRunner().invoke(app, ["animate", str(labels), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "o"),
                                   "--preview", "none", "--audio", str(fake)])
    assert res.exit_code == 2
    assert "not a PCM WAV" in res.output


@pytest.mark.parametrize(("fps", "expect"), [("30", "Greta plays FAP files at 25 fps"),
                                             ("29.97", "not a whole number"), ("25", None)])
def test_frame_rate_warnings(tmp_path: Path, fps: str, expect: str | None) -> None:
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    res = CliRunner().invoke(app, ["animate", str(labels), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "o"),
                                   "--preview", "none", "--fps", fps])
    assert res.exit_code == 0, res.output
    if expect is None:
        assert "warning:" not in res.output
    else:
        assert "warning:" in res.output and expect in " ".join(res.output.split())


def test_fap_name_must_be_one_word(tmp_path: Path) -> None:
    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    res = CliRunner().invoke(app, ["animate", str(labels), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "o"),
                                   "--preview", "none", "--fap-name", "two words"])
    assert res.exit_code == 2
    assert "one ASCII word" in res.output


THREE = Path("/usr/share/javascript/three")


def test_three_js_loads_and_plays_the_glb(run: Path, tmp_path: Path) -> None:
    """three.js (Debian libjs-three, r111) and its GLTFLoader in headless Chromium: the morph targets
    get their FAP names, and its AnimationMixer at frame 7 gives the weights coartic computed."""
    import base64
    import json

    from coartic.face.viewer import chromium_program

    if not (THREE / "examples/js/loaders/GLTFLoader.js").is_file():
        pytest.skip("three.js (Debian package libjs-three, installed by scripts/setup.sh) is not installed")
    chromium = chromium_program()
    b64 = base64.b64encode((run / "base.glb").read_bytes()).decode()
    page = tmp_path / "three.html"
    page.write_text(f"""<html><body><pre id="out">pending</pre>
<script src="{(THREE / 'three.min.js').as_uri()}"></script>
<script src="{(THREE / 'examples/js/loaders/GLTFLoader.js').as_uri()}"></script>
<script>
const buf = Uint8Array.from(atob("{b64}"), c => c.charCodeAt(0)).buffer;
new THREE.GLTFLoader().parse(buf, "", gltf => {{
  const mixer = new THREE.AnimationMixer(gltf.scene);
  mixer.clipAction(gltf.animations[0]).play();
  mixer.setTime(7 / 25);
  const meshes = [];
  gltf.scene.traverse(o => {{ if (o.isMesh) meshes.push({{dict: o.morphTargetDictionary, w: Array.from(o.morphTargetInfluences)}}); }});
  document.getElementById("out").textContent = JSON.stringify({{meshes, duration: gltf.animations[0].duration}});
}}, err => {{ document.getElementById("out").textContent = "ERROR " + err; }});
</script></body></html>""")
    dom = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'p'}",
                          "--virtual-time-budget=5000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=60).stdout
    text = dom[dom.index('<pre id="out">') + len('<pre id="out">'):dom.index("</pre>")]
    assert not text.startswith(("ERROR", "pending")), text
    got = json.loads(text)
    assert len(got["meshes"]) == len(PART_NAMES)  # one three.js mesh per primitive (part)
    faps = read_fap(run / "base.fap")
    assert got["duration"] == pytest.approx((faps.n_frames - 1) / 25, abs=1e-6)
    rig = default_rig()
    names, _, weights = split_signs(TARGET_NAMES, rig.targets, rig.weights(faps))
    want = weights[7]
    for mesh in got["meshes"]:
        assert list(mesh["dict"]) == names
        np.testing.assert_allclose(mesh["w"], want, atol=1e-6)


def test_animate_audio_is_the_mp4_sound_track(tmp_path: Path) -> None:
    """--audio puts the user's recording into the MP4 preview, as long as the video."""
    import json

    labels = tmp_path / "l.tsv"
    labels.write_text(LABELS)
    wav = write_wav(tmp_path / "rec.wav", 1.1)
    out = tmp_path / "o"
    res = CliRunner().invoke(app, ["animate", str(labels), "-t", str(GROUND_TRUTH), "-o", str(out),
                                   "--preview", "mp4", "--audio", str(wav)])
    assert res.exit_code == 0, res.output
    probe = subprocess.run(["ffprobe", "-v", "error", "-show_streams", "-of", "json", str(out / "preview.mp4")],
                           capture_output=True, text=True, check=True)
    streams = {s["codec_type"]: s for s in json.loads(probe.stdout)["streams"]}
    assert set(streams) == {"video", "audio"}
    assert int(streams["video"]["nb_frames"]) == 28
    assert abs(float(streams["audio"]["duration"]) - 1.1) <= 1 / 25
    assert (out / "l.wav").read_bytes() == wav.read_bytes()


BLENDER_SCRIPT = """
import bpy, json, sys
path, out = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.context.scene.render.fps = 25
# import_shading FLAT: Debian's Blender 3.4.1 fails on numpy >= 1.24 (np.bool) when it guesses shading
bpy.ops.import_scene.gltf(filepath=path, import_shading="FLAT")
ob = [o for o in bpy.data.objects if o.type == "MESH"][0]
keys = ob.data.shape_keys
res = {"names": [k.name for k in keys.key_blocks[1:]], "w": {}, "co": {}}
for k in (7, 14):
    bpy.context.scene.frame_set(k)
    res["w"][k] = [kb.value for kb in keys.key_blocks[1:]]
    me = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    res["co"][k] = [list(v.co) for v in me.vertices]
json.dump(res, open(out, "w"))
"""


def test_blender_imports_and_plays_the_glb(run: Path, tmp_path: Path) -> None:
    """Blender's own glTF importer: one object, a shape key per target under its name, and at two
    frames (one with negative FAPs) the evaluated mesh is coartic's face. Blender is not installed
    by scripts/setup.sh (hundreds of MB); the test runs where it is (docs/FACE.md gives the result)."""
    import json

    blender = shutil.which("blender")
    if blender is None:
        pytest.skip("Blender is not installed (optional: apt-get install blender python3-numpy)")
    script = tmp_path / "check.py"
    script.write_text(BLENDER_SCRIPT)
    out = tmp_path / "blender.json"
    proc = subprocess.run([blender, "-b", "--factory-startup", "--python", str(script), "--", str(run / "base.glb"),
                           str(out)], capture_output=True, text=True, timeout=300)
    assert out.is_file(), proc.stdout[-2000:] + proc.stderr[-2000:]
    got = json.loads(out.read_text())
    rig = default_rig()
    faps = read_fap(run / "base.fap")
    plain = rig.weights(faps)
    names, _, weights = split_signs(TARGET_NAMES, rig.targets, plain)
    assert got["names"] == names
    assert (plain[7] < 0).any()  # frame 7 needs negative FAPs: they must not be clamped away
    for k in (7, 14):
        np.testing.assert_allclose(got["w"][str(k)], weights[k], atol=1e-6)
        co = np.array(got["co"][str(k)])  # Blender is z-up: (x, y, z) = glTF's (x, -z, y)
        mm = np.column_stack([co[:, 0], co[:, 2], -co[:, 1]]) * 1000
        np.testing.assert_allclose(mm, rig.pose(plain[k]), atol=1e-3)


def test_arkit_morph_set_moves_the_brows_lids_cheeks_and_corners() -> None:
    """The ARKit glTF's expression shapes are coartic's face posed at their FAPs
    (coartic.runtime.expression.ARKIT_EXPRESSION): browInnerUp raises the brows' inner ends
    320 ENS, browDownLeft lowers the left brow only, eyeWideLeft lifts the left upper lid,
    cheekSquintRight lifts the right cheek, mouthSmileLeft lifts the left corner (its inner and
    outer FAPs together: the whole 150 MNS); a shape coartic does not drive (noseSneerLeft) moves nothing."""
    from coartic.face.gltf import arkit_morphs
    from coartic.runtime.fap import FaceUnits
    from coartic.runtime.rigs import ARKIT_NAMES

    rig = default_rig()
    m = rig.mesh
    neutral = {"ULO": 0.0, "LLO": 0.0, "ULP": 0.0, "LLP": 0.0, "LR": 50.0, "JO": 0.0}
    names, fields = arkit_morphs(rig, neutral, FaceUnits())
    field = {n: fields[names.index(n)] for n in ARKIT_NAMES}
    y = {n: {fp: float(f[m.feature_points[fp], 1]) for fp in m.feature_points} for n, f in field.items()}
    assert y["browInnerUp"]["4.1"] == pytest.approx(320 * m.ens / 1024) == y["browInnerUp"]["4.2"]
    assert y["browDownLeft"]["4.3"] == pytest.approx(-200 * m.ens / 1024) and y["browDownLeft"]["4.4"] == 0.0
    assert y["eyeWideLeft"]["3.1"] == pytest.approx(300 * m.irisd / 1024) and y["eyeWideLeft"]["3.2"] == 0.0
    assert y["cheekSquintRight"]["5.4"] == pytest.approx(300 * m.ens / 1024) and y["cheekSquintRight"]["5.3"] == 0.0
    assert y["mouthSmileLeft"]["2.4"] == pytest.approx(150 * m.mns / 1024) and abs(y["mouthSmileLeft"]["2.5"]) < 1e-12
    assert not field["noseSneerLeft"].any()
