"""Pictures drawn with Pillow alone: the runtime's previews (coartic.runtime.preview) without matplotlib.

matplotlib's import and its figure machinery cost `coartic speak` more CPU than the rest of the
command together (bench/results/speak_pictures.txt: 1.0 s of pictures for 2.1 s of speech). What
the previews need of it is small: filled outlines and lines anti-aliased, text, plain axes with
ticks. Here shapes are drawn SUPERSAMPLE times larger and reduced (a box filter: SUPERSAMPLE² levels
of coverage, as Agg's anti-aliasing), text is set at the final size by FreeType in matplotlib's
own font (DejaVu Sans, read from its package data without importing it), and ticks follow
matplotlib's AutoLocator rule (the smallest step of 1, 2, 2.5, 5 × 10^k that keeps the ticks within
the room for their labels). Sizes are given in points and converted with the picture's dpi, as in
matplotlib, so a picture keeps its layout.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw, ImageFont

from coartic.runtime.errors import AnimationError

SUPERSAMPLE = 3
RGB = tuple[int, int, int]
BLACK: RGB = (0, 0, 0)
WHITE: RGB = (255, 255, 255)
MINUS = "\u2212"  # matplotlib's minus sign on tick labels
TICK_STEPS = (1.0, 2.0, 2.5, 5.0, 10.0)  # matplotlib's AutoLocator steps
AXES_LW = 0.8  # points: matplotlib's axes.linewidth, also its ticks' width
TICK_LENGTH = 3.5  # points, outwards
TICK_PAD = 3.5  # points between a tick and its label
LABEL_PAD = 4.0  # points between the tick labels and the axis label
MARGIN = 0.05  # of the data range on each side (matplotlib's axes.xmargin / ymargin)
MARKER_EDGE = 1.0  # points: matplotlib draws a marker's edge (markeredgewidth) around its markersize


def rgb(color: str) -> RGB:
    """'#rrggbb' or a grey level '0.8' (matplotlib's notation) → an RGB triple."""
    if color.startswith("#") and len(color) == 7:
        return (int(color[1:3], 16), int(color[3:5], 16), int(color[5:7], 16))
    level = round(float(color) * 255)
    return (level, level, level)


@lru_cache(maxsize=1)
def _font_file() -> str | None:
    spec = importlib.util.find_spec("matplotlib")  # its data, not its import
    for root in (spec.submodule_search_locations or []) if spec is not None else []:
        path = Path(root) / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"
        if path.is_file():
            return str(path)
    return None


@lru_cache(maxsize=16)
def font(size_px: float) -> ImageFont.FreeTypeFont:
    """DejaVu Sans (matplotlib's default font) at `size_px`; Pillow's own font without matplotlib."""
    path = _font_file()
    if path is not None:
        return ImageFont.truetype(path, size_px)
    own = ImageFont.load_default(size_px)
    if not isinstance(own, ImageFont.FreeTypeFont):
        raise AnimationError("the pictures' text needs Pillow built with FreeType (pip install --force-reinstall "
                             "pillow), or write no pictures: --preview none")
    return own


@dataclass(frozen=True)
class Box:
    """A rectangle of the picture in pixels (x to the right, y down) showing data limits (y up)."""

    x0: float
    y0: float
    x1: float
    y1: float
    xlim: tuple[float, float]
    ylim: tuple[float, float]

    @property
    def width(self) -> int:
        return int(round(self.x1)) - int(round(self.x0))

    @property
    def height(self) -> int:
        return int(round(self.y1)) - int(round(self.y0))

    def px(self, x: float | NDArray[np.float64], y: float | NDArray[np.float64], scale: float = 1.0,
           local: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Data (x, y) → pixels of the picture, or of the box's own tile (`local`), `scale` times larger."""
        (a, b), (c, d) = self.xlim, self.ylim
        u = (np.asarray(x, dtype=float) - a) / (b - a) * self.width
        v = (d - np.asarray(y, dtype=float)) / (d - c) * self.height
        if not local:
            u, v = u + round(self.x0), v + round(self.y0)
        return u * scale, v * scale


def equal_aspect(x0: float, y0: float, x1: float, y1: float, xlim: tuple[float, float],
                 ylim: tuple[float, float]) -> Box:
    """The largest box of equal x and y scales centred in the cell (matplotlib's aspect 'equal')."""
    w, h = xlim[1] - xlim[0], ylim[1] - ylim[0]
    s = min((x1 - x0) / w, (y1 - y0) / h)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    return Box(cx - 0.5 * s * w, cy - 0.5 * s * h, cx + 0.5 * s * w, cy + 0.5 * s * h, xlim, ylim)


class Tile:
    """One box's content drawn SUPERSAMPLE times larger, then reduced and pasted (anti-aliasing)."""

    def __init__(self, box: Box, background: RGB, dpi: float) -> None:
        self.box, self.dpi = box, dpi
        self.image = Image.new("RGB", (box.width * SUPERSAMPLE, box.height * SUPERSAMPLE), background)
        self.draw = ImageDraw.Draw(self.image)

    def _points(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> list[tuple[float, float]]:
        u, v = self.box.px(x, y, SUPERSAMPLE, local=True)
        return list(zip(u.tolist(), v.tolist()))

    def width_px(self, lw_points: float) -> int:
        return max(1, int(round(lw_points * self.dpi / 72.0 * SUPERSAMPLE)))

    def polygon(self, xy: NDArray[np.float64], fill: RGB | None, edge: RGB | None = None, lw: float = 1.0) -> None:
        """A closed outline of data points (n, 2), filled and/or stroked `lw` points wide."""
        pts = self._points(xy[:, 0], xy[:, 1])
        if fill is not None:
            self.draw.polygon(pts, fill=fill)
        if edge is not None:
            self.draw.line([*pts, pts[0], pts[1]], fill=edge, width=self.width_px(lw))

    def line(self, x: NDArray[np.float64], y: NDArray[np.float64], color: RGB, lw: float) -> None:
        self.draw.line(self._points(np.asarray(x), np.asarray(y)), fill=color, width=self.width_px(lw))

    def markers(self, x: NDArray[np.float64], y: NDArray[np.float64], color: RGB, size: float) -> None:
        """Filled circles `size` points across (matplotlib's markersize) and their edge."""
        r = 0.5 * (size + MARKER_EDGE) * self.dpi / 72.0 * SUPERSAMPLE
        for u, v in self._points(np.asarray(x), np.asarray(y)):
            self.draw.ellipse((u - r, v - r, u + r, v + r), fill=color)

    def vlines(self, xs: NDArray[np.float64], color: RGB, lw: float) -> None:
        u, _ = self.box.px(np.asarray(xs), np.zeros(len(xs)), SUPERSAMPLE, local=True)
        h = self.image.height
        for x in u.tolist():
            self.draw.line([(x, 0), (x, h)], fill=color, width=self.width_px(lw))

    def paste_into(self, picture: Image.Image) -> None:
        picture.paste(self.image.reduce(SUPERSAMPLE), (int(round(self.box.x0)), int(round(self.box.y0))))


def frame(draw: ImageDraw.ImageDraw, box: Box, dpi: float, lw: float = AXES_LW) -> None:
    """The box's four spines, drawn around it."""
    w = max(1, int(round(lw * dpi / 72.0)))
    x0, y0 = int(round(box.x0)) - w, int(round(box.y0)) - w
    x1, y1 = int(round(box.x0)) + box.width + w - 1, int(round(box.y0)) + box.height + w - 1
    draw.rectangle((x0, y0, x1, y1), outline=BLACK, width=w)


def text(draw: ImageDraw.ImageDraw, at: tuple[float, float], s: str, size_pt: float, dpi: float,
         anchor: str = "ms", fill: RGB = BLACK) -> None:
    """`s` at `at` (pixels) with a Pillow anchor ('ms': centred on the baseline, 'mb' bottom, ...)."""
    draw.text(at, s, fill=fill, font=font(size_pt * dpi / 72.0), anchor=anchor)


def vertical_text(picture: Image.Image, at: tuple[float, float], s: str, size_pt: float, dpi: float) -> None:
    """`s` turned 90° anticlockwise (a y-axis label), its box's left edge at at[0], centred on at[1]."""
    f = font(size_pt * dpi / 72.0)
    l, t, r, b = f.getbbox(s, anchor="ls")
    ascent, descent = f.getmetrics()
    w, h = int(math.ceil(r - l)) + 2, ascent + descent
    mask = Image.new("L", (w, h), 0)
    ImageDraw.Draw(mask).text((1 - l, ascent), s, fill=255, font=f, anchor="ls")
    mask = mask.transpose(Image.Transpose.ROTATE_90)
    picture.paste(BLACK, (int(round(at[0])), int(round(at[1] - 0.5 * mask.height))), mask)


def text_width(s: str, size_pt: float, dpi: float) -> float:
    return float(font(size_pt * dpi / 72.0).getlength(s))


def line_height(size_pt: float, dpi: float) -> float:
    ascent, descent = font(size_pt * dpi / 72.0).getmetrics()
    return float(ascent + descent)


def with_margins(lo: float, hi: float) -> tuple[float, float]:
    """Data limits with matplotlib's 5 % margins (a flat series gets ±1 % of its value, or ±0.05)."""
    if hi - lo <= 0.0:
        pad = 0.01 * abs(lo) if lo != 0.0 else 0.05
        return lo - pad, hi + pad
    pad = MARGIN * (hi - lo)
    return lo - pad, hi + pad


def ticks(lo: float, hi: float, room: int) -> NDArray[np.float64]:
    """Ticks within [lo, hi] at most `room` steps apart: the smallest step of 1, 2, 2.5, 5 × 10^k
    not below (hi - lo) / room (matplotlib's AutoLocator); a smaller one if that leaves fewer than two."""
    span = hi - lo
    if not (span > 0 and math.isfinite(span)):
        return np.array([lo])
    room = max(1, room)
    magnitude = 10.0 ** math.floor(math.log10(span / room))
    steps = [s * magnitude * f for f in (0.1, 1.0, 10.0) for s in TICK_STEPS[:-1]]
    steps = sorted(s for s in steps if s > 0)
    raw = span / room
    first = next(i for i, s in enumerate(steps) if s >= raw * (1 - 1e-9))
    for step in reversed(steps[:first + 1]):
        k0, k1 = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        if k1 - k0 + 1 >= 2:
            return np.arange(k0, k1 + 1, dtype=np.float64) * step
    return np.array([lo, hi])


def tick_labels(values: NDArray[np.float64]) -> list[str]:
    """As matplotlib writes them: the decimals the step needs, its minus sign."""
    if values.size < 2:
        decimals = 0 if float(values[0]).is_integer() else 2
    else:
        step = float(values[1] - values[0])
        decimals = max(0, -math.floor(math.log10(step) + 1e-12))
        if not math.isclose(step * 10**decimals, round(step * 10**decimals), abs_tol=1e-6):
            decimals += 1
    out = []
    for v in values.tolist():
        s = f"{v:.{decimals}f}"
        if float(s) == 0.0:
            s = s.lstrip("-")
        out.append(s.replace("-", MINUS))
    return out


def y_tick_room(box: Box, dpi: float, size_pt: float) -> int:
    # matplotlib's YAxis.get_tick_space: the axis length over twice the label size, at most 9
    return min(9, int(box.height * 72.0 / dpi // (2 * size_pt)))


def x_tick_room(box: Box, dpi: float, size_pt: float) -> int:
    return min(9, int(box.width * 72.0 / dpi // (3 * size_pt)))


def y_axis(draw: ImageDraw.ImageDraw, box: Box, dpi: float, size_pt: float) -> float:
    """Ticks and their labels on the box's left side; returns the labels' widest width (px)."""
    values = ticks(*box.ylim, y_tick_room(box, dpi, size_pt))
    labels = tick_labels(values)
    x_axis_at = round(box.x0)
    length, pad, w = TICK_LENGTH * dpi / 72.0, TICK_PAD * dpi / 72.0, max(1, round(AXES_LW * dpi / 72.0))
    widest = 0.0
    _, ys = box.px(np.zeros(values.size), values)
    for y, label in zip(ys.tolist(), labels):
        y = round(y)
        draw.line([(x_axis_at - w - length, y), (x_axis_at - w, y)], fill=BLACK, width=w)
        text(draw, (x_axis_at - w - length - pad, y), label, size_pt, dpi, anchor="rm")
        widest = max(widest, text_width(label, size_pt, dpi))
    return widest


def x_axis(draw: ImageDraw.ImageDraw, box: Box, dpi: float, size_pt: float, labelled: bool = True) -> None:
    """Ticks on the box's bottom side, and their labels below them when `labelled`."""
    values = ticks(*box.xlim, x_tick_room(box, dpi, size_pt))
    y_axis_at = round(box.y0) + box.height
    length, pad, w = TICK_LENGTH * dpi / 72.0, TICK_PAD * dpi / 72.0, max(1, round(AXES_LW * dpi / 72.0))
    xs, _ = box.px(values, np.zeros(values.size))
    for x, label in zip(xs.tolist(), tick_labels(values)):
        x = round(x)
        draw.line([(x, y_axis_at + w - 1), (x, y_axis_at + w + length)], fill=BLACK, width=w)
        if labelled:
            text(draw, (x, y_axis_at + w + length + pad), label, size_pt, dpi, anchor="mt")


def y_axis_width(box: Box, dpi: float, size_pt: float) -> float:
    """How far (px) y_axis's ticks and labels reach left of the box."""
    labels = tick_labels(ticks(*box.ylim, y_tick_room(box, dpi, size_pt)))
    widest = max(text_width(s, size_pt, dpi) for s in labels)
    return (TICK_LENGTH + TICK_PAD) * dpi / 72.0 + widest + max(1, round(AXES_LW * dpi / 72.0))


def save_png(picture: Image.Image, path: Path, dpi: float) -> None:
    # compress_level 6: the default; optimize=True costs several times the encoding for a few %
    picture.save(path, format="PNG", dpi=(dpi, dpi))


def segment_labels_at(draw: ImageDraw.ImageDraw, box: Box, labels: Sequence[tuple[str, float]], size_pt: float,
                      dpi: float, above_px: float) -> None:
    """Labels centred on their times, their bottom `above_px` above the box's top."""
    xs, _ = box.px(np.array([t for _, t in labels]), np.zeros(len(labels)))
    for (label, _), x in zip(labels, xs.tolist()):
        text(draw, (x, round(box.y0) - above_px), label, size_pt, dpi, anchor="md")
