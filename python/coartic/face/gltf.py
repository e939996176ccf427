"""glTF 2.0 binary (.glb): the face with morph targets per FAP and an animation of the weights.

One node, one mesh with a primitive per part (skin, cavity, upper_teeth, lower_teeth, eyes; named
in each primitive's `extras.part`), vertex colours (COLOR_0), and the displacement fields of
`coartic.face.deform` as morph targets (`mesh.extras.targetNames`, the names Blender and three.js
show), each split into a positive and a negative target (`split_signs`) and stored sparse. The
animation has one channel, `path: "weights"`, sampled at the frame times with LINEAR
interpolation. Units are metres (glTF's), so the face is 0.2 m tall. The sound is not inside (glTF
has no audio in its core); `asset.extras` names the WAV written beside the file, with the frame
rate and the FAP file, and that is what `coartic view` plays.

The eight-target set (`limited=True`, `--gltf-morphs eight`) is for three.js up to r132, which
blends only the 8 largest morph influences of a mesh: one node and mesh per part (the skin in two,
above and below the lip line), each with at most 8 targets of its own and its own weights channel
(`limited_meshes`). Its primitives carry `_VERTEX`, each vertex's number in the face (an
application-specific attribute, float), so that a renderer that recomputes normals (`coartic view`)
joins the two halves of the skin where they share vertices.

`check_glb` is this module's own structural check against the specification (header and chunks,
every index and byte range, accessor types and bounds, morph-target and animation consistency);
the tests also read the file back with pygltflib and run Debian's gltfpack (cgltf's validator).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from coartic.face.deform import FaceRig, default_rig
from coartic.face.mesh import MOUTH_HALF_WIDTH, PART_NAMES, vertex_normals
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import BLINK_CLOSED, N_FAPS, FaceUnits, FapSequence, channels_to_faps
from coartic.outputs import atomic_write_bytes
from coartic.runtime.rigs import ARKIT_BASIS, ARKIT_BLINKS, ARKIT_NAMES, arkit_weights

if TYPE_CHECKING:
    from coartic.runtime.animate import Animation
    from coartic.runtime.exporters import ExportSettings, FaceAnimation

GLB_MAGIC = 0x46546C67  # "glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
FLOAT, UINT16, UINT32 = 5126, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_SIZES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
MM = 0.001  # glTF lengths are metres


class GltfError(AnimationError):
    """A glTF file that breaks the specification (names the file and the JSON path)."""


class _Builder:
    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def add(self, data: NDArray[Any], type_: str, component: int, target: int | None = None,
            bounds: bool = False) -> int:
        arr = np.ascontiguousarray(data)
        while len(self.blob) % 4:
            self.blob.append(0)
        view: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": arr.nbytes}
        if target is not None:
            view["target"] = target
        self.blob += arr.tobytes()
        self.views.append(view)
        count = arr.shape[0]
        acc: dict[str, Any] = {"bufferView": len(self.views) - 1, "componentType": component, "count": int(count),
                               "type": type_}
        if bounds:
            flat = arr.reshape(count, -1)
            acc["min"] = [float(v) for v in flat.min(axis=0)]
            acc["max"] = [float(v) for v in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def _view(self, arr: NDArray[Any]) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.views.append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": arr.nbytes})
        self.blob += np.ascontiguousarray(arr).tobytes()
        return len(self.views) - 1

    def zeros(self, count: int) -> int:
        """A bufferView of `count` zero VEC3 floats, the base every sparse target of a part shares
        (an accessor without a bufferView would also mean zeros, but three.js r111 cannot read it)."""
        return self._view(np.zeros((count, 3), dtype=np.float32))

    def add_sparse_vec3(self, data: NDArray[np.float32], zeros: int) -> int:
        """A float VEC3 accessor stored sparse over the zero bufferView `zeros`: only the rows that
        are not zero are written (a morph target moves a few hundred of the vertices)."""
        rows = np.flatnonzero(np.any(data != 0, axis=1))
        acc: dict[str, Any] = {"bufferView": zeros, "componentType": FLOAT, "count": int(data.shape[0]),
                               "type": "VEC3", "min": [float(v) for v in data.min(axis=0)],
                               "max": [float(v) for v in data.max(axis=0)]}
        if rows.size:
            idx_type, comp = (np.uint16, UINT16) if data.shape[0] <= 65535 else (np.uint32, UINT32)
            acc["sparse"] = {"count": int(rows.size),
                             "indices": {"bufferView": self._view(rows.astype(idx_type)), "componentType": comp},
                             "values": {"bufferView": self._view(np.ascontiguousarray(data[rows]))}}
        self.accessors.append(acc)
        return len(self.accessors) - 1


def split_signs(names: tuple[str, ...], targets: NDArray[np.float64], weights: NDArray[np.float64]
                ) -> tuple[list[str], NDArray[np.float64], NDArray[np.float64]]:
    """Each signed field as two targets, NAME for positive weights and NAME_neg (the field negated)
    for negative ones, so that every weight lies in 0..1: Blender's importer keeps a shape key
    within 0..1 unless the first keyframe says otherwise, and would flatten negative FAPs to 0.
    A field whose weight is never negative (the turns' NAME_1mcos) stays one target. Exact, also between
    frames: linear interpolation of w+ and w- adds up to that of w."""
    out_names, out_t, out_w = [], [], []
    for k, name in enumerate(names):
        w = weights[:, k]
        out_names.append(name)
        out_t.append(targets[k])
        out_w.append(np.maximum(w, 0.0))
        if not name.endswith("_1mcos"):  # 1 - cos θ is never negative
            out_names.append(f"{name}_neg")
            out_t.append(-targets[k])
            out_w.append(np.maximum(-w, 0.0))
    return out_names, np.stack(out_t), np.column_stack(out_w)


def srgb_to_linear(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """The mesh's colours are sRGB (as picked); glTF's COLOR_0 is linear."""
    out: NDArray[np.float64] = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return out


# three.js up to r132 (Debian's libjs-three is r111) blends only the 8 largest morph-target influences
# of a mesh (WebGL vertex attributes; later versions on WebGL2 use textures and blend all).
MAX_BLENDED_TARGETS = 8
# A mode below this fraction of its mesh's largest is numerical noise, not movement.
_MODE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class MorphMesh:
    """One glTF mesh: primitives (part, triangles in the face's vertex numbering), morph targets
    (names, displacement fields (targets, face vertices, 3) in mm) and their weights (frames, targets)."""

    name: str
    primitives: tuple[tuple[str, NDArray[np.int64]], ...]
    names: tuple[str, ...]
    fields: NDArray[np.float64]
    weights: NDArray[np.float64]
    max_error_mm: float = 0.0  # how far any vertex is from the exact face at a key (the limited set)


def limited_meshes(rig: FaceRig, weights: NDArray[np.float64],
                   max_targets: int = MAX_BLENDED_TARGETS) -> list[MorphMesh]:
    """The face as one glTF mesh per part, each with at most `max_targets` morph targets, for three.js
    up to r132 (MAX_BLENDED_TARGETS): then every target of a mesh is blended, at every key and
    between keys. The skin is two meshes, above and below the lip line (a triangle across it goes
    below): the upper lip, the lower lip with the jaw and the roll, move ~5 and ~10 ways.

    A mesh's targets are the principal displacements of this animation on its vertices (the
    singular vectors of the frames' displacements Σ_j w_j T_j, computed in the rig's weight space,
    so a long animation costs frames × fields, not frames × vertices), each scaled to the largest
    displacement it makes (weights within -1..1, the extreme frame at +1). A part that moves at most
    `max_targets` ways (the teeth, the tongue, the eyelids, the skull: jaw, tongue FAPs, blinks) is
    exact; otherwise the modes past the `max_targets`-th are left out and `max_error_mm` says how
    far that leaves any vertex, at the worst key."""
    mesh = rig.mesh
    w = np.asarray(weights, dtype=np.float64)
    groups: list[tuple[str, tuple[tuple[str, NDArray[np.int64]], ...]]] = []
    for part in PART_NAMES:
        tris = mesh.triangles[part]
        if part == "skin":
            above = mesh.upper[tris].all(axis=1)
            groups += [("skin_upper", (("skin", tris[above]),)), ("skin_lower", (("skin", tris[~above]),))]
        else:
            groups.append((part, ((part, tris),)))
    out = []
    for name, prims in groups:
        sel = np.unique(np.concatenate([t.reshape(-1) for _, t in prims]))
        basis = rig.targets[:, sel, :].reshape(rig.targets.shape[0], -1)  # (fields, 3m)
        q, r = np.linalg.qr(basis.T)  # basis = r.T q.T
        u, sv, vt = np.linalg.svd(w @ r.T, full_matrices=False)  # displacements = u sv vt q.T
        keep = int((sv > _MODE_TOLERANCE * sv[0]).sum()) if sv.size and sv[0] > 0 else 0
        k = min(keep, max_targets)
        modes = vt[:k] @ q.T  # (k, 3m), orthonormal rows
        coef = u[:, :k] * sv[:k]
        extreme = coef[np.argmax(np.abs(coef), axis=0), np.arange(k)]
        coef, modes = coef / extreme, modes * extreme[:, None]
        fields = np.zeros((k, mesh.n_vertices, 3))
        fields[:, sel] = modes.reshape(k, sel.size, 3)
        err = 0.0
        if keep > k:  # the modes left out, frame by frame in chunks (frames × vertices at once could be large)
            rest = vt[k:keep] @ q.T
            for lo in range(0, w.shape[0], 256):
                miss = (u[lo:lo + 256, k:keep] * sv[k:keep]) @ rest
                err = max(err, float(np.linalg.norm(miss.reshape(miss.shape[0], sel.size, 3), axis=2).max()))
        out.append(MorphMesh(name, prims, tuple(f"{name}_{j + 1}" for j in range(k)), fields, coef, err))
    return out


def gltf_document(rig: FaceRig, weights: NDArray[np.float64], fps: float, name: str, *,
                  audio: str | None = None, fap_file: str | None = None,
                  morphs: tuple[tuple[str, ...], NDArray[np.float64]] | None = None,
                  limited: bool = False) -> tuple[dict[str, Any], bytes]:
    """The glTF JSON and binary buffer for the face animated by `weights` (frames, targets) at `fps`.

    `morphs` = (names, fields (targets, vertices, 3) in mm) replaces the rig's FAP targets by another
    morph set, e.g. ARKit's (`arkit_morphs`); its weights are used as they are (no sign split).
    `limited`: the rig's weights blended by at most 8 targets per mesh (`limited_meshes`)."""
    weights = np.asarray(weights, dtype=np.float64)
    n_targets = rig.targets.shape[0] if morphs is None else len(morphs[0])
    if weights.ndim != 2 or weights.shape[1] != n_targets or weights.shape[0] < 1:
        raise AnimationError(f"glTF weights must be (frames >= 1, {n_targets}), got {weights.shape}")
    if not np.isfinite(weights).all():
        raise AnimationError("glTF weights are not finite")
    mesh = rig.mesh
    whole = tuple((part, mesh.triangles[part]) for part in PART_NAMES)
    if limited:
        meshes = limited_meshes(rig, weights)
    elif morphs is None:
        names, fields, signed = split_signs(rig.target_names, rig.targets, weights)
        meshes = [MorphMesh("face", whole, tuple(names), fields, signed)]
    else:
        meshes = [MorphMesh("face", whole, tuple(morphs[0]), morphs[1], weights)]
    # smooth normals of the face at rest, each part's from all its triangles (so that the two halves
    # of the limited set's skin shade alike along their seam); a renderer recomputes them as the
    # targets move the face, or uses these: glTF's morph targets may carry NORMAL deltas, these do not
    normals = np.zeros_like(mesh.vertices)
    for part in PART_NAMES:
        on = mesh.in_part(part)
        normals[on] = vertex_normals(mesh.vertices, mesh.triangles[part])[on]
    b = _Builder()
    doc_meshes: list[dict[str, Any]] = []
    nodes: list[dict[str, Any]] = []
    channels: list[dict[str, Any]] = []
    samplers: list[dict[str, Any]] = []
    times = (np.arange(weights.shape[0]) / fps).astype(np.float32)
    t_in = b.add(times, "SCALAR", FLOAT, bounds=True)
    for m in meshes:
        primitives = []
        for part, part_tris in m.primitives:
            sel = np.unique(part_tris)
            remap = np.full(mesh.n_vertices, -1, dtype=np.int64)
            remap[sel] = np.arange(sel.size)
            tris = remap[part_tris]
            pos = b.add((mesh.vertices[sel] * MM).astype(np.float32), "VEC3", FLOAT, ARRAY_BUFFER, bounds=True)
            col = b.add(srgb_to_linear(mesh.colors[sel]).astype(np.float32), "VEC3", FLOAT, ARRAY_BUFFER)
            nrm = b.add(normals[sel].astype(np.float32), "VEC3", FLOAT, ARRAY_BUFFER)
            idx_type, comp = (np.uint16, UINT16) if sel.size < 65535 else (np.uint32, UINT32)
            ind = b.add(tris.reshape(-1).astype(idx_type), "SCALAR", comp, ELEMENT_ARRAY_BUFFER)
            b.accessors[ind]["min"] = [int(tris.min())]
            b.accessors[ind]["max"] = [int(tris.max())]
            attributes = {"POSITION": pos, "NORMAL": nrm, "COLOR_0": col}
            if limited:  # the face's vertex numbers: a renderer that recomputes normals welds the skin's seam
                attributes["_VERTEX"] = b.add(sel.astype(np.float32), "SCALAR", FLOAT, ARRAY_BUFFER)
            prim: dict[str, Any] = {"attributes": attributes, "indices": ind, "material": 0, "mode": 4,
                                    "extras": {"part": part}}
            if m.names:
                zeros = b.zeros(sel.size)
                prim["targets"] = [{"POSITION": b.add_sparse_vec3((m.fields[k][sel] * MM).astype(np.float32), zeros)}
                                   for k in range(len(m.names))]
            primitives.append(prim)
        doc_mesh: dict[str, Any] = {"name": m.name, "primitives": primitives}
        if m.names:
            doc_mesh["weights"] = [0.0] * len(m.names)
            doc_mesh["extras"] = {"targetNames": list(m.names)}
            if limited:
                doc_mesh["extras"]["maxErrorMm"] = m.max_error_mm
            w_out = b.add(m.weights.astype(np.float32).reshape(-1), "SCALAR", FLOAT)
            channels.append({"sampler": len(samplers), "target": {"node": len(nodes), "path": "weights"}})
            samplers.append({"input": t_in, "output": w_out, "interpolation": "LINEAR"})
        nodes.append({"name": m.name, "mesh": len(doc_meshes)})
        doc_meshes.append(doc_mesh)
    while len(b.blob) % 4:
        b.blob.append(0)
    extras: dict[str, Any] = {"fps": float(fps), "frames": int(weights.shape[0]), "audio": audio,
                              "fap_file": fap_file, "units": "m", "face": "coartic generated face"}
    if limited:
        extras["morphs"] = {"max_blended": MAX_BLENDED_TARGETS,
                            "max_error_mm": max((m.max_error_mm for m in meshes), default=0.0)}
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "coartic (coartic.face.gltf)", "extras": extras},
        "scene": 0,
        "scenes": [{"name": name, "nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": doc_meshes,
        "materials": [{"name": "face", "doubleSided": True,
                       "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
                                                "roughnessFactor": 0.75}}],
        "buffers": [{"byteLength": len(b.blob)}],
        "bufferViews": b.views,
        "accessors": b.accessors,
    }
    if channels:  # a face that nothing moves (a still pose) has no animation: glTF wants channels in one
        doc["animations"] = [{"name": name, "channels": channels, "samplers": samplers}]
    return doc, bytes(b.blob)


def glb_bytes(doc: dict[str, Any], blob: bytes) -> bytes:
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (struct.pack("<III", GLB_MAGIC, 2, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
            + struct.pack("<II", len(blob), CHUNK_BIN) + blob)


def write_glb(path: str | PathLike[str], rig: FaceRig, weights: NDArray[np.float64], fps: float, name: str, *,
              audio: str | None = None, fap_file: str | None = None,
              morphs: tuple[tuple[str, ...], NDArray[np.float64]] | None = None, limited: bool = False) -> Path:
    """Write the animated face to `path` (atomically), after checking it."""
    path = Path(path)
    data = glb_bytes(*gltf_document(rig, weights, fps, name, audio=audio, fap_file=fap_file, morphs=morphs,
                                    limited=limited))
    check_glb_bytes(data, str(path))
    atomic_write_bytes(path, data)
    return path


def read_glb(path: str | PathLike[str]) -> tuple[dict[str, Any], bytes]:
    """JSON and binary chunk of a .glb, checked."""
    data = Path(path).read_bytes()
    return check_glb_bytes(data, str(path))


def accessor_array(doc: dict[str, Any], blob: bytes, index: int) -> NDArray[Any]:
    """The data of accessor `index` as a (count, components) or (count,) array."""
    acc = doc["accessors"][index]
    ncomp = _COMPONENTS[acc["type"]]
    dtype = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}[
        acc["componentType"]]
    if "bufferView" not in acc:
        arr = np.zeros(acc["count"] * ncomp, dtype=dtype)  # glTF: no bufferView means zeros
    else:
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        arr = np.frombuffer(blob, dtype=dtype, count=acc["count"] * ncomp, offset=start).copy()
    sparse = acc.get("sparse")
    if sparse:
        m = sparse["count"]
        iview = doc["bufferViews"][sparse["indices"]["bufferView"]]
        itype = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32}[sparse["indices"]["componentType"]]
        rows = np.frombuffer(blob, dtype=itype, count=m,
                             offset=iview.get("byteOffset", 0) + sparse["indices"].get("byteOffset", 0))
        vview = doc["bufferViews"][sparse["values"]["bufferView"]]
        vals = np.frombuffer(blob, dtype=dtype, count=m * ncomp,
                             offset=vview.get("byteOffset", 0) + sparse["values"].get("byteOffset", 0))
        arr.reshape(acc["count"], ncomp)[rows.astype(np.int64)] = vals.reshape(m, ncomp)
    return arr.reshape(acc["count"], ncomp) if ncomp > 1 else arr


def _fail(where: str, msg: str) -> GltfError:
    return GltfError(f"{where}: {msg}")


def check_glb_bytes(data: bytes, where: str = "<glb>") -> tuple[dict[str, Any], bytes]:
    """Check a .glb against the glTF 2.0 rules this exporter relies on; GltfError names the first breach."""
    if len(data) < 20:
        raise _fail(where, f"{len(data)} bytes, too short for a GLB header")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2:
        raise _fail(where, f"not a glTF 2.0 binary (magic {magic:#x}, version {version})")
    if length != len(data):
        raise _fail(where, f"header says {length} bytes, file has {len(data)}")
    jlen, jtype = struct.unpack_from("<II", data, 12)
    if jtype != CHUNK_JSON or jlen % 4 or 20 + jlen > len(data):
        raise _fail(where, "first chunk must be JSON, 4-byte aligned, inside the file")
    try:
        doc = json.loads(data[20:20 + jlen].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise _fail(where, f"JSON chunk does not parse ({err})") from None
    blob = b""
    pos = 20 + jlen
    if pos < len(data):
        blen, btype = struct.unpack_from("<II", data, pos)
        if btype != CHUNK_BIN or blen % 4 or pos + 8 + blen != len(data):
            raise _fail(where, "second chunk must be BIN, 4-byte aligned, ending the file")
        blob = data[pos + 8:pos + 8 + blen]
    check_gltf(doc, blob, where)
    return doc, blob


def _index(doc: dict[str, Any], key: str, i: Any, where: str) -> dict[str, Any]:
    items = doc.get(key, [])
    if not isinstance(i, int) or not 0 <= i < len(items):
        raise _fail(where, f"refers to {key}[{i}], which does not exist ({len(items)} defined)")
    item: dict[str, Any] = items[i]
    return item


def check_gltf(doc: dict[str, Any], blob: bytes, where: str = "<gltf>") -> None:
    """The structural rules of glTF 2.0 (§3, §5 of the specification) for what this exporter writes."""
    if doc.get("asset", {}).get("version") != "2.0":
        raise _fail(where, "asset.version must be '2.0'")
    buffers = doc.get("buffers", [])
    for i, buf in enumerate(buffers):
        if "uri" not in buf and i != 0:
            raise _fail(where, f"buffers[{i}] has no uri; only buffer 0 may be the GLB's BIN chunk")
        if i == 0 and "uri" not in buf and not (buf["byteLength"] <= len(blob) <= buf["byteLength"] + 3):
            raise _fail(where, f"buffers[0].byteLength {buf['byteLength']} does not match the BIN chunk ({len(blob)})")
    for i, view in enumerate(doc.get("bufferViews", [])):
        buf = _index(doc, "buffers", view.get("buffer"), f"{where}: bufferViews[{i}]")
        end = view.get("byteOffset", 0) + view["byteLength"]
        if view["byteLength"] < 1 or end > buf["byteLength"]:
            raise _fail(where, f"bufferViews[{i}] bytes {view.get('byteOffset', 0)}..{end} outside buffer of {buf['byteLength']}")
        if view.get("target") not in (None, ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER):
            raise _fail(where, f"bufferViews[{i}].target {view.get('target')} is not 34962 or 34963")
    for i, acc in enumerate(doc.get("accessors", [])):
        at = f"accessors[{i}]"
        if acc.get("type") not in _COMPONENTS or acc.get("componentType") not in _SIZES:
            raise _fail(where, f"{at}: type {acc.get('type')} / componentType {acc.get('componentType')} invalid")
        if not isinstance(acc.get("count"), int) or acc["count"] < 1:
            raise _fail(where, f"{at}: count must be >= 1")
        size = _SIZES[acc["componentType"]]
        elem = size * _COMPONENTS[acc["type"]]
        if "bufferView" in acc:
            view = _index(doc, "bufferViews", acc["bufferView"], f"{where}: {at}")
            stride = view.get("byteStride", elem)
            off = acc.get("byteOffset", 0)
            if (view.get("byteOffset", 0) + off) % size:
                raise _fail(where, f"{at}: data not aligned to its {size}-byte components")
            if off + stride * (acc["count"] - 1) + elem > view["byteLength"]:
                raise _fail(where, f"{at}: {acc['count']} elements overrun bufferViews[{acc['bufferView']}]")
        sparse = acc.get("sparse")
        if sparse is not None:
            m = sparse.get("count")
            if not isinstance(m, int) or not 1 <= m <= acc["count"]:
                raise _fail(where, f"{at}.sparse.count must be 1..count")
            comp = sparse["indices"].get("componentType")
            if comp not in (5121, UINT16, UINT32):
                raise _fail(where, f"{at}.sparse.indices must be unsigned byte, short or int")
            for part, width in (("indices", _SIZES[comp]), ("values", elem)):
                sv = _index(doc, "bufferViews", sparse[part].get("bufferView"), f"{where}: {at}.sparse.{part}")
                if sv.get("target") is not None or "byteStride" in sv:
                    raise _fail(where, f"{at}.sparse.{part}: its bufferView must have no target or stride")
                if sparse[part].get("byteOffset", 0) + m * width > sv["byteLength"]:
                    raise _fail(where, f"{at}.sparse.{part}: {m} elements overrun their bufferView")
            if blob:
                iv = doc["bufferViews"][sparse["indices"]["bufferView"]]
                itype = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32}[comp]
                rows = np.frombuffer(blob, dtype=itype, count=m,
                                     offset=iv.get("byteOffset", 0) + sparse["indices"].get("byteOffset", 0))
                if (m > 1 and not (np.diff(rows.astype(np.int64)) > 0).all()) or int(rows.max()) >= acc["count"]:
                    raise _fail(where, f"{at}.sparse.indices must increase strictly and stay below count")
        for bound in ("min", "max"):
            if bound in acc and len(acc[bound]) != _COMPONENTS[acc["type"]]:
                raise _fail(where, f"{at}.{bound} has {len(acc[bound])} values for type {acc['type']}")
        if "min" in acc and "max" in acc and blob:
            arr = accessor_array(doc, blob, i).reshape(acc["count"], -1)
            # equal to the bit, the data's type widened to float64 (np.allclose with no tolerance said the
            # same at ten times the cost: a thousand accessors per face)
            if not (np.array_equal(arr.min(axis=0), np.asarray(acc["min"], dtype=np.float64))
                    and np.array_equal(arr.max(axis=0), np.asarray(acc["max"], dtype=np.float64))):
                raise _fail(where, f"{at}: min/max do not match the data")
    n_nodes = len(doc.get("nodes", []))
    for i, scene in enumerate(doc.get("scenes", [])):
        for n in scene.get("nodes", []):
            _index(doc, "nodes", n, f"{where}: scenes[{i}]")
    for m, mesh in enumerate(doc.get("meshes", [])):
        n_targets = None
        for p, prim in enumerate(mesh["primitives"]):
            at = f"meshes[{m}].primitives[{p}]"
            attrs = prim.get("attributes", {})
            if "POSITION" not in attrs:
                raise _fail(where, f"{at} has no POSITION")
            pos = _index(doc, "accessors", attrs["POSITION"], f"{where}: {at}")
            if pos["type"] != "VEC3" or pos["componentType"] != FLOAT or "min" not in pos or "max" not in pos:
                raise _fail(where, f"{at}: POSITION must be float VEC3 with min and max")
            counts = {_index(doc, "accessors", a, f"{where}: {at}.{k}")["count"] for k, a in attrs.items()}
            if len(counts) != 1:
                raise _fail(where, f"{at}: attributes have different counts {sorted(counts)}")
            if "indices" in prim:
                ind = _index(doc, "accessors", prim["indices"], f"{where}: {at}.indices")
                if ind["type"] != "SCALAR" or ind["componentType"] not in (5121, UINT16, UINT32):
                    raise _fail(where, f"{at}.indices must be unsigned SCALAR")
                if ind["count"] % 3 and prim.get("mode", 4) == 4:
                    raise _fail(where, f"{at}: {ind['count']} indices is not whole triangles")
                if blob and int(accessor_array(doc, blob, prim["indices"]).max()) >= pos["count"]:
                    raise _fail(where, f"{at}: an index is >= the vertex count {pos['count']}")
            if "material" in prim:
                _index(doc, "materials", prim["material"], f"{where}: {at}")
            targets = prim.get("targets", [])
            if n_targets is None:
                n_targets = len(targets)
            elif n_targets != len(targets):
                raise _fail(where, f"{at}: {len(targets)} morph targets, primitive 0 has {n_targets}")
            for t, target in enumerate(targets):
                for k, a in target.items():
                    acc = _index(doc, "accessors", a, f"{where}: {at}.targets[{t}].{k}")
                    if acc["count"] != pos["count"]:
                        raise _fail(where, f"{at}.targets[{t}].{k}: {acc['count']} elements for {pos['count']} vertices")
                    if k == "POSITION" and ("min" not in acc or "max" not in acc):
                        raise _fail(where, f"{at}.targets[{t}].POSITION needs min and max")
        if "weights" in mesh and len(mesh["weights"]) != (n_targets or 0):
            raise _fail(where, f"meshes[{m}].weights has {len(mesh['weights'])} values for {n_targets} targets")
        names = mesh.get("extras", {}).get("targetNames")
        if names is not None and len(names) != (n_targets or 0):
            raise _fail(where, f"meshes[{m}].extras.targetNames has {len(names)} names for {n_targets} targets")
    for a, anim in enumerate(doc.get("animations", [])):
        samplers = anim.get("samplers", [])
        seen = set()
        for c, ch in enumerate(anim.get("channels", [])):
            at = f"animations[{a}].channels[{c}]"
            if not isinstance(ch.get("sampler"), int) or not 0 <= ch["sampler"] < len(samplers):
                raise _fail(where, f"{at}: sampler {ch.get('sampler')} does not exist")
            tgt = ch["target"]
            key = (tgt.get("node"), tgt["path"])
            if key in seen:
                raise _fail(where, f"{at}: node {key[0]} path {key[1]} animated twice")
            seen.add(key)
            node = _index(doc, "nodes", tgt.get("node"), f"{where}: {at}")
            sampler = samplers[ch["sampler"]]
            t_in = _index(doc, "accessors", sampler["input"], f"{where}: {at}.input")
            t_out = _index(doc, "accessors", sampler["output"], f"{where}: {at}.output")
            if t_in["componentType"] != FLOAT or "min" not in t_in or "max" not in t_in:
                raise _fail(where, f"{at}: sampler input must be float with min and max")
            if blob:
                times = accessor_array(doc, blob, sampler["input"])
                if times.size > 1 and not (np.diff(times) > 0).all():
                    raise _fail(where, f"{at}: sampler input times are not strictly increasing")
                if times.min() < 0:
                    raise _fail(where, f"{at}: negative time")
            if tgt["path"] == "weights":
                if "mesh" not in node:
                    raise _fail(where, f"{at}: weights animated on node {tgt['node']} without a mesh")
                nt = len(doc["meshes"][node["mesh"]]["primitives"][0].get("targets", []))
                per_key = nt * (3 if sampler.get("interpolation") == "CUBICSPLINE" else 1)
                if nt == 0 or t_out["count"] != t_in["count"] * per_key:
                    raise _fail(where, f"{at}: {t_out['count']} weights for {t_in['count']} times × {nt} targets")
            elif tgt["path"] not in ("translation", "rotation", "scale"):
                raise _fail(where, f"{at}: unknown path {tgt['path']!r}")
    if n_nodes and "scene" in doc:
        _index(doc, "scenes", doc["scene"], f"{where}: scene")


def write_face_glb(path: str | PathLike[str], faps: FapSequence, *, audio: str | None = None,
                   fap_file: str | None = None, limited: bool = False) -> Path:
    """The project's face played by a FAP sequence, as a .glb at `path` (the sequence's fps and name);
    `limited`: at most 8 morph targets per mesh (`limited_meshes`), for three.js up to r132."""
    rig = default_rig()
    return write_glb(path, rig, rig.weights(faps), faps.fps, faps.name, audio=audio, fap_file=fap_file,
                     limited=limited)


def _side_share(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """How much of a symmetric movement belongs to the face's left (x > 0): 1 beyond half the mouth's
    half-width to the left, 0 as far to the right, a raised-cosine blend between (0.5 on the midline)."""
    t = np.clip(x / MOUTH_HALF_WIDTH + 0.5, 0.0, 1.0)
    out: NDArray[np.float64] = 0.5 - 0.5 * np.cos(np.pi * t)
    return out


def arkit_morphs(rig: FaceRig, neutral: dict[str, float], face: FaceUnits) -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """ARKit's 52 morph targets on the face: each driven shape is the face posed at the channel
    movement its weight 1 stands for (coartic.runtime.rigs.ARKIT_BASIS, through the same FAPs and
    rig as the FAP morph set; the jaw's turn taken at its full angle, as a blendshape is linear).
    A Left/Right pair is the pair's symmetric movement split between the face's sides
    (`_side_share`; Left = the face's own left), so the two at equal weights add up to it. The
    eyeBlinkLeft/Right shut the lid of FAP 19/20 as the FAP file's blinks do; an emotion's shapes
    (brows, eyeWide, eyeSquint, cheekSquint, mouthSmile, mouthFrown) are the face posed at their
    FAPs (coartic.runtime.expression.ARKIT_EXPRESSION), each on its own side already. The shapes
    coartic does not drive (gaze, nose, cheekPuff, tongueOut, ...) are present and move nothing."""
    from coartic.runtime.expression import ARKIT_EXPRESSION

    fields = np.zeros((len(ARKIT_NAMES), rig.mesh.n_vertices, 3))
    left = _side_share(rig.mesh.vertices[:, 0])[:, None]

    def posed(delta: dict[str, float]) -> NDArray[np.float64]:
        chans = {c: np.array([neutral[c] + delta.get(c, 0.0)]) for c in neutral}
        faps = channels_to_faps(chans, neutral, face, "arkit", 25.0)
        out: NDArray[np.float64] = rig.pose(rig.weights(faps)[0]) - rig.mesh.vertices
        return out

    def at_faps(values: dict[int, float]) -> NDArray[np.float64]:
        mask = np.zeros((1, N_FAPS), dtype=bool)
        held = np.zeros((1, N_FAPS), dtype=np.int64)
        for fap, v in values.items():
            mask[0, fap - 1], held[0, fap - 1] = True, int(round(v))
        out: NDArray[np.float64] = rig.pose(rig.weights(FapSequence("arkit", 25.0, mask, held))[0]) - rig.mesh.vertices
        return out

    for k, name in enumerate(ARKIT_NAMES):
        if name in ARKIT_BLINKS:  # the lid shut as the FAP file's blinks shut it
            fields[k] = at_faps({ARKIT_BLINKS[name]: BLINK_CLOSED})
            continue
        if name in ARKIT_EXPRESSION:
            fields[k] = at_faps(ARKIT_EXPRESSION[name])
            continue
        if name not in ARKIT_BASIS:
            continue
        for side, share in (("Left", left), ("Right", 1.0 - left)):
            if name.endswith(side):
                twin = name[: -len(side)] + ("Right" if side == "Left" else "Left")
                pair = {c: ARKIT_BASIS[name].get(c, 0.0) + ARKIT_BASIS[twin].get(c, 0.0)
                        for c in {*ARKIT_BASIS[name], *ARKIT_BASIS[twin]}}
                fields[k] = posed(pair) * share
                break
        else:
            fields[k] = posed(ARKIT_BASIS[name])
    return ARKIT_NAMES, fields


def export_gltf(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter (coartic.runtime.exporters): NAME.glb with the FAP morph set, or ARKit's
    (`settings.gltf_morphs == "arkit"`, weights from coartic.runtime.rigs.arkit_weights)."""
    animation = fed.animation
    path = settings.out / f"{settings.name}.glb"
    fap_file = settings.files["fap"].name if "fap" in settings.files else None
    if settings.gltf_morphs == "arkit":
        rig = default_rig()
        write_glb(path, rig, fed.once(arkit_weights), animation.fps, settings.name, audio=settings.audio_name(),
                  fap_file=fap_file, morphs=arkit_morphs(rig, animation.neutral, settings.face))
    else:
        write_face_glb(path, fed.faps, audio=settings.audio_name(),
                       fap_file=fap_file, limited=settings.gltf_morphs == "eight")
    return {"gltf": path}
