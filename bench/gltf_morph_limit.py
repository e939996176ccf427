"""three.js up to r132 blends only the 8 largest morph-target influences of a mesh: how wrong is each
glTF morph set under that limit? (issue 20, item 4)

For sentences through Festival and the shipped table, the face coartic's rig gives at every frame
(every target blended) against what a renderer limited to 8 influences per mesh shows, as the
largest distance of any vertex (mm; the skin, lips, teeth, tongue, eyelids), at the worst frame and
in the median frame:
- the FAP set (`--gltf-morphs fap`, one mesh, 68 targets): three.js r111's rule, the 8 largest
  |weights| of the frame kept (WebGLMorphtargets sorts them so);
- one mesh with this animation's 8 principal displacements (the rank-8 approximation of all the
  frames' displacements at once);
- the eight-target set (`--gltf-morphs eight`): a mesh per part, the skin in two, each with at most
  8 principal displacements of its own (coartic.face.gltf.limited_meshes), and the time to write it.
tests/python/test_face_gltf_limit.py renders the eight-target set and the FAP set in three.js r111
in headless Chromium against the exact face.

Run: .venv/bin/python bench/gltf_morph_limit.py [--out bench/results/gltf_morph_limit.txt]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from coartic.face.deform import default_rig
from coartic.face.gltf import MAX_BLENDED_TARGETS, limited_meshes, split_signs, write_face_glb
from coartic.runtime.pipeline import speak_text
from coartic.runtime.shipped import load_shipped_table

ROOT = Path(__file__).resolve().parents[1]
SENTENCES = (
    "Il babbo mangia la pappa.",
    "Vieni a vedere le foglie del giardino, amore.",
    "Oggi piove, ma domani usciremo tutti insieme a fare una passeggiata lungo il fiume.",
    "Nel mezzo del cammin di nostra vita mi ritrovai per una selva oscura, che la diritta via era "
    "smarrita. Ahi quanto a dir qual era è cosa dura esta selva selvaggia e aspra e forte.",
)


def worst_and_median(err: NDArray[np.float64]) -> tuple[float, float]:
    """err (frames, vertices) mm → (worst frame's largest, median frame's largest)."""
    per_frame = err.max(axis=1)
    return float(per_frame.max()), float(np.median(per_frame))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "gltf_morph_limit.txt"))
    args = ap.parse_args()
    table = load_shipped_table()
    rig = default_rig()
    k = MAX_BLENDED_TARGETS
    lines = [f"glTF morph sets under three.js r111's limit of {k} blended targets per mesh; the shipped table, "
             "Festival pc_diphone, 25 fps",
             f"machine: {platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}", "",
             "largest vertex error, mm: worst frame / median frame",
             f"{'speech s':>8s} {'frames':>6s} {'FAP targets moving':>18s} {'FAP set, r111':>15s} "
             f"{'one mesh, rank 8':>17s} {'eight (per part)':>17s} {'write s: eight, FAP':>20s}"]
    with tempfile.TemporaryDirectory() as tmp:
        for n, text in enumerate(SENTENCES):
            said = speak_text(text, table, Path(tmp) / f"s{n}", preview="none")
            w = rig.weights(said.faps)
            exact = np.tensordot(w, rig.targets, axes=(1, 0))  # (frames, vertices, 3) mm
            _, fields, signed = split_signs(rig.target_names, rig.targets, w)
            moving = (signed != 0).sum(axis=1)
            keep = np.argsort(-np.abs(signed), axis=1, kind="stable")[:, :k]
            top = np.zeros_like(signed)
            np.put_along_axis(top, keep, np.take_along_axis(signed, keep, axis=1), axis=1)
            r111 = np.linalg.norm(np.tensordot(top, fields, axes=(1, 0)) - exact, axis=2)
            flat = exact.reshape(exact.shape[0], -1)
            u, sv, vt = np.linalg.svd(flat, full_matrices=False)
            rank = np.linalg.norm((((u[:, :k] * sv[:k]) @ vt[:k]) - flat).reshape(exact.shape), axis=2)
            write_face_glb(Path(tmp) / "warm.glb", said.faps, limited=True)  # warm-up: caches, allocations
            t0 = time.perf_counter()
            path = write_face_glb(Path(tmp) / f"s{n}.glb", said.faps, limited=True)
            t_write = time.perf_counter() - t0
            t0 = time.perf_counter()
            write_face_glb(Path(tmp) / f"s{n}_fap.glb", said.faps)
            t_fap = time.perf_counter() - t0
            eight = max(m.max_error_mm for m in limited_meshes(rig, w))
            a, b = worst_and_median(r111)
            c, d = worst_and_median(rank)
            lines.append(f"{said.animation.duration:8.2f} {w.shape[0]:6d} {f'{int(np.median(moving))} (max {moving.max()})':>18s} "
                         f"{f'{a:.2f} / {b:.2f}':>15s} {f'{c:.2f} / {d:.2f}':>17s} {f'{eight:.3f} (worst)':>17s} "
                         f"{f'{t_write:.2f}, {t_fap:.2f}':>20s}")
            assert path.is_file()
    lines += ["", "the eight-target set is what --gltf-morphs eight writes: at every frame within the error above of "
              "the face every renderer without the limit shows (Blender, three.js r133+ on WebGL2, coartic view)"]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
