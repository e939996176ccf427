"""MPEG-4 FAPs → vertex displacements: feature points, raised-cosine zones of influence, the jaw.

Each low-level lip FAP moves its feature point along its direction by value × FAPU (MNS / 1024 or
MW / 1024, of this face) and drags the vertices around it with the weight
(1 + cos(π d / d_max)) / 2 of their distance d, within the FAP's region (an upper-lip FAP never
moves the lower lip, which touches it at rest). Where zones of several feature points that move
the same way overlap (inner and outer lip contour, midpoint and lip-mid points), the raised
cosines are combined so that each feature point moves by exactly its own FAP and by no other
(interpolation with the raised cosine as kernel: a small linear system per group). Everything is
linear in the FAP values, so each FAP is one displacement field — a morph target.

The jaw (FAP 3, open_jaw) is a rotation about the axis through the jaw joints, chosen so that the
chin point (2.1) drops by value × MNS / 1024. It carries the chin, the lower lip, the lower teeth
and the lower mouth cavity (weights 1 there, blending to 0 towards the cheeks and the lip
corners). A rotation by θ is r ↦ r + sin θ (ω × r) + (1 − cos θ) ω × (ω × r): two displacement
fields with the weights sin θ and 1 − cos θ, so the jaw is two morph targets and turns exactly.

coartic's lower-lip FAPs give where the lower lip goes (LLO and LLP are measured in the head frame,
docs/RUNTIME.md), jaw included. So that the lower lip is not moved twice, the lower-lip FAPs are
applied relative to the jaw: each lower-lip field gets the FAP's displacement minus what the jaw
rotation already did at its feature point. The feature points then land where the FAPs say. A
stream that never sends a lower-lip FAP leaves that part of the lip riding on the jaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from coartic.face.mesh import JAW_PIVOT, MOUTH_HALF_WIDTH, FaceMesh, build_face
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import FAP_NAMES, MW_FAPS, N_FAPS, FapSequence

JAW_FAP = 3
X, Y, Z = np.eye(3)


@dataclass(frozen=True)
class FapZone:
    """One FAP on the mesh: its feature point, direction, region and zone radius."""

    fap: int
    point: str  # MPEG-4 feature point
    direction: tuple[float, float, float]
    region: str  # "upper", "lower" (skin above / below the lip line) or "lips" (both)
    group: str  # FAPs of a group are interpolated together (same region, same direction)
    d_max: float  # mm


def _z(fap: int, fp: str, direction: NDArray[np.float64], region: str, group: str, d_max: float) -> FapZone:
    return FapZone(fap, fp, (float(direction[0]), float(direction[1]), float(direction[2])), region, group, d_max)


_VERTICAL = 18.0  # mm: reaches the inner and outer contour and half the mouth, not the nose
_STRETCH = 24.0
_PUSH = 26.0

# ISO/IEC 14496-2 feature points and directions of the lip FAPs (x = the face's left).
ZONES: tuple[FapZone, ...] = (
    _z(4, "2.2", -Y, "upper", "upper_y", _VERTICAL),
    _z(5, "2.3", Y, "lower", "lower_y", _VERTICAL),
    _z(6, "2.4", X, "lips", "left_x", _STRETCH),
    _z(7, "2.5", -X, "lips", "right_x", _STRETCH),
    _z(8, "2.6", -Y, "upper", "upper_y", _VERTICAL),
    _z(9, "2.7", -Y, "upper", "upper_y", _VERTICAL),
    _z(10, "2.8", Y, "lower", "lower_y", _VERTICAL),
    _z(11, "2.9", Y, "lower", "lower_y", _VERTICAL),
    _z(12, "2.4", Y, "upper", "upper_y", _VERTICAL),
    _z(13, "2.5", Y, "upper", "upper_y", _VERTICAL),
    _z(12, "2.4", Y, "lower", "lower_y", _VERTICAL),
    _z(13, "2.5", Y, "lower", "lower_y", _VERTICAL),
    _z(16, "2.3", Z, "lower", "lower_z", _PUSH),
    _z(17, "2.2", Z, "upper", "upper_z", _PUSH),
    _z(51, "8.1", -Y, "upper", "upper_y", _VERTICAL),
    _z(52, "8.2", Y, "lower", "lower_y", _VERTICAL),
    _z(53, "8.3", X, "lips", "left_x", _STRETCH),
    _z(54, "8.4", -X, "lips", "right_x", _STRETCH),
    _z(55, "8.5", -Y, "upper", "upper_y", _VERTICAL),
    _z(56, "8.6", -Y, "upper", "upper_y", _VERTICAL),
    _z(57, "8.7", Y, "lower", "lower_y", _VERTICAL),
    _z(58, "8.8", Y, "lower", "lower_y", _VERTICAL),
    _z(59, "8.3", Y, "upper", "upper_y", _VERTICAL),
    _z(60, "8.4", Y, "upper", "upper_y", _VERTICAL),
    _z(59, "8.3", Y, "lower", "lower_y", _VERTICAL),
    _z(60, "8.4", Y, "lower", "lower_y", _VERTICAL),
)
LIP_FAPS: tuple[int, ...] = tuple(sorted({z.fap for z in ZONES}))
# FAPs whose feature point rides on the jaw: applied relative to it (module docstring).
LOWER_LIP_FAPS: frozenset[int] = frozenset(z.fap for z in ZONES if z.region == "lower" and z.point in
                                           ("2.3", "2.8", "2.9", "8.2", "8.7", "8.8"))
TARGET_NAMES: tuple[str, ...] = (*(FAP_NAMES[f - 1] for f in LIP_FAPS), "open_jaw_sin", "open_jaw_1mcos")
# A morph target is the displacement at FAP value 1024 (one whole MNS or MW), so that the weights,
# value / 1024, stay within ±1 for speech and a rig's sliders (Blender clamps to 0..1 by default
# but the animation plays any value).
TARGET_VALUE = 1024.0


def raised_cosine(d: NDArray[np.float64], d_max: float | NDArray[np.float64]) -> NDArray[np.float64]:
    """(1 + cos(π d / d_max)) / 2 within d_max, 0 beyond (d_max broadcasts against d)."""
    w: NDArray[np.float64] = 0.5 * (1.0 + np.cos(np.pi * np.minimum(d / d_max, 1.0)))
    return w


def _smooth01(t: NDArray[np.float64]) -> NDArray[np.float64]:
    t = np.clip(t, 0.0, 1.0)
    out: NDArray[np.float64] = 0.5 - 0.5 * np.cos(np.pi * t)
    return out


def jaw_weights(mesh: FaceMesh) -> NDArray[np.float64]:
    """How much each vertex turns with the jaw: chin, lower lip and lower teeth 1, the upper face 0."""
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    w = np.zeros(mesh.n_vertices)
    skin_lower = mesh.in_part("skin") & ~mesh.upper
    # on the lip line the lower lip turns fully between the corners and not at them; below, the
    # whole lower face does within a few centimetres, fading out towards the face's edge
    at_line = _smooth01((MOUTH_HALF_WIDTH - np.abs(x)) / (0.4 * MOUTH_HALF_WIDTH))
    depth = _smooth01(-y / 22.0)
    lateral = _smooth01((72.0 - np.abs(x)) / 30.0)
    w[skin_lower] = (lateral * (at_line + (1.0 - at_line) * depth))[skin_lower]
    w[mesh.in_part("lower_teeth")] = 1.0
    cav = mesh.in_part("cavity")
    w[cav] = _smooth01((4.0 - y) / 12.0)[cav]
    return w


@dataclass(frozen=True)
class FaceRig:
    """The mesh and its morph targets: `targets[k]` is the displacement (n, 3) of TARGET_NAMES[k]."""

    mesh: FaceMesh
    targets: NDArray[np.float64]  # (n_targets, n_vertices, 3)
    jaw: NDArray[np.float64]  # (n_vertices,) jaw weights

    @property
    def target_names(self) -> tuple[str, ...]:
        return TARGET_NAMES

    def fapu(self, fap: int) -> float:
        """This face's FAPU (mm) for a lip or jaw FAP."""
        return (self.mesh.mw if fap in MW_FAPS else self.mesh.mns) / 1024.0

    def jaw_angle(self, open_jaw: NDArray[np.float64]) -> NDArray[np.float64]:
        """Rotation (rad) that drops the chin point 2.1 by open_jaw × MNS / 1024."""
        drop = np.asarray(open_jaw, dtype=float) * self.fapu(JAW_FAP)
        ry, rz = self.mesh.point("2.1")[1] - JAW_PIVOT[0], self.mesh.point("2.1")[2] - JAW_PIVOT[1]
        # y(θ) - y(0) = ry (cos θ - 1) - rz sin θ = -drop  <=>  rz sin θ - ry cos θ = drop - ry
        r = math.hypot(ry, rz)
        phase = math.atan2(-ry, rz)  # rz sin θ - ry cos θ = r sin(θ + phase)
        arg = np.clip((drop - ry) / r, -1.0, 1.0)
        theta: NDArray[np.float64] = np.arcsin(arg) - phase
        return theta

    def weights(self, faps: FapSequence) -> NDArray[np.float64]:
        """Morph-target weights per frame, (n_frames, n_targets). Unsent FAPs hold their last value."""
        values = held_values(faps)
        ever_sent = np.maximum.accumulate(faps.mask, axis=0)
        lip = values[:, [f - 1 for f in LIP_FAPS]] / TARGET_VALUE
        theta = self.jaw_angle(values[:, JAW_FAP - 1])
        s, c = np.sin(theta), 1.0 - np.cos(theta)
        # lower-lip FAPs relative to the jaw: subtract the jaw's share at their feature points
        jaw_sin, jaw_cos = self.targets[-2], self.targets[-1]
        for k, fap in enumerate(LIP_FAPS):
            if fap not in LOWER_LIP_FAPS:
                continue
            zone = next(z for z in ZONES if z.fap == fap and z.region == "lower")
            v = self.mesh.feature_points[zone.point]
            along = np.asarray(zone.direction) @ np.stack([jaw_sin[v], jaw_cos[v]], axis=1)  # (2,)
            full = self.fapu(fap) * TARGET_VALUE  # mm moved by weight 1
            # a stream that never sends this FAP leaves the lip riding on the jaw
            lip[:, k] -= ever_sent[:, fap - 1] * (s * along[0] + c * along[1]) / full
        out: NDArray[np.float64] = np.column_stack([lip, s, c])
        return out

    def pose(self, weights: NDArray[np.float64]) -> NDArray[np.float64]:
        """Vertex positions (n, 3) for one row of weights (or (frames, n, 3) for several)."""
        w = np.asarray(weights, dtype=float)
        out: NDArray[np.float64] = self.mesh.vertices + np.tensordot(w, self.targets, axes=(w.ndim - 1, 0))
        return out


def held_values(faps: FapSequence) -> NDArray[np.float64]:
    """FAP values per frame with unmasked FAPs holding their last sent value (0 before any)."""
    mask, values = faps.mask, faps.values.astype(float)
    idx = np.where(mask, np.arange(faps.n_frames)[:, None], -1)
    last = np.maximum.accumulate(idx, axis=0)
    held: NDArray[np.float64] = np.where(last >= 0, np.take_along_axis(values, np.maximum(last, 0), axis=0), 0.0)
    return held


def _region_mask(mesh: FaceMesh, region: str) -> NDArray[np.bool_]:
    skin = mesh.in_part("skin")
    if region == "upper":
        return skin & mesh.upper
    if region == "lower":
        return skin & ~mesh.upper
    return skin


def build_rig(mesh: FaceMesh) -> FaceRig:
    """Displacement fields of every lip FAP and of the jaw on `mesh`."""
    for fp in {z.point for z in ZONES} | {"2.1", "9.15"}:
        if fp not in mesh.feature_points:
            raise AnimationError(f"the face mesh has no feature point {fp}, needed by the FAP zones")
    verts = mesh.vertices
    fields = {f: np.zeros((mesh.n_vertices, 3)) for f in LIP_FAPS}
    for group in sorted({z.group for z in ZONES}):
        zones = [z for z in ZONES if z.group == group]
        # feature points are vertices; two names on one vertex (inner and outer corner) are one point
        points = sorted({mesh.feature_points[z.point] for z in zones})
        where = verts[points]
        d_max = np.array([max(z.d_max for z in zones if mesh.feature_points[z.point] == p) for p in points])
        # kernel[i, j] = raised cosine of point j seen from point i; with its inverse the combined
        # weights interpolate: point j's field is 1 at point j and 0 at every other point of the group
        dist_pp = np.linalg.norm(where[:, None, :] - where[None, :, :], axis=2)
        coef = np.linalg.inv(raised_cosine(dist_pp, d_max[None, :]))
        for region in sorted({z.region for z in zones}):
            mask = _region_mask(mesh, region)
            dist = np.linalg.norm(verts[mask][:, None, :] - where[None, :, :], axis=2)
            interp = raised_cosine(dist, d_max[None, :]) @ coef  # (m, points): column j = point j's field
            for z in zones:
                if z.region != region:
                    continue
                v = mesh.feature_points[z.point]
                # FAPs on one vertex (inner and outer corner) share it: coartic sends them equal
                sharing = sum(1 for o in zones if mesh.feature_points[o.point] == v and o.region == region)
                fields[z.fap][mask] += np.outer(interp[:, points.index(v)] / sharing, z.direction)
    jaw = jaw_weights(mesh)
    r = verts - np.array([0.0, JAW_PIVOT[0], JAW_PIVOT[1]])
    cross = np.column_stack([np.zeros(len(r)), -r[:, 2], r[:, 1]])  # x̂ × r
    cross2 = np.column_stack([np.zeros(len(r)), -r[:, 1], -r[:, 2]])  # x̂ × (x̂ × r)
    fapu = {f: (mesh.mw if f in MW_FAPS else mesh.mns) / 1024.0 for f in LIP_FAPS}
    targets = [fields[f] * fapu[f] * TARGET_VALUE for f in LIP_FAPS]
    targets += [jaw[:, None] * cross, jaw[:, None] * cross2]
    return FaceRig(mesh=mesh, targets=np.stack(targets), jaw=jaw)


@lru_cache(maxsize=1)
def default_rig() -> FaceRig:
    """The project's face and its fields, built once per process (a third of a second)."""
    return build_rig(build_face())
