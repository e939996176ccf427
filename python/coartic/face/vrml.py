"""VRML97 (.wrl) of the face, as LUCIA was exported: the deformed face at one frame, or the whole
animation with a CoordinateInterpolator per part driven by a TimeSensor, and the sound as an
AudioClip started with it.

Units are metres, like the glTF. Every part is an IndexedFaceSet with per-vertex colours; the
animated file keys each part's coordinates at every frame (linear in between, as VRML97
interpolators are), so any VRML97 browser plays it without knowing about FAPs.
"""

from __future__ import annotations

from collections.abc import Iterable
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from coartic.face.deform import FaceRig, default_rig
from coartic.face.gltf import MM
from coartic.face.mesh import PART_NAMES
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import FapSequence
from coartic.runtime.festival import wav_duration
from coartic.outputs import atomic_write_text

if TYPE_CHECKING:
    from coartic.runtime.exporters import ExportSettings, FaceAnimation

# An animated world keys every vertex of every moving part at every frame, ~58 kB of text per frame:
# 1500 frames (a minute at 25 fps) is ~90 MB. Longer animations are refused (single frames are not).
VRML_MAX_FRAMES = 1500


def _vec3(values: NDArray[np.float64]) -> str:
    """Rows of 3 numbers, one vertex per line, VRML's comma-separated MFVec3f."""
    rows = np.asarray(values).reshape(-1, 3)
    return ",\n".join(" ".join(_fmt(v) for v in row) for row in rows)


def _fmt(v: float) -> str:
    s = f"{float(v):.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "", "-") else s


def _indices(tris: NDArray[np.int64]) -> str:
    return ",\n".join(f"{a} {b} {c} -1" for a, b, c in tris)


def _parts(rig: FaceRig) -> Iterable[tuple[str, NDArray[np.int64], NDArray[np.int64]]]:
    """Each part's vertex indices and triangles renumbered within the part."""
    mesh = rig.mesh
    for part in PART_NAMES:
        sel = np.flatnonzero(mesh.in_part(part))
        remap = np.full(mesh.n_vertices, -1, dtype=np.int64)
        remap[sel] = np.arange(sel.size)
        yield part, sel, remap[mesh.triangles[part]]


def vrml_text(rig: FaceRig, weights: NDArray[np.float64], fps: float, name: str, *,
              audio: str | None = None, audio_seconds: float | None = None) -> str:
    """A VRML97 world: one frame if `weights` is one row, else the animation at `fps`.

    With `audio_seconds` (the WAV's length) the loop lasts exactly as long as the sound, so that
    both restart together: a loop of n_frames / fps would drift against the clip every cycle."""
    w = np.atleast_2d(np.asarray(weights, dtype=float))
    if w.shape[1] != rig.targets.shape[0] or not np.isfinite(w).all():
        raise AnimationError(f"VRML weights must be finite (frames, {rig.targets.shape[0]}), got {w.shape}")
    if w.shape[0] > VRML_MAX_FRAMES:
        raise AnimationError(f"{name}: an animated VRML world of {w.shape[0]} frames would be ~{w.shape[0] * 58 // 1000} MB "
                             f"of text (more than {VRML_MAX_FRAMES} frames); export chosen frames instead "
                             "(write_face_vrml(..., frames=[...])) or use the glTF")
    poses = rig.pose(w) * MM  # (frames, n, 3) metres
    animated = w.shape[0] > 1
    out = ["#VRML V2.0 utf8", f"# {name}: coartic's generated face driven by MPEG-4 FAPs (coartic.face.vrml)",
           f'WorldInfo {{ title "{_string(name)}" info [ "frames {w.shape[0]}", "fps {fps:g}" ] }}',
           'NavigationInfo { type [ "EXAMINE", "ANY" ] }',
           'Viewpoint { position 0 0.02 0.55 description "front" }',
           "Transform { children ["]
    for part, sel, tris in _parts(rig):
        out += [
            "  Shape {",
            "    appearance Appearance { material Material { diffuseColor 1 1 1 ambientIntensity 0.3 } }",
            "    geometry IndexedFaceSet {",
            "      solid FALSE creaseAngle 0 colorPerVertex TRUE",
            f"      coord DEF {part}_coord Coordinate {{ point [\n{_vec3(poses[0][sel])}\n      ] }}",
            f"      color Color {{ color [\n{_vec3(rig.mesh.colors[sel])}\n      ] }}",
            f"      coordIndex [\n{_indices(tris)}\n      ]",
            "    }",
            "  }",
        ]
    out.append("] }")
    if animated:
        duration = w.shape[0] / fps if audio_seconds is None else float(audio_seconds)
        if not (np.isfinite(duration) and duration > 0):
            raise AnimationError(f"{name}: the sound's length must be positive, got {audio_seconds!r} s")
        # frames after the end of the sound cannot be shown within its loop: the last key is the
        # last frame that starts before the sound ends
        n_keys = min(w.shape[0], int(np.floor(duration * fps - 1e-9)) + 1)
        keys = np.arange(n_keys) / fps / duration
        poses = poses[:n_keys]
        out.append(f"DEF clock TimeSensor {{ cycleInterval {_fmt(duration)} loop TRUE }}")
        for part, sel, _ in _parts(rig):
            if np.ptp(poses[:, sel], axis=0).max() == 0.0:
                continue  # a part that never moves needs no interpolator
            out.append(f"DEF {part}_motion CoordinateInterpolator {{")
            out.append(f"  key [ {' '.join(_fmt(k) for k in keys)} ]")
            out.append(f"  keyValue [\n{_vec3(poses[:, sel])}\n  ]")
            out.append("}")
            out.append(f"ROUTE clock.fraction_changed TO {part}_motion.set_fraction")
            out.append(f"ROUTE {part}_motion.value_changed TO {part}_coord.set_point")
        if audio:
            out.append(f'Sound {{ source DEF voice AudioClip {{ url [ "{_string(audio)}" ] loop TRUE }} '
                       "spatialize FALSE minFront 100 minBack 100 maxFront 100 maxBack 100 }")
    return "\n".join(out) + "\n"


def _string(s: str) -> str:
    return s.replace("\\", "\\\\").replace('"', '\\"')


def write_vrml(path: str | PathLike[str], rig: FaceRig, weights: NDArray[np.float64], fps: float, name: str, *,
               audio: str | None = None, audio_seconds: float | None = None) -> Path:
    """Write `vrml_text(...)` to `path` atomically."""
    path = Path(path)
    atomic_write_text(path, vrml_text(rig, weights, fps, name, audio=audio, audio_seconds=audio_seconds))
    return path


def write_face_vrml(path: str | PathLike[str], faps: FapSequence, *, frames: Iterable[int] | None = None,
                    audio: str | None = None, audio_seconds: float | None = None) -> list[Path]:
    """The project's face played by `faps`: the animation in `path`, or with `frames`, the face at
    each of those frames in PATH_STEM_fK.wrl (static worlds, as LUCIA's snapshots)."""
    rig = default_rig()
    weights = rig.weights(faps)
    path = Path(path)
    if frames is None:
        return [write_vrml(path, rig, weights, faps.fps, faps.name, audio=audio, audio_seconds=audio_seconds)]
    written = []
    for k in frames:
        if not 0 <= k < faps.n_frames:
            raise AnimationError(f"frame {k} is outside 0..{faps.n_frames - 1} of {faps.name!r}")
        written.append(write_vrml(path.with_name(f"{path.stem}_f{k}.wrl"), rig, weights[k], faps.fps,
                                  f"{faps.name} frame {k}"))
    return written


def export_vrml(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter (coartic.runtime.exporters): NAME.wrl, the face animated with the sound."""
    faps = fed.faps
    audio = settings.audio
    path = write_face_vrml(settings.out / f"{settings.name}.wrl", faps, audio=settings.audio_name(),
                           audio_seconds=wav_duration(audio) if audio is not None else None)[0]
    return {"vrml": path}
