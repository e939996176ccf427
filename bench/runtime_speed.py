"""How fast is the runtime against real time? (issue 12)

Festival says one sentence once (3 s at the normal rate); then, from Python after start-up:
- the animation itself, channels + FAP frames (what a player needs, no file, no preview), as the
  median of many runs, against the speech's duration (the reference: real time);
- the glTF weights of the face for those FAPs, and writing the .glb;
- the preview of the default view (the GIF `coartic animate|speak` writes), and the MP4 with the
  sound, per frame against the frame period (40 ms at 25 fps): below 1 x is faster than real time.

Run: .venv/bin/python bench/runtime_speed.py [--out bench/results/runtime_speed.txt]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from coartic.face.deform import default_rig
from coartic.face.gltf import write_face_glb
from coartic.runtime.animate import animate, neutral_posture
from coartic.runtime.fap import animation_faps
from coartic.runtime.pipeline import speak_text, speaker_face
from coartic.runtime.preview import _frames, render_preview
from coartic.table import ParameterTable

ROOT = Path(__file__).resolve().parents[1]
SENTENCE = "Il babbo mangia la pappa, poi va via."


def median_time(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up: imports, caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", default=str(ROOT / "corpus-synthetic" / "ground_truth.json"))
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "runtime_speed.txt"))
    ap.add_argument("--repeats", type=int, default=50)
    args = ap.parse_args()
    table = ParameterTable.load(args.table)
    neutral = neutral_posture(table)
    face = speaker_face(table)
    lines = [f"sentence: {SENTENCE!r}, table: {Path(args.table).name}, Festival pc_diphone, 25 fps",
             f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
             f"load average {os.getloadavg()[0]:.1f} at the start (other jobs share the cores)", ""]
    with tempfile.TemporaryDirectory() as tmp:
        said = speak_text(SENTENCE, table, Path(tmp) / "say", preview="none")
        anim = said.animation
        dur, n = anim.duration, anim.n_frames
        segments = anim.segments

        def channels_and_faps() -> object:
            a = animate(table, segments, 25.0, duration=dur)
            return animation_faps(a, face, "bench")  # lips, jaw, the tongue through the model, blinks

        t_anim = median_time(channels_and_faps, args.repeats)
        faps = said.faps
        rig = default_rig()
        t_weights = median_time(lambda: rig.weights(faps), args.repeats)
        t_glb = median_time(lambda: write_face_glb(Path(tmp) / "face.glb", faps), 5)
        lines += [
            f"speech: {dur:.2f} s = {n} frames",
            "",
            "animation (channels + FAP frames, in memory), median of "
            f"{args.repeats}: {1000 * t_anim:.2f} ms = {t_anim / dur:.5f} x real time "
            f"({1e6 * t_anim / n:.1f} us per frame)",
            f"face weights for the glTF ({len(rig.target_names)} displacement fields): {1000 * t_weights:.2f} ms = "
            f"{t_weights / dur:.5f} x real time",
            f"writing the .glb (checked): {1000 * t_glb:.1f} ms = {t_glb / dur:.3f} x real time",
            "",
            "preview of the default view (front + side + aperture trace, 512 x 320 px), per frame against 40 ms:",
        ]
        t0 = time.perf_counter()
        for _ in _frames(anim, neutral, "bench"):
            pass
        t_frames = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        render_preview(anim, neutral, Path(tmp) / "p.gif")
        t_gif = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        render_preview(anim, neutral, Path(tmp) / "p.mp4", audio=said.files["wav"])
        t_mp4 = (time.perf_counter() - t0) / n
        period = 1.0 / anim.fps
        for what, t in (("drawing the frames (Pillow, background drawn once)", t_frames), ("GIF (the default)", t_gif),
                        ("MP4 with the sound (ffmpeg, x264 veryfast)", t_mp4)):
            lines.append(f"  {what}: {1000 * t:.1f} ms per frame = {t / period:.2f} x real time")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
