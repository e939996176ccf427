"""A low-polygon face generated here, with its MPEG-4 feature points.

The face is built from formulas (no scanned or downloaded model, so it is the project's own, under
the project's licence): a relief mask over a grid that is denser around the mouth, cut along the
lip line so that the mouth can open, plus the parts a mouth needs to look like one when it opens:
upper and lower teeth, a dark mouth cavity, and two eyes.

Coordinates are glTF's and MPEG-4's: millimetres, +y up, +z out of the face towards the viewer,
+x to the face's left (the viewer's right). The origin is on the lip line of the neutral face,
which has the mouth closed and the lips in contact (MPEG-4's neutral face).

Each vertex belongs to one part (`PART_NAMES`); the skin's vertices are also either above the lip
line ("upper", including the upper copy of every vertex on the cut) or below it ("lower"). The
feature points are vertices, named by their MPEG-4 number ("2.2" = upper inner lip midpoint).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

PART_NAMES: tuple[str, ...] = ("skin", "cavity", "upper_teeth", "lower_teeth", "eyes", "tongue", "eyelids", "skull")

SKIN = (0.87, 0.66, 0.54)
LIP = (0.70, 0.24, 0.28)
TEETH = (0.93, 0.91, 0.84)
CAVITY = (0.16, 0.03, 0.05)
EYE_WHITE = (0.95, 0.95, 0.93)
IRIS = (0.20, 0.14, 0.10)
HAIR = (0.24, 0.16, 0.11)
GUM = (0.80, 0.42, 0.45)
TONGUE = (0.78, 0.36, 0.38)
MUCOSA = (0.62, 0.20, 0.25)
PUPIL = (0.03, 0.03, 0.03)
SKIN_LID = (0.84, 0.62, 0.51)
LASH = (0.18, 0.12, 0.09)

# Proportions of an adult face, mm. The mouth's half-width sets MW; the nose base height sets MNS.
MOUTH_HALF_WIDTH = 25.0
NOSE_BASE_Y = 30.0
UPPER_LIP_HEIGHT = 9.0  # vermilion, at the midline
LOWER_LIP_HEIGHT = 10.0
FACE_TOP = 125.0  # hairline, above the lip line
FACE_BOTTOM = 68.0  # the chin point; the skull closes the head under it
EYE_X = 32.0  # the left eye's centre; the right one's is at -EYE_X
EYE_Y = 62.0
EYE_RADIUS = 11.0
LID_OPEN_ELEVATION = 0.30  # rad above the eye's centre: the open upper lid's edge, over the iris's top
LID_LOWER_ELEVATION = -0.42  # rad: the lower lid's edge, under the iris
# The lips' inner (mucosal) surface: rows going in from the lip line, (up or down, back) in mm at
# the midline, scaled to 0 at the corners. They keep in front of the teeth and gums at rest.
LIP_INNER_ROWS = ((0.8, 2.2), (2.8, 4.6), (6.5, 6.3), (10.5, 7.4))
LOWER_LIP_INNER_ROWS = ((0.8, 2.2), (2.8, 4.8), (6.5, 8.0), (9.5, 10.8))
# Feature points of the upper face on the skin (x, y mm; the face's left, the right mirrored): the
# brows' inner ends, tops and outer ends (MPEG-4 4.1, 4.3, 4.5; under the drawn brow band) and the
# cheeks (5.3, on the cheekbone under the eye), each the skin vertex nearest these places.
UPPER_FACE_POINTS: dict[str, tuple[float, float]] = {"4.1": (15.0, 78.5), "4.3": (30.0, 80.0), "4.5": (45.0, 78.0),
                                                     "5.3": (36.0, 38.0)}
# Where the jaw turns: the temporomandibular joints, on the axis x through this point (y, z).
JAW_PIVOT = (22.0, -85.0)

_NU = 49  # columns of the skin grid (odd: one column on the midline)
_NV_UP = 32  # rows above the lip line
_NV_DOWN = 26  # rows below it


@dataclass(frozen=True)
class FaceMesh:
    """Vertices of all parts (rest positions), triangles per part, colours, and feature points."""

    vertices: NDArray[np.float64]  # (n, 3)
    colors: NDArray[np.float64]  # (n, 3) sRGB in 0..1 (glTF export converts to linear)
    part: NDArray[np.int64]  # (n,) index into PART_NAMES
    upper: NDArray[np.bool_]  # (n,) skin vertex above the lip line (or on the cut's upper side)
    triangles: dict[str, NDArray[np.int64]]  # part name -> (m, 3) vertex indices, counter-clockwise seen from outside
    feature_points: dict[str, int]  # MPEG-4 feature point "g.n" -> vertex index
    slit: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))  # (k, 2): upper, lower copy along the cut
    upper_lid: dict[str, NDArray[np.bool_]] = field(default_factory=dict)  # "l"/"r" -> (n,) the upper lid's vertices
    lower_lid: dict[str, NDArray[np.bool_]] = field(default_factory=dict)  # "l"/"r" -> (n,) the lower lid's vertices

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def in_part(self, name: str) -> NDArray[np.bool_]:
        mask: NDArray[np.bool_] = self.part == PART_NAMES.index(name)
        return mask

    def point(self, fp: str) -> NDArray[np.float64]:
        return np.asarray(self.vertices[self.feature_points[fp]], dtype=np.float64)

    @property
    def mns(self) -> float:
        """Mouth-nose separation, mm: nose base (9.15) to the upper inner lip midpoint (2.2)."""
        return float(self.point("9.15")[1] - self.point("2.2")[1])

    @property
    def irisd(self) -> float:
        """Iris diameter, mm (IRISD = IRISD0 / 1024): the eyes' iris spans 0.45 rad from the front."""
        return float(2.0 * EYE_RADIUS * np.sin(0.45))

    @property
    def mw(self) -> float:
        """Mouth width, mm: between the lip corners (8.3 left, 8.4 right)."""
        return float(self.point("8.3")[0] - self.point("8.4")[0])

    @property
    def ens(self) -> float:
        """Eye-nose separation, mm: the left pupil (3.5) above the nose base (9.15); the brows' and
        cheeks' FAPU is ENS / 1024."""
        return float(self.point("3.5")[1] - self.point("9.15")[1])

    @property
    def es(self) -> float:
        """Eye separation, mm: between the pupils (3.5 left, 3.6 right); the brows' squeeze is in ES / 1024."""
        return float(self.point("3.5")[0] - self.point("3.6")[0])


def _grid_x(u: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Columns (fraction of the half-width): denser at the midline near the mouth (dx/du 0.6 at
    u = 0 against 1 on average), even higher up and lower down, where the face is narrow and the
    rows far apart (columns squeezed there made slivers)."""
    near = np.exp(-((y / 30.0) ** 2))
    out: NDArray[np.float64] = near * (0.6 * u + 0.4 * u**3) + (1.0 - near) * u
    return out


def _half_width(y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Half-width of the face mask at height y: narrow chin, widest at the cheekbones."""
    knots_y = np.array([-FACE_BOTTOM, -58.0, -36.0, 0.0, 40.0, 70.0, 100.0, FACE_TOP])
    knots_w = np.array([36.0, 44.0, 56.0, 64.0, 72.0, 74.0, 68.0, 50.0])
    out: NDArray[np.float64] = np.interp(y, knots_y, knots_w)
    return out


def _bump(x: NDArray[np.float64], y: NDArray[np.float64], x0: float, y0: float, sx: float, sy: float) -> NDArray[np.float64]:
    out: NDArray[np.float64] = np.exp(-(((x - x0) / sx) ** 2) - ((y - y0) / sy) ** 2)
    return out


def _upper_lip_edge(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Height of the upper lip's outer (vermilion) border above the lip line, with a cupid's bow."""
    s = np.clip(1.0 - (x / MOUTH_HALF_WIDTH) ** 2, 0.0, 1.0)
    bow = 1.0 - 0.18 * np.exp(-((x / 4.0) ** 2))
    out: NDArray[np.float64] = UPPER_LIP_HEIGHT * s**0.6 * bow
    return out


def _lower_lip_edge(x: NDArray[np.float64]) -> NDArray[np.float64]:
    s = np.clip(1.0 - (x / MOUTH_HALF_WIDTH) ** 2, 0.0, 1.0)
    out: NDArray[np.float64] = LOWER_LIP_HEIGHT * s**0.5
    return out


def skin_depth(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """z of the skin surface: a flattened ellipsoid with nose, brows, eye sockets, cheeks, lips, chin."""
    a, b, c, yc = 82.0, 125.0, 100.0, 40.0
    base = c * np.clip(1.0 - np.abs(x / a) ** 2.6 - np.abs((y - yc) / b) ** 2.6, 0.0, None) ** (1 / 2.6)
    # nose: a ridge from the bridge (y 85) to the tip (y 34), ending at its base
    t = np.clip((85.0 - y) / 51.0, 0.0, 1.0)
    ridge_h = 6.0 + 17.0 * t**1.4
    ridge_w = 6.0 + 7.0 * t
    cut = 1.0 / (1.0 + np.exp(-(y - NOSE_BASE_Y - 2.5) / 1.6))  # falls off below the nose tip
    nose = ridge_h * np.exp(-((x / ridge_w) ** 2)) * cut * (y < 95.0)
    nostrils = 4.0 * (_bump(x, y, 11.0, NOSE_BASE_Y + 5.0, 5.0, 5.0) + _bump(x, y, -11.0, NOSE_BASE_Y + 5.0, 5.0, 5.0))
    sockets = -9.0 * (_bump(x, y, 32.0, 62.0, 15.0, 10.0) + _bump(x, y, -32.0, 62.0, 15.0, 10.0))
    brows = 4.0 * (_bump(x, y, 30.0, 78.0, 20.0, 5.0) + _bump(x, y, -30.0, 78.0, 20.0, 5.0))
    cheeks = 5.0 * (_bump(x, y, 42.0, 22.0, 16.0, 16.0) + _bump(x, y, -42.0, 22.0, 16.0, 16.0))
    lip_region = np.exp(-((x / (MOUTH_HALF_WIDTH * 0.95)) ** 4))
    upper_lip = 6.0 * lip_region * np.exp(-(((y - 3.5) / 6.0) ** 2))
    lower_lip = 7.0 * lip_region * np.exp(-(((y + 5.0) / 7.5) ** 2))
    # the lower face comes forwards again under the lip (the base alone would recede like a bird's)
    lower_face = 8.0 * np.exp(-(((y + 32.0) / 20.0) ** 2)) * np.exp(-((x / 34.0) ** 2))
    corners = -3.0 * (_bump(x, y, MOUTH_HALF_WIDTH + 3.0, 0.0, 5.0, 6.0) + _bump(x, y, -MOUTH_HALF_WIDTH - 3.0, 0.0, 5.0, 6.0))
    labiomental = -3.0 * _bump(x, y, 0.0, -19.0, 14.0, 4.0)
    chin = 7.0 * _bump(x, y, 0.0, -45.0, 16.0, 13.0)
    out: NDArray[np.float64] = base + nose + nostrils + sockets + brows + cheeks + upper_lip + lower_lip + lower_face + corners + labiomental + chin
    return out


def _skin() -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.int64], NDArray[np.int64], dict[str, int], NDArray[np.float64]]:
    """Grid vertices (x, y, z), upper flags, triangles, slit pairs, lip feature points, colours."""
    u = np.linspace(-1.0, 1.0, _NU)
    vu = np.linspace(0.0, 1.0, _NV_UP + 1)  # 0 = the lip line
    vd = np.linspace(0.0, 1.0, _NV_DOWN + 1)[1:]
    # rows are closer together near the lips: 1.4 mm at the lip line, 6 mm at the forehead and chin
    y_rows = np.concatenate([-FACE_BOTTOM * (0.45 * vd[::-1] + 0.55 * vd[::-1] ** 2),
                             FACE_TOP * (0.35 * vu + 0.65 * vu**2)])
    lip_row = _NV_DOWN  # index of y = 0
    n_rows = y_rows.size
    xs = _grid_x(u[None, :], y_rows[:, None]) * _half_width(y_rows)[:, None]
    ys = np.repeat(y_rows[:, None], _NU, axis=1)
    index = np.arange(n_rows * _NU).reshape(n_rows, _NU)
    verts = [np.column_stack([xs.ravel(), ys.ravel()])]
    upper = (ys >= 0.0).ravel()
    # The cut: columns strictly between the corners get a second vertex on the lip line, used by
    # the triangles below it (the lower lip); the corners themselves stay one vertex.
    x_line = xs[lip_row]
    corner_l = int(np.argmin(np.abs(x_line - MOUTH_HALF_WIDTH)))
    corner_r = int(np.argmin(np.abs(x_line + MOUTH_HALF_WIDTH)))
    cut_cols = np.arange(corner_r + 1, corner_l)
    lower_copy = index.size + np.arange(cut_cols.size)
    verts.append(np.column_stack([x_line[cut_cols], np.zeros(cut_cols.size)]))
    below_index = index.copy()
    below_index[lip_row, cut_cols] = lower_copy
    tris = []
    for r in range(n_rows - 1):
        idx = below_index if r < lip_row else index  # the row pair below the lip line uses the lower copies
        for c in range(_NU - 1):
            a, b, cc, d = idx[r, c], idx[r, c + 1], idx[r + 1, c + 1], idx[r + 1, c]
            # split along the diagonal that points away from the midline: symmetric left and right
            if (c < _NU // 2) == (r < lip_row):
                tris += [(a, b, cc), (a, cc, d)]
            else:
                tris += [(a, b, d), (b, cc, d)]
    xy = np.concatenate(verts)
    z = skin_depth(xy[:, 0], xy[:, 1])
    # the mask's outermost columns and top row dip 1.8 mm under the skull's surface, so that its
    # edge tucks in instead of standing out as a step in profile
    dip = np.zeros(z.size)
    dip[index[:, [1, -2]].ravel()] = 1.0  # the next columns in part: no thin triangle between
    dip[index[-2]] = 1.0
    dip[index[:, [0, -1]].ravel()] = 1.8
    dip[index[-1]] = 1.8
    z = z - dip
    vertices = np.column_stack([xy, z])
    upper = np.concatenate([upper, np.zeros(cut_cols.size, dtype=bool)])
    # the lips' inner surfaces: rows going in from the cut (up and back for the upper lip, down and
    # back for the lower), the corners shared, so that parted lips show their thickness
    n_grid = vertices.shape[0]
    cut_x = x_line[cut_cols]
    scale = np.clip(1.0 - (cut_x / MOUTH_HALF_WIDTH) ** 2, 0.0, 1.0) ** 0.35
    extra: list[NDArray[np.float64]] = []
    n_extra = 0
    for up in (True, False):
        first = index[lip_row, cut_cols] if up else lower_copy
        rows = [first]
        for dy, dz in (LIP_INNER_ROWS if up else LOWER_LIP_INNER_ROWS):
            pts = np.column_stack([cut_x, (dy if up else -dy) * scale, z[first] - dz * scale])
            rows.append(n_grid + n_extra + np.arange(cut_x.size))
            extra.append(pts)
            n_extra += cut_x.size
        ends = (int(index[lip_row, corner_r]), int(index[lip_row, corner_l]))
        for r0, r1 in zip(rows[:-1], rows[1:]):
            for c in range(cut_x.size - 1):
                a, b, cc, d = r0[c], r0[c + 1], r1[c + 1], r1[c]
                tris += [(a, d, cc), (a, cc, b)] if (c < cut_x.size // 2) else [(a, d, b), (b, d, cc)]
            tris += [(ends[0], r1[0], r0[0]), (ends[1], r0[-1], r1[-1])]
    vertices = np.concatenate([vertices, *extra])
    upper = np.concatenate([upper, np.ones(cut_x.size * len(LIP_INNER_ROWS), dtype=bool),
                            np.zeros(cut_x.size * len(LIP_INNER_ROWS), dtype=bool)])
    is_inner = np.zeros(vertices.shape[0], dtype=bool)
    is_inner[n_grid:] = True
    # lips: vermilion between the lip line and the borders, inside the corners
    x, y = vertices[:, 0], vertices[:, 1]
    # how far inside the vermilion border (mm), blended over 1.5 mm so the coarse grid shows no steps
    inside = np.where(y >= 0, _upper_lip_edge(x) - y, _lower_lip_edge(x) + y)
    inside = np.minimum(inside, MOUTH_HALF_WIDTH - np.abs(x))
    lip = np.clip(inside / 1.5 + 0.5, 0.0, 1.0)[:, None]
    colors = lip * np.array(LIP) + (1.0 - lip) * np.array(SKIN)
    colors[is_inner] = MUCOSA
    # eyebrows and a hairline: darker bands that make the face read as one at a glance
    x, y = vertices[:, 0], vertices[:, 1]
    brow = 0.85 * np.clip(1.3 - np.hypot((np.abs(x) - 30.0) / 17.0, (y - 79.0 + 0.004 * (np.abs(x) - 30.0) ** 2) / 7.0), 0, 1)
    hair = np.clip((y - 104.0) / 6.0, 0.0, 1.0)
    dark = (np.maximum(brow, hair) * ~is_inner)[:, None]
    colors = dark * np.array(HAIR) + (1.0 - dark) * colors
    mid = _NU // 2
    fps: dict[str, int] = {
        "2.2": int(index[lip_row, mid]),
        "2.3": int(lower_copy[mid - (corner_r + 1)]),
        "2.4": int(index[lip_row, corner_l]),
        "2.5": int(index[lip_row, corner_r]),
    }
    # lip-mid points halfway to the corners, on the cut
    half_l = int(np.argmin(np.abs(x_line - MOUTH_HALF_WIDTH / 2)))
    half_r = int(np.argmin(np.abs(x_line + MOUTH_HALF_WIDTH / 2)))
    fps["2.6"] = int(index[lip_row, half_l])
    fps["2.7"] = int(index[lip_row, half_r])
    fps["2.8"] = int(lower_copy[half_l - (corner_r + 1)])
    fps["2.9"] = int(lower_copy[half_r - (corner_r + 1)])
    # the outer lip contour: the grid vertex nearest the vermilion border on the same columns
    for name, col, up in (("8.1", mid, True), ("8.2", mid, False), ("8.5", half_l, True), ("8.6", half_r, True),
                          ("8.7", half_l, False), ("8.8", half_r, False)):
        x0 = x_line[col:col + 1]
        target = float(_upper_lip_edge(x0)[0]) if up else -float(_lower_lip_edge(x0)[0])
        row = int(np.argmin(np.abs(y_rows - target)))
        fps[name] = int(index[row, col])
    # outer corners = inner corners: the cut ends in one vertex per side
    fps["8.3"] = fps["2.4"]
    fps["8.4"] = fps["2.5"]
    fps["9.15"] = int(index[int(np.argmin(np.abs(y_rows - NOSE_BASE_Y))), mid])
    fps["2.1"] = int(index[0, mid])  # bottom of the chin
    grid = vertices[:index.size, :2]
    for name, (px, py) in UPPER_FACE_POINTS.items():
        group, n = name.split(".")
        for fp, sx in ((name, px), (f"{group}.{int(n) + 1}", -px)):  # the right side's number is the next one
            fps[fp] = int(np.argmin(np.hypot(grid[:, 0] - sx, grid[:, 1] - py)))
    slit = np.column_stack([index[lip_row, cut_cols], lower_copy])
    return vertices, upper, np.array(tris, dtype=np.int64), slit, fps, colors


def _grid_triangles(rows: int, cols: int, offset: int = 0, wrap: bool = False) -> NDArray[np.int64]:
    """Two triangles per cell of a rows x cols vertex grid (row-major), the columns closed into a
    ring with `wrap`; the diagonal alternates so that neither half of a ring leans one way."""
    tris = []
    n_c = cols if wrap else cols - 1
    for r in range(rows - 1):
        for c in range(n_c):
            c1 = (c + 1) % cols
            a, b, cc, d = r * cols + c, r * cols + c1, (r + 1) * cols + c1, (r + 1) * cols + c
            if (r + c) % 2:
                tris += [(a, b, cc), (a, cc, d)]
            else:
                tris += [(a, b, d), (b, cc, d)]
    return np.array(tris, dtype=np.int64) + offset


_ARCH_HALF_WIDTH = 26.0  # mm: x of the last molars
_ARCH_DEPTH = 36.0  # mm behind the incisors there


def _arch(arc: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The dental arch seen from above, at arc lengths `arc` from the midline (signed, scaled so that
    the largest reaches the last molars): x, depth behind the incisors and the outward normal
    (x, z). The front is flatter than a parabola, so the lingual side, 10 mm in, does not bunch up."""
    xs = np.linspace(0.0, _ARCH_HALF_WIDTH, 400)
    ds = _ARCH_DEPTH * (xs / _ARCH_HALF_WIDTH) ** 2.3
    length = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(ds)))])
    x = np.sign(arc) * np.interp(np.abs(arc) / np.abs(arc).max() * length[-1], length, xs)
    depth = _ARCH_DEPTH * (np.abs(x) / _ARCH_HALF_WIDTH) ** 2.3
    slope = _ARCH_DEPTH * 2.3 * np.abs(x) ** 1.3 / _ARCH_HALF_WIDTH**2.3 * np.sign(x)
    normal = np.column_stack([slope, np.ones_like(x)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return x, depth, normal


def _teeth(upper: bool) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """A full row of teeth with its gum: a ribbon swept along the dental arch, the profile (labial
    face, biting edge, lingual face) going from the gum round the edge and back. The upper incisors'
    edge is 2.5 mm below the lip line and 5.4 mm behind it, where a lower lip pulled up and back
    meets it (/f v/); the lower incisors close 2 mm above that edge and 3.6 mm behind it."""
    # profile of the crown at the midline: (y, z behind the lip line, is gum), edge first round
    if upper:
        profile = [(12.5, 9.9, True), (10.0, 8.9, True), (7.5, 8.4, False), (3.0, 7.0, False), (-1.0, 5.85, False),
                   (-2.5, 5.4, False), (-2.5, 6.6, False), (1.0, 8.6, False), (5.0, 10.6, False), (9.0, 12.2, True)]
        tooth_w = (8.5, 6.5, 7.5, 7.0, 7.0, 10.0, 10.0)
    else:
        profile = [(-13.0, 13.8, True), (-9.0, 12.8, True), (-7.0, 12.0, False), (-3.0, 10.2, False),
                   (-0.5, 9.0, False), (-0.5, 10.0, False), (-4.0, 11.8, False), (-8.0, 14.4, True)]
        tooth_w = (5.0, 6.0, 7.0, 7.0, 7.0, 11.0, 11.0)
    # columns every ~2.6 mm of arch, and one on every boundary between two teeth (darker there)
    bounds = np.concatenate([[0.0], np.cumsum(tooth_w)])
    arc = np.concatenate([np.linspace(a, b, int(np.ceil((b - a) / 2.6)) + 1)[:-1] for a, b in zip(bounds[:-1], bounds[1:])]
                         + [bounds[-1:]])
    s = np.concatenate([-arc[:0:-1], arc])
    x, depth, normal = _arch(s)
    lip_z = float(skin_depth(np.zeros(1), np.zeros(1))[0])
    b0 = 5.4 if upper else 9.0  # depth of the incisors' labial face at the edge, the arch's reference
    verts, colors = [], []
    at_bound = np.isin(np.round(np.abs(s), 6), np.round(bounds, 6))
    for y, back, gum in profile:
        # height sinks towards the molars a little (the curve of Spee), depth follows the arch normal
        yy = y - (1 if upper else -1) * 1.0 * (x / 25.0) ** 2
        zz = lip_z - b0 - depth - (back - b0) * normal[:, 1]
        xx = x - (back - b0) * normal[:, 0]
        verts.append(np.column_stack([xx, np.full_like(x, yy), zz]))
        shade = np.where(at_bound, 0.78, 1.0)[:, None]
        colors.append(np.tile(GUM, (x.size, 1)) if gum else shade * np.array(TEETH))
    v = np.concatenate(verts)
    tris = _grid_triangles(len(profile), x.size)
    return v, tris, np.concatenate(colors)


def _cavity() -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The dark inside of the mouth: the back half of an ellipsoid opening towards the lips, so that
    whatever is seen through the parted lips and past the teeth and tongue is dark."""
    lip_z = float(skin_depth(np.zeros(1), np.zeros(1))[0])
    cz = lip_z - 6.0
    n_u, n_v = 20, 7  # around the rim, towards the back
    phi = np.linspace(0.0, 2.0 * np.pi, n_u, endpoint=False)
    t = np.linspace(0.0, 0.8, n_v) * np.pi / 2  # stops short of the back pole, closed by a fan
    ry = np.where(np.sin(phi) > 0, 20.0, 24.0)
    x = 28.0 * np.cos(t)[:, None] * np.cos(phi)[None, :]
    y = ry[None, :] * np.cos(t)[:, None] * np.sin(phi)[None, :] - 2.0
    # the rim stays 7 mm under the skin all round (the face curves back towards the cheeks)
    rim_z = skin_depth(x[0], y[0]) - 7.0
    back_z = cz - 42.0
    z = rim_z[None, :] + (back_z - rim_z[None, :]) * np.sin(t)[:, None]
    verts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    tris = _grid_triangles(n_v, n_u, wrap=True)
    # the back: a small ring closed by a fan of n_u triangles about its centre (wide enough angles)
    centre = verts.shape[0]
    verts = np.concatenate([verts, [[0.0, -2.0, cz - 42.0]]])
    last = (n_v - 1) * n_u
    cap = [(last + j, last + (j + 1) % n_u, centre) for j in range(n_u)]
    return verts, np.concatenate([tris, np.array(cap, dtype=np.int64)])


def _tongue() -> tuple[NDArray[np.float64], NDArray[np.int64], dict[str, int]]:
    """The tongue lying on the floor of the mouth, its tip behind the lower incisors: a grid from
    the tip backwards (rows) and from side to side over the top (columns), the sides going down
    to the floor. Feature points 6.1 (tip), 6.2 (body), 6.3 / 6.4 (left / right border)."""
    lip_z = float(skin_depth(np.zeros(1), np.zeros(1))[0])
    tip_z = lip_z - 12.8  # behind the lower incisors
    n_b, n_a = 11, 13
    b = np.linspace(0.0, 1.0, n_b)[:, None]
    a = np.linspace(-1.0, 1.0, n_a)[None, :]
    length = 34.0
    half_w = 7.0 + 14.0 * np.sqrt(np.clip(b / 0.45, 0.0, 1.0))
    height = 7.0 + 7.5 * np.sin(np.pi * np.clip(b / 0.9, 0.0, 1.0)) ** 0.7
    floor = -12.5
    x = half_w * np.sin(np.pi * a / 2)
    y = floor + height * np.cos(np.pi * a / 2) ** 0.6
    z = tip_z - length * b - 3.0 * (1.0 - np.cos(np.pi * a / 2)) * (1.0 - b)
    verts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    mid = n_a // 2
    fps = {"6.1": mid, "6.2": int(round(0.55 * (n_b - 1))) * n_a + mid,
           "6.3": 3 * n_a + n_a - 3, "6.4": 3 * n_a + 2}
    return verts, _grid_triangles(n_b, n_a), fps


def eye_centre(cx: float) -> NDArray[np.float64]:
    """Centre of the eyeball at x = cx (mm), set into its socket."""
    cz = float(skin_depth(np.array([cx]), np.array([EYE_Y]))[0]) - 4.0
    return np.array([cx, EYE_Y, cz])


def _sphere_patch(centre: NDArray[np.float64], radius: float, elev: tuple[float, float], azim: float, n_e: int,
                  n_a: int) -> NDArray[np.float64]:
    """Vertices (n_e x n_a grid) of a patch of the sphere about `centre`: elevations elev[0]..elev[1]
    (radians, 0 = level with the centre, up positive), azimuths ±azim about the +z axis."""
    e = np.linspace(elev[0], elev[1], n_e)[:, None]
    az = np.linspace(-azim, azim, n_a)[None, :]
    x = radius * np.cos(e) * np.sin(az)
    y = radius * np.sin(e) + 0.0 * az
    z = radius * np.cos(e) * np.cos(az)
    out: NDArray[np.float64] = np.column_stack([x.ravel(), y.ravel(), z.ravel()]) + centre
    return out


def _eye(cx: float) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """An eyeball in its socket, iris towards +z: a latitude-longitude sphere about the z axis whose
    front pole is closed by a ring (no fan of slivers where it shows)."""
    c = eye_centre(cx)
    n_lat, n_lon = 11, 16
    th = np.linspace(np.pi / 12, np.pi - np.pi / 12, n_lat)[:, None]
    ph = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)[None, :]
    v = np.column_stack([(EYE_RADIUS * np.sin(th) * np.cos(ph)).ravel(), (EYE_RADIUS * np.sin(th) * np.sin(ph)).ravel(),
                         (EYE_RADIUS * np.cos(th) + 0.0 * ph).ravel()])
    tris = _grid_triangles(n_lat, n_lon, wrap=True)
    front, back = v.shape[0], v.shape[0] + 1
    v = np.concatenate([v, [[0.0, 0.0, EYE_RADIUS], [0.0, 0.0, -EYE_RADIUS]]]) + c
    last = (n_lat - 1) * n_lon
    caps = [(j, (j + 1) % n_lon, front) for j in range(n_lon)] + [(last + j, last + (j + 1) % n_lon, back)
                                                                 for j in range(n_lon)]
    polar = np.arccos(np.clip((v[:, 2] - c[2]) / EYE_RADIUS, -1, 1))
    colors = np.where((polar < 0.45)[:, None], np.array(IRIS), np.array(EYE_WHITE))
    colors[polar < 0.2] = PUPIL
    return v, np.concatenate([tris, np.array(caps, dtype=np.int64)]), colors


def _lids(cx: float) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_], int, int]:
    """Upper and lower eyelid of one eye: sphere patches just outside the eyeball. The upper lid
    (rows marked True) turns down about the eye's centre to blink, the lower one (the rest) up.
    Returns vertices, triangles, colours, the upper-lid mask, and the upper and lower lids' edge
    midpoints (feature points 3.1 / 3.2 and 3.3 / 3.4)."""
    c = eye_centre(cx)
    n_e, n_a = 6, 11
    up = _sphere_patch(c, EYE_RADIUS + 0.8, (LID_OPEN_ELEVATION, 1.1), 1.25, n_e, n_a)
    low = _sphere_patch(c, EYE_RADIUS + 0.6, (-1.3, LID_LOWER_ELEVATION), 1.25, 4, n_a)
    v = np.concatenate([up, low])
    tris = np.concatenate([_grid_triangles(n_e, n_a), _grid_triangles(4, n_a, offset=up.shape[0])])
    colors = np.tile(SKIN_LID, (v.shape[0], 1))
    colors[:n_a] = LASH  # the lid's edge: lashes
    colors[up.shape[0] + 3 * n_a:] = LASH
    is_upper = np.zeros(v.shape[0], dtype=bool)
    is_upper[: up.shape[0]] = True
    return v, tris, colors, is_upper, n_a // 2, up.shape[0] + 3 * n_a + n_a // 2  # the lower lid's top row: its edge


def _skull() -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """The rest of the head, closed: a subdivided icosahedron (no slivers) shaped to the face
    mask's superellipsoid, drawn in a little behind the mask wherever the mask covers it, with a
    neck under it. Hair on the crown and the back."""
    v, tris = _icosphere(3)
    a, b, c_front, c_back, yc, n = 82.0, 125.0, 100.0, 104.0, 40.0, 2.6
    d = v / np.linalg.norm(v, axis=1, keepdims=True)
    # radius along d to the superellipsoid |x/a|^n + |(y - yc)/b|^n + |z/c|^n = 1 about (0, yc, 0)
    cz = np.where(d[:, 2] > 0, c_front, c_back)
    r = (np.abs(d[:, 0] / a) ** n + np.abs(d[:, 1] / b) ** n + np.abs(d[:, 2] / cz) ** n) ** (-1 / n)
    p = d * r[:, None] + np.array([0.0, yc, 0.0])
    # behind the mask (inside its outline, in front): drawn in, 1 mm at the mask's rim, 25 mm inside
    x, y = p[:, 0], p[:, 1]
    inside = np.minimum.reduce([_half_width(y) - np.abs(x), y + FACE_BOTTOM, FACE_TOP - y])
    pull = np.where(p[:, 2] > 0, 1.0 + 24.0 * np.clip(inside / 18.0, 0.0, 1.0) ** 1.5, 0.0)
    p[:, 2] -= pull * np.clip(p[:, 2] / 15.0, 0.0, 1.0)
    hair = np.clip(np.maximum((y - 100.0) / 12.0, (-p[:, 2] - 10.0) / 20.0 * (y > 0)), 0.0, 1.0)[:, None]
    colors = hair * np.array(HAIR) + (1.0 - hair) * np.array(SKIN)
    # the neck: an elliptic tube from under the jaw down, behind the chin
    n_ring, n_rows = 24, 5
    ang = np.linspace(0.0, 2 * np.pi, n_ring, endpoint=False)
    ys = np.linspace(-55.0, -150.0, n_rows)
    neck = np.column_stack([np.tile(46.0 * np.cos(ang), n_rows), np.repeat(ys, n_ring),
                            np.tile(-22.0 + 44.0 * np.sin(ang), n_rows)])
    neck_t = _grid_triangles(n_rows, n_ring, offset=p.shape[0], wrap=True)
    verts = np.concatenate([p, neck])
    return verts, np.concatenate([tris, neck_t]), np.concatenate([colors, np.tile(SKIN, (neck.shape[0], 1))])


def _icosphere(level: int) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Unit icosphere: an icosahedron with every triangle split in four `level` times."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    verts = [np.array(p, dtype=float) / np.linalg.norm(p) for p in v]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(level):
        cache: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int) -> int:
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = verts[i] + verts[j]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new = []
        for i, j, k in faces:
            a, b, c = mid(i, j), mid(j, k), mid(k, i)
            new += [(i, a, c), (j, b, a), (k, c, b), (a, b, c)]
        faces = new
    return np.array(verts), np.array(faces, dtype=np.int64)


def orient(vertices: NDArray[np.float64], triangles: NDArray[np.int64]) -> NDArray[np.int64]:
    """The triangles wound alike (every shared edge run in opposite directions by its two
    triangles), each connected piece turned so that its normals point away from its centre:
    counter-clockwise seen from outside, as glTF's front faces and smooth normals need."""
    tris = triangles.copy()
    edges: dict[tuple[int, int], list[int]] = {}
    for t, (a, b, c) in enumerate(tris):
        for u, v in ((a, b), (b, c), (c, a)):
            edges.setdefault((min(u, v), max(u, v)), []).append(t)
    seen = np.zeros(len(tris), dtype=bool)
    for start in range(len(tris)):
        if seen[start]:
            continue
        seen[start] = True
        piece, queue = [start], [start]
        while queue:
            t = queue.pop()
            a, b, c = tris[t]
            for u, v in ((a, b), (b, c), (c, a)):
                for o in edges[(min(u, v), max(u, v))]:
                    if seen[o]:
                        continue
                    oa, ob, oc = tris[o]
                    if (u, v) in ((oa, ob), (ob, oc), (oc, oa)):  # run the same way: flip the other
                        tris[o] = (oa, oc, ob)
                    seen[o] = True
                    piece.append(o)
                    queue.append(o)
        p = vertices[tris[piece]]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        centre = vertices[np.unique(tris[piece])].mean(axis=0)
        if (n * (p.mean(axis=1) - centre)).sum() < 0:
            tris[piece] = tris[piece][:, [0, 2, 1]]
    return tris


def vertex_normals(vertices: NDArray[np.float64], triangles: NDArray[np.int64]) -> NDArray[np.float64]:
    """Unit normals per vertex: the area-weighted mean of its triangles' (wound alike, `orient`);
    +z for a vertex no triangle uses."""
    p = vertices[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    out = np.zeros_like(vertices)
    for i in range(3):
        np.add.at(out, triangles[:, i], n)
    length = np.linalg.norm(out, axis=1, keepdims=True)
    normals: NDArray[np.float64] = np.where(length > 0, out / np.where(length > 0, length, 1.0), [0.0, 0.0, 1.0])
    return normals


def min_angles(vertices: NDArray[np.float64], triangles: NDArray[np.int64]) -> NDArray[np.float64]:
    """Smallest interior angle (degrees) of each triangle: a sliver has one near 0."""
    p = vertices[triangles]
    out = np.full(triangles.shape[0], 180.0)
    for i in range(3):
        u = p[:, (i + 1) % 3] - p[:, i]
        w = p[:, (i + 2) % 3] - p[:, i]
        cos = (u * w).sum(axis=1) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        out = np.minimum(out, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return out

def build_face() -> FaceMesh:
    """The project's face: deterministic, so every run and every file shows the same face."""
    skin_v, upper, skin_t, slit, fps, skin_c = _skin()
    parts: list[tuple[str, NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]] = [
        ("skin", skin_v, skin_t, skin_c)
    ]
    cav_v, cav_t = _cavity()
    parts.append(("cavity", cav_v, cav_t, np.tile(CAVITY, (cav_v.shape[0], 1))))
    for name, up in (("upper_teeth", True), ("lower_teeth", False)):
        tv, tt, tc = _teeth(up)
        parts.append((name, tv, tt, tc))
    ev_l, et_l, ec_l = _eye(EYE_X)
    eye_pupil = ev_l.shape[0] - 2  # _eye's front pole (the last two vertices are the poles)
    ev_r, et_r, ec_r = _eye(-EYE_X)
    parts.append(("eyes", np.concatenate([ev_l, ev_r]), np.concatenate([et_l, et_r + ev_l.shape[0]]),
                  np.concatenate([ec_l, ec_r])))
    tg_v, tg_t, tg_fps = _tongue()
    parts.append(("tongue", tg_v, tg_t, np.tile(TONGUE, (tg_v.shape[0], 1))))
    lv_l, lt_l, lc_l, lu_l, mid_l, low_l = _lids(EYE_X)
    lv_r, lt_r, lc_r, lu_r, mid_r, low_r = _lids(-EYE_X)
    parts.append(("eyelids", np.concatenate([lv_l, lv_r]), np.concatenate([lt_l, lt_r + lv_l.shape[0]]),
                  np.concatenate([lc_l, lc_r])))
    parts.append(("skull", *_skull()))
    vertices, colors, part, tris = [], [], [], {}
    offset = 0
    starts: dict[str, int] = {}
    for name, v, t, c in parts:
        vertices.append(v)
        colors.append(c)
        part.append(np.full(v.shape[0], PART_NAMES.index(name), dtype=np.int64))
        tris[name] = orient(v, t) + offset
        starts[name] = offset
        offset += v.shape[0]
    all_upper = np.zeros(offset, dtype=bool)
    all_upper[: upper.size] = upper
    fps.update({k: v + starts["tongue"] for k, v in tg_fps.items()})
    fps["3.1"] = starts["eyelids"] + mid_l  # upper lid edge midpoints, left and right
    fps["3.2"] = starts["eyelids"] + lv_l.shape[0] + mid_r
    fps["3.3"] = starts["eyelids"] + low_l  # lower lid edge midpoints
    fps["3.4"] = starts["eyelids"] + lv_l.shape[0] + low_r
    fps["3.5"] = starts["eyes"] + eye_pupil  # the pupils: the eyeballs' front poles
    fps["3.6"] = starts["eyes"] + ev_l.shape[0] + eye_pupil
    lids: dict[str, dict[str, NDArray[np.bool_]]] = {"upper": {}, "lower": {}}
    for side, first, upper_mask in (("l", starts["eyelids"], lu_l), ("r", starts["eyelids"] + lv_l.shape[0], lu_r)):
        for which, rows in (("upper", upper_mask), ("lower", ~upper_mask)):
            mask = np.zeros(offset, dtype=bool)
            mask[first:first + rows.size] = rows
            lids[which][side] = mask
    return FaceMesh(vertices=np.concatenate(vertices), colors=np.concatenate(colors), part=np.concatenate(part),
                    upper=all_upper, triangles=tris, feature_points=fps, slit=slit,
                    upper_lid=lids["upper"], lower_lid=lids["lower"])
