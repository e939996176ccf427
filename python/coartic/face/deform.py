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

from coartic.face.mesh import (EYE_RADIUS, EYE_X, JAW_PIVOT, LID_LOWER_ELEVATION, LID_OPEN_ELEVATION, MOUTH_HALF_WIDTH,
                               FaceMesh, build_face, eye_centre, skin_depth)
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
# The tongue (ISO/IEC 14496-2 FAPs 43-47): feature point, direction, and how far along the tongue
# from that point the movement reaches (mm, raised cosine). 43 and 45 are in MW, 44 and 46 in MNS;
# tongue_roll (47, angle units of 1e-5 rad) lifts both borders (6.3, 6.4) about the midline.
TONGUE_ZONES: dict[int, tuple[str, NDArray[np.float64], float]] = {
    43: ("6.1", -X, 16.0),  # shift_tongue_tip: to the face's right
    44: ("6.1", Y, 16.0),  # raise_tongue_tip
    45: ("6.1", Z, 22.0),  # thrust_tongue_tip
    46: ("6.2", Y, 20.0),  # raise_tongue
}
TONGUE_ROLL = 47
TONGUE_FAPS: tuple[int, ...] = (43, 44, 45, 46, TONGUE_ROLL)
# tongue_roll's target is the tongue rolled by this many angle units (0.5 rad), not 1024 (0.01 rad)
TONGUE_ROLL_TARGET = 50000.0
# FAPs whose feature point rides on the jaw: applied relative to it (module docstring).
LOWER_LIP_FAPS: frozenset[int] = frozenset(z.fap for z in ZONES if z.region == "lower" and z.point in
                                           ("2.3", "2.8", "2.9", "8.2", "8.7", "8.8"))
ON_JAW_FAPS: frozenset[int] = LOWER_LIP_FAPS | {44, 45, 46}
# Eyelids: close_t_l_eyelid (19) and close_t_r_eyelid (20) turn the upper lid down about the eye's
# centre, in IRISD (iris diameter / 1024) of the lid's edge midpoint 3.1 / 3.2.
LID_FAPS: dict[int, tuple[str, str]] = {19: ("l", "3.1"), 20: ("r", "3.2")}
# The upper face, which an emotion moves (coartic.runtime.expression; ISO/IEC 14496-2 groups 3-5):
# raise_l/r_i/m/o_eyebrow (31-36, ENS, up) at the brows' inner ends, tops and outer ends, the
# squeeze (37, 38, ES) drawing the inner ends towards the midline, lift_l/r_cheek (41, 42, ENS, up)
# at the cheekbones (5.3, 5.4), and close_b_l/r_eyelid (21, 22, IRISD, up) turning each lower lid
# up about its eye's centre. Each brow FAP moves its point exactly and fades to the brow's next
# point (raised cosines along the brow that add up to 1 between its points), to nothing at the
# midline and 15 mm past the outer end, and in height over the socket's rim below (to nothing at
# BROW_BELOW_MM) and the forehead above (at BROW_ABOVE_MM). The lips are out of every zone's reach:
# an expression leaves the /p b m/ closure and the /f v/ contact to the lip FAPs.
BROW_RAISE: dict[int, str] = {31: "4.1", 32: "4.2", 33: "4.3", 34: "4.4", 35: "4.5", 36: "4.6"}
BROW_SQUEEZE: dict[int, str] = {37: "4.1", 38: "4.2"}
CHEEK_LIFT: dict[int, str] = {41: "5.3", 42: "5.4"}
UPPER_FACE_FAPS: tuple[int, ...] = tuple(sorted({*BROW_RAISE, *BROW_SQUEEZE, *CHEEK_LIFT}))
ES_FAPS: frozenset[int] = frozenset(BROW_SQUEEZE)
LOWER_LID_FAPS: dict[int, tuple[str, str]] = {21: ("l", "3.3"), 22: ("r", "3.4")}
BROW_BELOW_MM = (66.0, 74.0)  # y: no movement under the first, all of it above the second
BROW_ABOVE_MM = (88.0, 112.0)  # y: all of it under the first, none above the second (the hairline)
BROW_PAST_OUTER_MM = 15.0
CHEEK_RADIUS_MM = 22.0
# A lower lip pulled back and up rolls in (its inner edge goes back and down, behind the upper
# incisors, as at /f v/): at ROLL_MAX when it is ROLL_FULL_MM behind rest and not lowered, none
# once it has dropped ROLL_OPEN_MM from the upper lip's level (an open mouth does not roll its lip).
ROLL_MAX = math.radians(55.0)
ROLL_FULL_MM = 2.0
ROLL_OPEN_MM = 3.0
ROLL_CENTRE = (-6.0, -2.5)  # (y, z from the lip line) of the roll's axis, inside the lower lip
# Protruded lips round (orbicularis oris): per mm the lips push forward (mean of FAPs 16 and 17),
# their lateral halves bunch towards the midline, the slit closes at the sides (the opening becomes
# an oval) and the inner lip surfaces turn out. The corners stay where FAPs 6/7 (53/54) put them.
FUNNEL_MEDIAL_MM = 0.9  # at the middle of each half of the mouth, per mm of protrusion
FUNNEL_CLOSE_MM = 0.45  # each lip towards the lip line there, per mm
FUNNEL_EVERT_MM = 0.8  # the inner lip surface forwards, per mm
TARGET_NAMES: tuple[str, ...] = (*(FAP_NAMES[f - 1] for f in LIP_FAPS), *(FAP_NAMES[f - 1] for f in TONGUE_FAPS),
                                 "funnel_lips",
                                 "open_jaw_sin", "open_jaw_1mcos", "roll_b_lip_sin", "roll_b_lip_1mcos",
                                 "close_t_l_eyelid_sin", "close_t_l_eyelid_1mcos",
                                 "close_t_r_eyelid_sin", "close_t_r_eyelid_1mcos",
                                 *(FAP_NAMES[f - 1] for f in UPPER_FACE_FAPS),
                                 "close_b_l_eyelid_sin", "close_b_l_eyelid_1mcos",
                                 "close_b_r_eyelid_sin", "close_b_r_eyelid_1mcos")
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
    w[mesh.in_part("tongue")] = 1.0
    cav = mesh.in_part("cavity")
    w[cav] = _smooth01((4.0 - y) / 12.0)[cav]
    # under the chin the skull closes the head: its front below the mouth goes with the jaw too
    skull = mesh.in_part("skull")
    z = mesh.vertices[:, 2]
    w[skull] = (_smooth01(-y / 22.0) * _smooth01((72.0 - np.abs(x)) / 30.0) * _smooth01(z / 30.0))[skull]
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
        """This face's FAPU (mm) for a lip, jaw, tongue, eyelid, brow or cheek FAP."""
        return face_fapu(self.mesh, fap)

    def index(self, name: str) -> int:
        return TARGET_NAMES.index(name)

    def lid_angle(self, close: NDArray[np.float64]) -> NDArray[np.float64]:
        """Rotation (rad) of an upper lid that drops its edge midpoint by close × IRISD / 1024."""
        r = EYE_RADIUS + 0.8
        drop = np.asarray(close, dtype=float) * self.mesh.irisd / 1024.0
        e0 = LID_OPEN_ELEVATION
        theta: NDArray[np.float64] = e0 - np.arcsin(np.clip(math.sin(e0) - drop / r, -1.0, 1.0))
        return theta

    def lower_lid_angle(self, close: NDArray[np.float64]) -> NDArray[np.float64]:
        """Rotation (rad, up) of a lower lid that raises its edge midpoint by close × IRISD / 1024."""
        r = EYE_RADIUS + 0.6
        rise = np.asarray(close, dtype=float) * self.mesh.irisd / 1024.0
        e0 = LID_LOWER_ELEVATION
        theta: NDArray[np.float64] = np.arcsin(np.clip(math.sin(e0) + rise / r, -1.0, 1.0)) - e0
        return theta

    def roll_angle(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """The lower lip's roll (rad) per frame from the held FAP values (see ROLL_MAX)."""
        back = -values[:, 16 - 1] * self.fapu(16)
        drop = np.maximum(-values[:, 5 - 1] * self.fapu(5), 0.0)
        phi: NDArray[np.float64] = (ROLL_MAX * np.clip(back / ROLL_FULL_MM, 0.0, 1.0)
                                    * np.clip(1.0 - drop / ROLL_OPEN_MM, 0.0, 1.0))
        return phi

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
        sent = (*LIP_FAPS, *TONGUE_FAPS)
        scale = np.array([TONGUE_ROLL_TARGET if f == TONGUE_ROLL else TARGET_VALUE for f in sent])
        lip = values[:, [f - 1 for f in sent]] / scale
        theta = self.jaw_angle(values[:, JAW_FAP - 1])
        s, c = np.sin(theta), 1.0 - np.cos(theta)
        # lower-lip and tongue FAPs relative to the jaw: subtract the jaw's share at their points
        jaw_sin, jaw_cos = self.targets[self.index("open_jaw_sin")], self.targets[self.index("open_jaw_1mcos")]
        for k, fap in enumerate(sent):
            if fap not in ON_JAW_FAPS:
                continue
            if fap in TONGUE_ZONES:
                point, direction = TONGUE_ZONES[fap][0], TONGUE_ZONES[fap][1]
            else:
                zone = next(z for z in ZONES if z.fap == fap and z.region == "lower")
                point, direction = zone.point, np.asarray(zone.direction)
            v = self.mesh.feature_points[point]
            along = direction @ np.stack([jaw_sin[v], jaw_cos[v]], axis=1)  # (2,)
            full = self.fapu(fap) * TARGET_VALUE  # mm moved by weight 1
            # a stream that never sends this FAP leaves the lip (tongue) riding on the jaw
            lip[:, k] -= ever_sent[:, fap - 1] * (s * along[0] + c * along[1]) / full
        roll = self.roll_angle(values) * ever_sent[:, 16 - 1]
        push = 0.5 * (values[:, 16 - 1] * self.fapu(16) + values[:, 17 - 1] * self.fapu(17))
        cols = [lip, np.maximum(push, 0.0), s, c, np.sin(roll), 1.0 - np.cos(roll)]
        for fap in LID_FAPS:
            lid = self.lid_angle(values[:, fap - 1])
            cols += [np.sin(lid), 1.0 - np.cos(lid)]
        cols.append(values[:, [f - 1 for f in UPPER_FACE_FAPS]] / TARGET_VALUE)
        for fap in LOWER_LID_FAPS:
            lid = self.lower_lid_angle(values[:, fap - 1])
            cols += [np.sin(lid), 1.0 - np.cos(lid)]
        out: NDArray[np.float64] = np.column_stack(cols)
        return out

    def pose(self, weights: NDArray[np.float64]) -> NDArray[np.float64]:
        """Vertex positions (n, 3) for one row of weights (or (frames, n, 3) for several)."""
        w = np.asarray(weights, dtype=float)
        out: NDArray[np.float64] = self.mesh.vertices + np.tensordot(w, self.targets, axes=(w.ndim - 1, 0))
        return out


def face_fapu(mesh: FaceMesh, fap: int) -> float:
    """The mesh's FAPU (mm) of `fap`: IRISD for the eyelids, ES for the brows' squeeze, ENS for the
    brows' and cheeks' raise, MW or MNS for the lips, jaw and tongue (ISO/IEC 14496-2's table)."""
    if fap in LID_FAPS or fap in LOWER_LID_FAPS:
        return mesh.irisd / 1024.0
    if fap in ES_FAPS:
        return mesh.es / 1024.0
    if fap in BROW_RAISE or fap in CHEEK_LIFT:
        return mesh.ens / 1024.0
    return (mesh.mw if fap in MW_FAPS else mesh.mns) / 1024.0


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
    for fp in ({z.point for z in ZONES} | {"2.1", "9.15", "6.1", "6.2", "3.1", "3.2", "3.3", "3.4", "3.5", "3.6"}
               | set(BROW_RAISE.values()) | set(CHEEK_LIFT.values())):
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
    fapu = {f: (mesh.mw if f in MW_FAPS else mesh.mns) / 1024.0 for f in (*LIP_FAPS, *TONGUE_FAPS)}
    targets = [fields[f] * fapu[f] * TARGET_VALUE for f in LIP_FAPS]
    targets += _tongue_targets(mesh, fapu)
    targets.append(funnel_field(mesh))
    jaw = jaw_weights(mesh)
    targets += _rotation(verts, (JAW_PIVOT[0], JAW_PIVOT[1]), jaw)
    lip_z = float(skin_depth(np.zeros(1), np.zeros(1))[0])
    targets += _rotation(verts, (ROLL_CENTRE[0], lip_z + ROLL_CENTRE[1]), roll_weights(mesh), backwards=True)
    for side in ("l", "r"):
        centre = eye_centre(EYE_X if side == "l" else -EYE_X)
        targets += _rotation(verts, (centre[1], centre[2]), mesh.upper_lid[side].astype(float))
    upper_face = upper_face_fields(mesh)
    targets += [upper_face[f] * face_fapu(mesh, f) * TARGET_VALUE for f in UPPER_FACE_FAPS]
    for side, _ in LOWER_LID_FAPS.values():
        centre = eye_centre(EYE_X if side == "l" else -EYE_X)
        targets += _rotation(verts, (centre[1], centre[2]), mesh.lower_lid[side].astype(float), backwards=True)
    return FaceRig(mesh=mesh, targets=np.stack(targets), jaw=jaw)


def _hat(u: NDArray[np.float64], knots: tuple[float, float, float]) -> NDArray[np.float64]:
    """1 at knots[1], falling as a raised cosine to 0 at knots[0] and knots[2] (0 beyond): hats on
    consecutive knots add up to 1 between them."""
    lo, mid, hi = knots
    t = np.where(u < mid, (mid - u) / (mid - lo), (u - mid) / (hi - mid))
    return raised_cosine(np.clip(t, 0.0, 1.0), 1.0) * (u > lo) * (u < hi)


def upper_face_fields(mesh: FaceMesh) -> dict[int, NDArray[np.float64]]:
    """Each brow and cheek FAP's displacement (n, 3) per FAP unit of movement at its feature point
    (1 mm there; the module's comment at BROW_RAISE): on the skin only."""
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    skin = mesh.in_part("skin").astype(float)
    height = _smooth01((y - BROW_BELOW_MM[0]) / (BROW_BELOW_MM[1] - BROW_BELOW_MM[0])) * _smooth01(
        (BROW_ABOVE_MM[1] - y) / (BROW_ABOVE_MM[1] - BROW_ABOVE_MM[0]))
    out: dict[int, NDArray[np.float64]] = {}
    for side, raises, squeeze in ((1.0, (31, 33, 35), 37), (-1.0, (32, 34, 36), 38)):
        u = side * x  # distance from the midline towards this brow
        at = [side * mesh.point(BROW_RAISE[f])[0] for f in raises]
        knots = [0.0, *at, at[-1] + BROW_PAST_OUTER_MM]
        for j, fap in enumerate(raises):
            w = _hat(u, (knots[j], knots[j + 1], knots[j + 2])) * height * skin
            out[fap] = np.outer(w, Y)
            if j == 0:  # the squeeze draws the inner end towards the midline (MPEG-4: the left brow's to the right)
                out[squeeze] = np.outer(w, -side * X)
    for fap, fp in CHEEK_LIFT.items():
        d = np.hypot(x - mesh.point(fp)[0], y - mesh.point(fp)[1])
        out[fap] = np.outer(raised_cosine(d, CHEEK_RADIUS_MM) * skin, Y)
    return out


def _rotation(verts: NDArray[np.float64], axis_yz: tuple[float, float], weight: NDArray[np.float64],
              backwards: bool = False) -> list[NDArray[np.float64]]:
    """The two fields of a turn about an x-parallel axis through (y, z), sin θ and 1 − cos θ
    (module docstring), scaled per vertex by `weight`. A positive turn moves what is in front of the
    axis down (the jaw opening, a lid closing); `backwards` moves what is above the axis back."""
    r = verts - np.array([0.0, axis_yz[0], axis_yz[1]])
    sign = -1.0 if backwards else 1.0
    cross = sign * np.column_stack([np.zeros(len(r)), -r[:, 2], r[:, 1]])  # ω × r, ω = ±x̂
    cross2 = np.column_stack([np.zeros(len(r)), -r[:, 1], -r[:, 2]])  # ω × (ω × r)
    return [weight[:, None] * cross, weight[:, None] * cross2]


def funnel_field(mesh: FaceMesh) -> NDArray[np.float64]:
    """The lips' rounding per mm of protrusion (FUNNEL_*): zero at the corners and the midline."""
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    skin = mesh.in_part("skin")
    lateral = np.sin(np.pi * np.clip(np.abs(x) / MOUTH_HALF_WIDTH, 0.0, 1.0))  # 0 mid and at corners
    near = _smooth01((16.0 - np.abs(y)) / 10.0) * _smooth01((MOUTH_HALF_WIDTH + 8.0 - np.abs(x)) / 8.0)
    out = np.zeros((mesh.n_vertices, 3))
    out[:, 0] = -np.sign(x) * FUNNEL_MEDIAL_MM * lateral * near
    at_cut = _smooth01((8.0 - np.abs(y)) / 6.0)
    out[:, 1] = np.where(mesh.upper, -1.0, 1.0) * FUNNEL_CLOSE_MM * lateral ** 0.5 * at_cut * near
    lip_z = float(skin_depth(np.zeros(1), np.zeros(1))[0])
    inside = np.clip((lip_z - mesh.vertices[:, 2]) / 4.0, 0.0, 1.0) * (np.abs(x) < MOUTH_HALF_WIDTH)
    out[:, 2] = FUNNEL_EVERT_MM * inside * np.sqrt(np.clip(1 - (x / MOUTH_HALF_WIDTH) ** 2, 0, 1))
    out[~skin] = 0.0
    return out


def roll_weights(mesh: FaceMesh) -> NDArray[np.float64]:
    """How much of the lower lip rolls: its upper part between the corners, fading out towards the
    outer vermilion border (which stays where the FAPs put it) and the corners."""
    x, y = mesh.vertices[:, 0], mesh.vertices[:, 1]
    w = np.zeros(mesh.n_vertices)
    lower = mesh.in_part("skin") & ~mesh.upper
    at_line = _smooth01((MOUTH_HALF_WIDTH - np.abs(x)) / (0.3 * MOUTH_HALF_WIDTH))
    w[lower] = (at_line * _smooth01((y + 9.0) / 5.0))[lower]
    return w


def _tongue_targets(mesh: FaceMesh, fapu: dict[int, float]) -> list[NDArray[np.float64]]:
    """Fields of the tongue FAPs (TONGUE_ZONES, and the roll), on the tongue's vertices only."""
    verts = mesh.vertices
    on = mesh.in_part("tongue").astype(float)
    out = []
    for fap in TONGUE_FAPS:
        if fap == TONGUE_ROLL:
            # both borders up about the midline: a point |x| from it rises |x| × angle
            tip = verts[mesh.feature_points["6.1"]]
            reach = raised_cosine(np.abs(verts[:, 2] - tip[2]), 30.0)
            field = np.outer(on * reach * np.abs(verts[:, 0]) * TONGUE_ROLL_TARGET * 1e-5, Y)
        else:
            point, direction, d_max = TONGUE_ZONES[fap]
            d = np.linalg.norm(verts - verts[mesh.feature_points[point]], axis=1)
            field = np.outer(on * raised_cosine(d, d_max), direction) * fapu[fap] * TARGET_VALUE
        out.append(field)
    return out


@lru_cache(maxsize=1)
def default_rig() -> FaceRig:
    """The project's face and its fields, built once per process (a third of a second)."""
    return build_rig(build_face())
