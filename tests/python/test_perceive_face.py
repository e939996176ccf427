"""An emotion study's videos are coartic's 3-D face with its sound (issue 27 item 4): the face the
glTF carries, drawn by `coartic view`'s renderer in headless Chromium, brows and lids included, and
the item's sound as the video's track."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from face_helpers import eyes_of, upper_face
from perceive_helpers import write_spec

ROOT = Path(__file__).resolve().parents[2]
SIZE = 200
FPS = 10

EMOTION_STUDY = f"""
[study]
name = "emotion-face"
design = "emotion"
seed = 5
consent = "ok"

[stimuli]
items = ["aba"]
fps = {FPS}
size_px = {SIZE}

[[condition]]
name = "surprised"
table = "emotive.json"
emotion = "surprise"

[[condition]]
name = "angry"
table = "emotive.json"
emotion = "anger"
"""


def frame_png(video: Path, k: int, png: Path) -> Path:
    """Frame k of an MP4 as a PNG (ffmpeg)."""
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(video), "-vf", f"select=eq(n\\,{k})", "-frames:v", "1",
                    str(png)], check=True)
    return png


@pytest.mark.festival
def test_emotion_stimuli_show_the_3d_face_with_its_brows_and_sound(tmp_path: Path) -> None:
    """Surprise and anger on /aba/: each video is the 3-D face (eye whites: the 2-D preview has no
    eyes) at the study's size and frame rate, with the item's sound as its track; surprise's brows
    stand higher than anger's (by 11 pixels of 200 measured), in a frame before the first blink."""
    from coartic.face.viewer import chromium_program
    from coartic.perceive.spec import read_study
    from coartic.perceive.stimuli import prepare_stimuli
    from coartic.synthetic_cli import load_generator
    from coartic.table import ParameterTable

    try:
        chromium_program()
    except Exception as err:  # scripts/setup.sh installs it
        pytest.skip(str(err))
    gen = load_generator()
    gen.emotive_truth(ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth.json"),
                      gen.load_emotions()).save(tmp_path / "emotive.json")
    manifest = prepare_stimuli(read_study(write_spec(tmp_path, EMOTION_STUDY)), tmp_path / "study")
    assert manifest["render"] == "3d"
    assert json.loads((tmp_path / "study" / "study.json").read_text())["render"] == "3d"
    faces = {}
    for stim in manifest["stimuli"]:
        video = tmp_path / "study" / stim["file"]
        probe = json.loads(subprocess.run(["ffprobe", "-v", "error", "-show_streams", "-of", "json", str(video)],
                                          capture_output=True, check=True).stdout)
        kinds = {s["codec_type"]: s for s in probe["streams"]}
        assert set(kinds) == {"video", "audio"}
        assert (kinds["video"]["width"], kinds["video"]["height"]) == (SIZE, SIZE)
        assert int(kinds["video"]["nb_frames"]) == stim["frames"]
        assert float(kinds["audio"]["duration"]) == pytest.approx(stim["duration_s"], abs=0.1)
        # 0.3 s: still in the pause before the voice, and before the first blink (0.6 s)
        faces[stim["condition"]] = frame_png(video, int(0.3 * FPS), tmp_path / f"{stim['condition']}.png")
    eyes = eyes_of(faces["surprised"])
    measured = {c: upper_face(png, eyes) for c, png in faces.items()}
    assert measured["surprised"]["brow"] < measured["angry"]["brow"] - 5, measured
    assert all(m["sclera"] > 50 for m in measured.values()), measured
    img = np.asarray(Image.open(faces["angry"]).convert("RGB"))
    assert img.shape == (SIZE, SIZE, 3)


def test_without_chromium_the_3d_render_says_what_to_do(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """No Chromium on PATH: prepare stops before Festival, naming the spec, the key and the way out."""
    from coartic.perceive.spec import read_study
    from coartic.perceive.stimuli import prepare_stimuli
    from coartic.runtime.errors import AnimationError

    monkeypatch.setenv("PATH", str(tmp_path))  # nothing there: no chromium, no festival either
    (tmp_path / "emotive.json").write_text("{}", encoding="utf-8")
    spec = read_study(write_spec(tmp_path, EMOTION_STUDY))
    with pytest.raises(AnimationError, match=r'study.toml: \[stimuli\] render = "3d" draws the face in Chromium: '
                                             r'no Chromium on PATH .*; or set render = "2d"'):
        prepare_stimuli(spec, tmp_path / "study")
    assert not (tmp_path / "study").exists()
