"""Key coartic's ARKit or viseme curves onto the shape keys of a rig that already exists, in Blender.

Run it with Blender's own Python (it imports nothing but the standard library and, when it runs
in Blender, `bpy`):

    blender --background rig.blend --python "$(python -c 'import coartic.runtime.blender_keys as m; print(m.__file__)')" \\
        -- out/NAME.arkit.json --object Face --save keyed.blend

The curves are any of the files `coartic animate/speak --export arkit,visemes` writes: NAME.arkit.json
(NVIDIA Audio2Face's layout: exportFps, facsNames, weightMat), NAME.visemes.json ({fps, visemes,
weights}) or either CSV (frame, time, one column per shape). Each curve goes to the shape key of the
same name, else of the same name ignoring case and the prefixes rigs put before them
(`SHAPE_KEY_PREFIXES`: viseme_, vrc.v_, blendShape1. ...), else the one `--map` names (a JSON object
{curve: shape key}); a curve with no key, and a key matched twice, are reported, and with `--strict`
refused. The keys are set at the scene's frame rate from `--start` (the scene's start frame by
default): a curve at 25 fps keys a 24-fps scene at the times of its frames (fractional frames),
and keys that linear interpolation already gives to within `--tolerance` are left out.

Everything but the last step (`apply_plan`, which needs `bpy`) is plain Python:
tests/python/test_runtime_blender.py tests it without Blender, and runs the script in Blender
where Blender is installed.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# what rigs put before a shape's own name (Ready Player Me and Oculus: viseme_; VRChat: vrc.v_;
# Maya/FBX exports: blendShape1.; some ARKit rigs: a mesh name and a dot is handled as any prefix
# ending in "." or "_" below)
SHAPE_KEY_PREFIXES: tuple[str, ...] = ("viseme_", "vrc.v_", "blendshape1.", "blendshape.", "arkit_", "arkit.")
DEFAULT_TOLERANCE = 1e-4
# Meta's vowel visemes ih oh ou are Ready Player Me's and VRChat's I O U
VOWEL_ALIASES = {"ih": "i", "oh": "o", "ou": "u"}


class CurvesError(ValueError):
    """A curves file or mapping that cannot be keyed (names the file and what is wrong)."""


@dataclass(frozen=True)
class Curves:
    """Weights per frame of `names` at `fps`, frame k at time k / fps."""

    fps: float
    names: tuple[str, ...]
    weights: tuple[tuple[float, ...], ...]  # (frames, names)
    source: str


def read_curves(path: str | Path) -> Curves:
    """An ARKit or viseme file of coartic's (JSON or CSV), checked."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise CurvesError(f"{path}: cannot read ({err.strerror})") from None
    if path.suffix.lower() == ".json":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as err:
            raise CurvesError(f"{path}, line {err.lineno}: not JSON ({err.msg})") from None
        if isinstance(doc, dict) and "facsNames" in doc:
            fps, names, rows = doc.get("exportFps"), doc["facsNames"], doc.get("weightMat")
        elif isinstance(doc, dict) and "visemes" in doc:
            fps, names, rows = doc.get("fps"), doc["visemes"], doc.get("weights")
        else:
            raise CurvesError(f"{path}: neither coartic's ARKit JSON (facsNames, weightMat) nor its visemes JSON "
                              "(visemes, weights)")
    elif path.suffix.lower() == ".csv":
        table = list(csv.reader(text.splitlines()))
        if not table or table[0][:2] != ["frame", "time"] or len(table[0]) < 3:
            raise CurvesError(f"{path}, line 1: expected the header 'frame,time,<shape>...' of coartic's curves CSV")
        names = table[0][2:]
        try:
            times = [float(r[1]) for r in table[1:]]
            rows = [[float(x) for x in r[2:]] for r in table[1:]]
        except (ValueError, IndexError) as err:
            raise CurvesError(f"{path}: a row is not numbers ({err})") from None
        fps = (len(times) - 1) / times[-1] if len(times) > 1 and times[-1] > 0 else None
        if fps is not None:
            fps = round(fps, 6)
    else:
        raise CurvesError(f"{path}: expected a .json or .csv written by coartic --export arkit or visemes")
    if not isinstance(fps, (int, float)) or not fps > 0:
        raise CurvesError(f"{path}: no positive frame rate")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        raise CurvesError(f"{path}: the shape names are not distinct strings")
    if not isinstance(rows, list) or not rows:
        raise CurvesError(f"{path}: no frames")
    out = []
    for k, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != len(names):
            raise CurvesError(f"{path}: frame {k} has {len(row) if isinstance(row, list) else '?'} weights for "
                              f"{len(names)} shapes")
        vals = tuple(float(v) for v in row)
        if any(v != v or v in (float("inf"), float("-inf")) for v in vals):
            raise CurvesError(f"{path}: frame {k} has a weight that is not finite")
        out.append(vals)
    return Curves(float(fps), tuple(names), tuple(out), str(path))


def _bare(name: str) -> str:
    low = name.lower()
    for prefix in SHAPE_KEY_PREFIXES:
        if low.startswith(prefix):
            low = low[len(prefix):]
            break
    return VOWEL_ALIASES.get(low, low)


def match_shape_keys(curves: Sequence[str], keys: Sequence[str],
                     mapping: dict[str, str] | None = None) -> tuple[dict[str, str], list[str]]:
    """{curve: shape key} and the curves left without a key. A curve takes, in order: the key
    `mapping` names, the key of its exact name, of its name ignoring case, of its name ignoring
    case, SHAPE_KEY_PREFIXES and VOWEL_ALIASES (viseme_aa ~ vrc.v_aa ~ aa, viseme_U ~ ou). Raises CurvesError for a mapping that
    names a missing curve or key, or two curves on one key."""
    mapping = dict(mapping or {})
    bad = [c for c in mapping if c not in curves]
    if bad:
        raise CurvesError(f"--map names curve(s) {', '.join(bad)} that the file does not have ({' '.join(curves)})")
    missing = [k for k in mapping.values() if k not in keys]
    if missing:
        raise CurvesError(f"--map names shape key(s) {', '.join(missing)} that the object does not have")
    lower: dict[str, str] = {}
    bare: dict[str, str] = {}
    for k in keys:
        lower.setdefault(k.lower(), k)
        bare.setdefault(_bare(k), k)
    out: dict[str, str] = {}
    unmatched = []
    for c in curves:
        key = mapping.get(c) or (c if c in keys else None) or lower.get(c.lower()) or bare.get(_bare(c))
        if key is None:
            unmatched.append(c)
        else:
            out[c] = key
    twice = sorted({k for k in out.values() if list(out.values()).count(k) > 1})
    if twice:
        raise CurvesError(f"shape key(s) {', '.join(twice)} matched by several curves "
                          f"({', '.join(c for c, k in out.items() if k in twice)}): name one with --map")
    return out, unmatched


def keyframes(values: Sequence[float], fps: float, scene_fps: float, start: float,
              tolerance: float = DEFAULT_TOLERANCE) -> list[tuple[float, float]]:
    """(scene frame, value) keys of one curve: frame k of `fps` at scene frame start + k·scene_fps/fps,
    leaving out every key that the straight line between the keys kept around it gives within
    `tolerance` (the first and last are always kept). One pass: from each key kept, the slopes
    that stay within `tolerance` of every point passed narrow until the next point falls outside."""
    ratio = scene_fps / fps
    pts = [(start + k * ratio, float(v)) for k, v in enumerate(values)]
    if len(pts) <= 2:
        return pts
    kept = [pts[0]]
    x0, y0 = pts[0]
    lo, hi = float("-inf"), float("inf")
    for k in range(1, len(pts)):
        x, y = pts[k]
        slope = (y - y0) / (x - x0)
        if not lo <= slope <= hi:  # the line from the last key cannot reach here: key the point before
            x0, y0 = pts[k - 1]
            kept.append(pts[k - 1])
            lo, hi = float("-inf"), float("inf")
        lo = max(lo, (y - tolerance - y0) / (x - x0))
        hi = min(hi, (y + tolerance - y0) / (x - x0))
    if kept[-1] != pts[-1]:
        kept.append(pts[-1])
    return kept


@dataclass(frozen=True)
class Plan:
    """What to key: shape key -> [(frame, value)], and what was left out."""

    keys: dict[str, list[tuple[float, float]]]
    unmatched: list[str]
    scene_end: float


def plan(curves: Curves, shape_keys: Sequence[str], scene_fps: float, start: float,
         mapping: dict[str, str] | None = None, tolerance: float = DEFAULT_TOLERANCE, strict: bool = False) -> Plan:
    """The keys to set on an object whose shape keys are `shape_keys` (the Basis left out)."""
    matched, unmatched = match_shape_keys(curves.names, shape_keys, mapping)
    if not matched:
        raise CurvesError(f"{curves.source}: none of its {len(curves.names)} curves ({' '.join(curves.names[:6])} ...) "
                          f"matches a shape key of the object ({' '.join(shape_keys[:8]) or 'none'}); use --map")
    if unmatched and strict:
        raise CurvesError(f"{curves.source}: no shape key for {', '.join(unmatched)} (--strict); use --map")
    col = {n: j for j, n in enumerate(curves.names)}
    keys = {key: keyframes([row[col[c]] for row in curves.weights], curves.fps, scene_fps, start, tolerance)
            for c, key in matched.items()}
    end = start + (len(curves.weights) - 1) * scene_fps / curves.fps
    return Plan(keys, unmatched, end)


def apply_plan(obj: Any, the_plan: Plan) -> int:  # pragma: no cover - needs Blender (bpy)
    """Insert the keys on `obj`'s shape keys (its action made if needed); returns how many."""
    import bpy  # type: ignore[import-not-found]

    shape_keys = obj.data.shape_keys
    if shape_keys.animation_data is None:
        shape_keys.animation_data_create()
    if shape_keys.animation_data.action is None:
        shape_keys.animation_data.action = bpy.data.actions.new(name=f"{obj.name}_coartic")
    action = shape_keys.animation_data.action
    n = 0
    for key, points in the_plan.keys.items():
        path = f'key_blocks["{key}"].value'
        fc = action.fcurves.find(path) or action.fcurves.new(path)
        fc.keyframe_points.clear()
        fc.keyframe_points.add(len(points))
        fc.keyframe_points.foreach_set("co", [v for p in points for v in p])
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"
        fc.update()
        block = shape_keys.key_blocks[key]
        block.slider_min = min(block.slider_min, min(v for _, v in points))
        block.slider_max = max(block.slider_max, max(v for _, v in points))
        n += len(points)
    return n


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="blender --background RIG.blend --python blender_keys.py --",
                                 description="Key coartic's ARKit or viseme curves onto a rig's shape keys.")
    ap.add_argument("curves", help="NAME.arkit.json/.csv or NAME.visemes.json/.csv written by coartic --export")
    ap.add_argument("--object", help="the mesh object with the shape keys (default: the only mesh that has any)")
    ap.add_argument("--map", help="JSON file {curve: shape key} for names that do not match")
    ap.add_argument("--start", type=float, help="scene frame of the curves' first frame (default: the scene's start)")
    ap.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE,
                    help="leave out keys that linear interpolation gives within this")
    ap.add_argument("--strict", action="store_true", help="refuse curves without a shape key")
    ap.add_argument("--save", help="save the .blend here (default: leave it unsaved)")
    return ap.parse_args(list(argv))


def script_args(argv: Sequence[str]) -> list[str]:
    """The arguments after Blender's `--` (all of them when run as a plain script)."""
    argv = list(argv)
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def read_map(path: str | None) -> dict[str, str] | None:
    if path is None:
        return None
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise CurvesError(f"--map {path}: cannot read a JSON object ({err})") from None
    if not isinstance(doc, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in doc.items()):
        raise CurvesError(f"--map {path}: expected a JSON object of curve name to shape key name")
    return doc


def _pick_object(objects: Iterable[Any], name: str | None) -> Any:  # pragma: no cover - needs Blender
    meshes = [o for o in objects if getattr(o, "type", None) == "MESH" and o.data.shape_keys is not None]
    if name is not None:
        found = [o for o in meshes if o.name == name]
        if not found:
            raise CurvesError(f"--object {name}: no mesh with shape keys of that name "
                              f"({', '.join(o.name for o in meshes) or 'none'})")
        return found[0]
    if len(meshes) != 1:
        raise CurvesError(f"{len(meshes)} meshes have shape keys ({', '.join(o.name for o in meshes)}): "
                          "choose one with --object")
    return meshes[0]


def main(argv: Sequence[str] | None = None) -> int:  # pragma: no cover - needs Blender
    args = parse_args(script_args(sys.argv if argv is None else argv))
    try:
        import bpy
    except ImportError:
        print("blender_keys.py runs inside Blender: blender --background RIG.blend --python blender_keys.py -- ...",
              file=sys.stderr)
        return 2
    try:
        curves = read_curves(args.curves)
        scene = bpy.context.scene
        obj = _pick_object(bpy.data.objects, args.object)
        names = [k.name for k in obj.data.shape_keys.key_blocks[1:]]
        scene_fps = scene.render.fps / scene.render.fps_base
        start = float(scene.frame_start if args.start is None else args.start)
        the_plan = plan(curves, names, scene_fps, start, read_map(args.map), args.tolerance, args.strict)
    except CurvesError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    n = apply_plan(obj, the_plan)
    scene.frame_end = max(scene.frame_end, int(the_plan.scene_end + 0.999))
    for c in the_plan.unmatched:
        print(f"note: no shape key for {c}: left out", file=sys.stderr)
    print(f"keyed {len(the_plan.keys)} shape keys of {obj.name} ({n} keys) from {curves.source}")
    if args.save:
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
    return 0


if __name__ == "__main__":  # pragma: no cover - run by Blender
    raise SystemExit(main())
