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

PART_NAMES: tuple[str, ...] = ("skin", "cavity", "upper_teeth", "lower_teeth", "eyes")

SKIN = (0.87, 0.66, 0.54)
LIP = (0.70, 0.24, 0.28)
TEETH = (0.93, 0.91, 0.84)
CAVITY = (0.16, 0.03, 0.05)
EYE_WHITE = (0.95, 0.95, 0.93)
IRIS = (0.20, 0.14, 0.10)
HAIR = (0.24, 0.16, 0.11)

# Proportions of an adult face, mm. The mouth's half-width sets MW; the nose base height sets MNS.
MOUTH_HALF_WIDTH = 25.0
NOSE_BASE_Y = 30.0
UPPER_LIP_HEIGHT = 9.0  # vermilion, at the midline
LOWER_LIP_HEIGHT = 10.0
FACE_TOP = 125.0  # hairline, above the lip line
FACE_BOTTOM = 78.0  # below the chin point
# Where the jaw turns: the temporomandibular joints, on the axis x through this point (y, z).
JAW_PIVOT = (22.0, -85.0)

_NU = 41  # columns of the skin grid (odd: one column on the midline)
_NV_UP = 26  # rows above the lip line
_NV_DOWN = 17  # rows below it


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

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def in_part(self, name: str) -> NDArray[np.bool_]:
        mask: NDArray[np.bool_] = self.part == PART_NAMES.index(name)
        return mask

    def point(self, fp: str) -> NDArray[np.float64]:
        return self.vertices[self.feature_points[fp]]

    @property
    def mns(self) -> float:
        """Mouth-nose separation, mm: nose base (9.15) to the upper inner lip midpoint (2.2)."""
        return float(self.point("9.15")[1] - self.point("2.2")[1])

    @property
    def mw(self) -> float:
        """Mouth width, mm: between the lip corners (8.3 left, 8.4 right)."""
        return float(self.point("8.3")[0] - self.point("8.4")[0])


def _grid_x(u: NDArray[np.float64]) -> NDArray[np.float64]:
    # denser at the midline: dx/du is 0.5 at u = 0 against 1 on average
    out: NDArray[np.float64] = 0.5 * u + 0.5 * u**3
    return out


def _half_width(y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Half-width of the face mask at height y: narrow chin, widest at the cheekbones."""
    knots_y = np.array([-FACE_BOTTOM, -66.0, -40.0, 0.0, 40.0, 70.0, 100.0, FACE_TOP])
    knots_w = np.array([16.0, 36.0, 54.0, 64.0, 72.0, 74.0, 68.0, 50.0])
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
    lower_lip = 6.0 * lip_region * np.exp(-(((y + 4.5) / 6.5) ** 2))
    corners = -3.0 * (_bump(x, y, MOUTH_HALF_WIDTH + 3.0, 0.0, 5.0, 6.0) + _bump(x, y, -MOUTH_HALF_WIDTH - 3.0, 0.0, 5.0, 6.0))
    labiomental = -3.0 * _bump(x, y, 0.0, -19.0, 14.0, 4.0)
    chin = 7.0 * _bump(x, y, 0.0, -45.0, 16.0, 13.0)
    out: NDArray[np.float64] = base + nose + nostrils + sockets + brows + cheeks + upper_lip + lower_lip + corners + labiomental + chin
    return out


def _skin() -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.int64], NDArray[np.int64], dict[str, int], NDArray[np.float64]]:
    """Grid vertices (x, y, z), upper flags, triangles, slit pairs, lip feature points, colours."""
    u = np.linspace(-1.0, 1.0, _NU)
    vu = np.linspace(0.0, 1.0, _NV_UP + 1)  # 0 = the lip line
    vd = np.linspace(0.0, 1.0, _NV_DOWN + 1)[1:]
    # rows are closer together near the lips: 1.9 mm at the lip line, ~10 mm at the forehead
    y_rows = np.concatenate([-FACE_BOTTOM * (0.25 * vd[::-1] + 0.75 * vd[::-1] ** 2),
                             FACE_TOP * (0.2 * vu + 0.8 * vu**2)])
    lip_row = _NV_DOWN  # index of y = 0
    n_rows = y_rows.size
    xs = _grid_x(u)[None, :] * _half_width(y_rows)[:, None]
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
    vertices = np.column_stack([xy, z])
    upper = np.concatenate([upper, np.zeros(cut_cols.size, dtype=bool)])
    # the sides of the head: the mask's rim continued backwards, so that a turned face is not a shell
    rim = np.concatenate([index[0, :], index[1:, -1], index[-1, -2::-1], index[-2:0:-1, 0]])
    back = vertices[rim] * np.array([0.82, 1.0, 0.0]) + np.array([0.0, 0.0, -45.0])
    back[:, 1] = np.where(back[:, 1] < -FACE_BOTTOM + 1, back[:, 1] + 12.0, back[:, 1])  # under the chin
    skirt = vertices.shape[0] + np.arange(rim.size)
    for i in range(rim.size):
        j = (i + 1) % rim.size
        tris += [(rim[i], skirt[i], skirt[j]), (rim[i], skirt[j], rim[j])]
    vertices = np.concatenate([vertices, back])
    upper = np.concatenate([upper, upper[rim]])
    # lips: vermilion between the lip line and the borders, inside the corners
    x, y = vertices[:, 0], vertices[:, 1]
    # how far inside the vermilion border (mm), blended over 1.5 mm so the coarse grid shows no steps
    inside = np.where(y >= 0, _upper_lip_edge(x) - y, _lower_lip_edge(x) + y)
    inside = np.minimum(inside, MOUTH_HALF_WIDTH - np.abs(x))
    lip = np.clip(inside / 1.5 + 0.5, 0.0, 1.0)[:, None]
    colors = lip * np.array(LIP) + (1.0 - lip) * np.array(SKIN)
    # eyebrows and a hairline: darker bands that make the face read as one at a glance
    brow = 0.85 * np.clip(1.3 - np.hypot((np.abs(x) - 30.0) / 17.0, (y - 79.0 + 0.004 * (np.abs(x) - 30.0) ** 2) / 7.0), 0, 1)
    hair = np.clip((y - 104.0) / 6.0, 0.0, 1.0)
    dark = np.maximum(brow, hair)[:, None]
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
    slit = np.column_stack([index[lip_row, cut_cols], lower_copy])
    return vertices, upper, np.array(tris, dtype=np.int64), slit, fps, colors


def _strip(points: NDArray[np.float64], height: float, thickness: float) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A curved band (teeth row) through `points` (its top edge), `height` down, with a back face."""
    n = points.shape[0]
    front_top = points
    front_bot = points - np.array([0.0, height, 0.0])
    back_top = points - np.array([0.0, 0.0, thickness])
    back_bot = front_bot - np.array([0.0, 0.0, thickness])
    verts = np.concatenate([front_top, front_bot, back_top, back_bot])
    tris = []
    for i in range(n - 1):
        a, b, c, d = i, i + 1, n + i + 1, n + i
        tris += [(a, d, c), (a, c, b)]  # front, facing +z
        a2, b2, c2, d2 = 2 * n + i, 2 * n + i + 1, 3 * n + i + 1, 3 * n + i
        tris += [(a2, b2, c2), (a2, c2, d2)]  # back
        tris += [(d, d + 1, 3 * n + i + 1), (d, 3 * n + i + 1, 3 * n + i)]  # bottom (biting edge)
    return verts, np.array(tris, dtype=np.int64)


def _teeth(upper: bool) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A row of teeth along the dental arch, hidden behind the closed lips at rest."""
    x = np.linspace(-22.0, 22.0, 13)
    lip_front = skin_depth(np.zeros(1), np.zeros(1))[0]
    z_front = lip_front - (11.0 if upper else 15.0)
    z = z_front - 14.0 * (x / 26.0) ** 2
    top = 9.0 if upper else -2.0  # upper incisors overlap the lower ones by 1 mm
    y = top - 1.5 * (x / 22.0) ** 2 * (1 if upper else -1)
    pts = np.column_stack([x, y, z])
    return _strip(pts, 10.0 if upper else 8.5, 3.0)


def _cavity() -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The dark inside of the mouth: a curved sheet behind the teeth, seen when the lips part."""
    xs = np.linspace(-34.0, 34.0, 9)
    ys = np.linspace(-42.0, 16.0, 9)
    gx, gy = np.meshgrid(xs, ys)
    gz = skin_depth(gx, gy) - 15.0 - 10.0 * (gx / 34.0) ** 2
    verts = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    tris = []
    n = xs.size
    for r in range(ys.size - 1):
        for c in range(n - 1):
            a, b, cc, d = r * n + c, r * n + c + 1, (r + 1) * n + c + 1, (r + 1) * n + c
            tris += [(a, b, cc), (a, cc, d)]
    return verts, np.array(tris, dtype=np.int64)


def _eye(cx: float) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """A low-polygon eyeball in its socket, iris towards +z."""
    radius, cy = 11.0, 62.0
    cz = skin_depth(np.array([cx]), np.array([cy]))[0] - 4.0
    n_lat, n_lon = 8, 12
    verts = [(cx, cy, cz + radius)]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            verts.append((cx + radius * np.sin(th) * np.cos(ph), cy + radius * np.sin(th) * np.sin(ph), cz + radius * np.cos(th)))
    verts.append((cx, cy, cz - radius))
    v = np.array(verts)
    tris = []
    for j in range(n_lon):
        tris.append((0, 1 + j, 1 + (j + 1) % n_lon))
    for i in range(n_lat - 2):
        for j in range(n_lon):
            a = 1 + i * n_lon + j
            b = 1 + i * n_lon + (j + 1) % n_lon
            tris += [(a, a + n_lon, b + n_lon), (a, b + n_lon, b)]
    last = v.shape[0] - 1
    for j in range(n_lon):
        a = 1 + (n_lat - 2) * n_lon + j
        b = 1 + (n_lat - 2) * n_lon + (j + 1) % n_lon
        tris.append((a, last, b))
    polar = np.arccos(np.clip((v[:, 2] - cz) / radius, -1, 1))
    colors = np.where((polar < 0.45)[:, None], np.array(IRIS), np.array(EYE_WHITE))
    return v, np.array(tris, dtype=np.int64), colors


def build_face() -> FaceMesh:
    """The project's face: deterministic, so every run and every file shows the same face."""
    skin_v, upper, skin_t, slit, fps, skin_c = _skin()
    parts: list[tuple[str, NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]] = [
        ("skin", skin_v, skin_t, skin_c)
    ]
    cav_v, cav_t = _cavity()
    parts.append(("cavity", cav_v, cav_t, np.tile(CAVITY, (cav_v.shape[0], 1))))
    for name, up in (("upper_teeth", True), ("lower_teeth", False)):
        tv, tt = _teeth(up)
        parts.append((name, tv, tt, np.tile(TEETH, (tv.shape[0], 1))))
    ev_l, et_l, ec_l = _eye(32.0)
    ev_r, et_r, ec_r = _eye(-32.0)
    parts.append(("eyes", np.concatenate([ev_l, ev_r]), np.concatenate([et_l, et_r + ev_l.shape[0]]),
                  np.concatenate([ec_l, ec_r])))
    vertices, colors, part, tris = [], [], [], {}
    offset = 0
    for name, v, t, c in parts:
        vertices.append(v)
        colors.append(c)
        part.append(np.full(v.shape[0], PART_NAMES.index(name), dtype=np.int64))
        tris[name] = t + offset
        offset += v.shape[0]
    all_upper = np.zeros(offset, dtype=bool)
    all_upper[: upper.size] = upper
    return FaceMesh(vertices=np.concatenate(vertices), colors=np.concatenate(colors), part=np.concatenate(part),
                    upper=all_upper, triangles=tris, feature_points=fps, slit=slit)
