"""A face a person can look at: front and side view of lips and jaw driven by the channels.

Geometry (mm, y up, x to the face's left in the front view, z forwards in the side view; origin
on the lip midline of the neutral face):
- The lips of the neutral face touch on the midline; each lip's inner edge moves with its channel's
  displacement from neutral (upper: ULO - ULO_0, lower: -(LLO - LLO_0)); where the two edges would
  cross the lips press, and meet halfway. Lip thickness is fixed (4 and 5 mm half-heights).
- The corners sit at x = ±LR/2 on the midline; inner contours are half-ellipses, outer ones fuller.
- The chin hangs below the lips by the neutral face's mouth-to-chin distance and drops with JO.
- Side view: upper and lower lip bulges move forward with ULP, LLP; the chin drops and swings
  back as the jaw opens.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties, findfont
from matplotlib.patches import Polygon, Rectangle
from matplotlib.transforms import offset_copy
from numpy.typing import NDArray
from PIL import Image, ImageDraw, ImageFont
from rich.progress import Progress

from coartic.io.labels import Segments
from coartic.outputs import atomic_path
from coartic.runtime.animate import Animation, neutral_posture, target_times
from coartic.runtime.errors import AnimationError
from coartic.speakers import SpeakerMapping
from coartic.table import CHANNELS, PAUSE, ParameterTable

if TYPE_CHECKING:
    from coartic.runtime.exporters import ExportSettings, FaceAnimation

# Half the vermilion height (mm) of an adult's upper and lower lip: the channels give where the lip
# markers go, not how thick the lips are.
UPPER_HALF_THICKNESS = 4.0
LOWER_HALF_THICKNESS = 5.0
CHIN_BELOW_LIPS = 35.0  # mm, neutral lip midline to chin
NOSE_ABOVE_LIPS = 30.0  # mm, the default MNS
_N = 41  # points per contour
GIF_MAX_FRAMES = 1500  # one minute at 25 fps
STRIP_CELL = (1.3, 1.6)  # inches per phoneme in the strip
STRIP_PANEL = (1.13, 0.95)  # inches at most for a panel's front view
# Segment marks on a time axis: boundaries as one line collection per axis, labels as text. Past
# these counts they are not drawn (and the figure says so): 5000 segments drawn one artist each took
# 42 s per figure, a million hung in Agg beyond the reach of Ctrl-C. docs/LIMITS.md.
MAX_SEGMENT_BOUNDARIES = 2000
MAX_SEGMENT_LABELS = 300
LIP = "#b5404a"
MOUTH = "#2a0e12"
SKIN = "#f0c9a8"
EDGE = "#6b3a2a"


@dataclass(frozen=True)
class MouthShape:
    """Contours of one posture, each an (n, 2) array of (x, y) or (z, y) in mm."""

    upper_outer: NDArray[np.float64]
    upper_inner: NDArray[np.float64]
    lower_inner: NDArray[np.float64]
    lower_outer: NDArray[np.float64]
    chin: NDArray[np.float64]
    profile: NDArray[np.float64]
    aperture: float  # inner-lip gap on the midline (0 when the lips touch or press)


def _arc(width: float, y_corner: float, y_mid: float, power: float) -> NDArray[np.float64]:
    x = np.linspace(-width / 2.0, width / 2.0, _N)
    u = np.clip(1.0 - (2.0 * x / max(width, 1e-9)) ** 2, 0.0, 1.0)
    return np.column_stack([x, y_corner + (y_mid - y_corner) * u**power])


def mouth_shape(posture: Mapping[str, float], neutral: Mapping[str, float]) -> MouthShape:
    """Front contours and side profile for channel values `posture` (ULO..JO) around `neutral`."""
    hu, hl = UPPER_HALF_THICKNESS, LOWER_HALF_THICKNESS
    ui = posture["ULO"] - neutral["ULO"]
    li = -(posture["LLO"] - neutral["LLO"])
    if ui < li:  # lips pressed: the contact line lies between the two
        ui = li = 0.5 * (ui + li)
    width = max(posture["LR"], 1.0)
    upper_outer = _arc(width, 0.0, ui + 2.0 * hu, 0.7)
    # cupid's bow: a small dip at the midline of the upper outer contour
    upper_outer[:, 1] -= 0.12 * hu * np.exp(-((upper_outer[:, 0] / (0.08 * width)) ** 2))
    drop = posture["JO"] - neutral["JO"]
    chin_y = -CHIN_BELOW_LIPS - drop
    chin = _arc(0.9 * neutral["LR"] + 10.0, chin_y + 18.0, chin_y, 0.5)
    # side view: z forwards; lips bulge at the markers, chin swings back as the jaw opens
    zu = posture["ULP"] - neutral["ULP"]
    zl = posture["LLP"] - neutral["LLP"]
    z_chin = -6.0 - 0.25 * max(drop, 0.0)
    profile = np.array([
        [4.0, NOSE_ABOVE_LIPS + 30.0],  # nose bridge
        [14.0, NOSE_ABOVE_LIPS + 6.0],  # nose tip
        [2.0, NOSE_ABOVE_LIPS - 2.0],  # subnasale
        [zu - 1.0, ui + 2.0 * hu],  # upper vermilion border
        [zu + 1.5, ui + hu],  # upper lip marker
        [zu - 2.0, ui],  # upper inner edge
        [zl - 3.0, li],  # lower inner edge
        [zl + 1.0, li - hl],  # lower lip marker
        [zl - 2.5, li - 2.0 * hl],  # lower vermilion border
        [z_chin - 6.0, 0.55 * (li - 2.0 * hl) + 0.45 * chin_y],  # labiomental fold
        [z_chin, chin_y + 4.0],  # chin point
        [z_chin - 10.0, chin_y - 6.0],  # under the chin
        [z_chin - 40.0, chin_y - 10.0],  # throat
    ])
    return MouthShape(
        upper_outer=upper_outer,
        upper_inner=_arc(width, 0.0, ui, 0.5),
        lower_inner=_arc(width, 0.0, li, 0.5),
        lower_outer=_arc(width, 0.0, li - 2.0 * hl, 0.6),
        chin=chin,
        profile=profile,
        aperture=float(ui - li),
    )


def front_outlines(s: MouthShape) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The front view's closed polygons: upper lip, lower lip and the mouth opening between them."""
    return (np.vstack([s.upper_outer, s.upper_inner[::-1]]), np.vstack([s.lower_inner, s.lower_outer[::-1]]),
            np.vstack([s.upper_inner, s.lower_inner[::-1]]))


def _front_half_width(neutral: Mapping[str, float]) -> float:
    return 0.9 * max(neutral["LR"], 20.0) + 10.0


class FaceArtist:
    """Front and side view on two axes, updated in place frame after frame."""

    def __init__(self, front: Axes, side: Axes, neutral: Mapping[str, float]) -> None:
        self.neutral = dict(neutral)
        half = _front_half_width(neutral)
        front.set_xlim(-half, half)
        front.set_ylim(-CHIN_BELOW_LIPS - 35, NOSE_ABOVE_LIPS + 10)
        side.set_xlim(-60, 30)
        side.set_ylim(-CHIN_BELOW_LIPS - 35, NOSE_ABOVE_LIPS + 10)
        for ax, title in ((front, "front"), (side, "side")):
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_facecolor(SKIN)
            ax.set_title(title, fontsize=8)
        nose = np.array([[-12, NOSE_ABOVE_LIPS], [0, NOSE_ABOVE_LIPS + 10], [12, NOSE_ABOVE_LIPS],
                         [0, NOSE_ABOVE_LIPS - 3]], dtype=float)
        front.add_patch(Polygon(nose, closed=True, fc="none", ec=EDGE, lw=1))
        empty = np.zeros((3, 2))
        self.upper = Polygon(empty, closed=True, fc=LIP, ec=EDGE, lw=1)
        self.lower = Polygon(empty, closed=True, fc=LIP, ec=EDGE, lw=1)
        self.mouth = Polygon(empty, closed=True, fc=MOUTH, ec="none")
        for patch in (self.upper, self.lower, self.mouth):
            front.add_patch(patch)
        (self.chin,) = front.plot([], [], color=EDGE, lw=1.5)
        (self.profile,) = side.plot([], [], color=EDGE, lw=1.5)
        (self.markers,) = side.plot([], [], "o", color=LIP, ms=3)

    def update(self, posture: Mapping[str, float]) -> MouthShape:
        s = mouth_shape(posture, self.neutral)
        for patch, xy in zip((self.upper, self.lower, self.mouth), front_outlines(s)):
            patch.set_xy(xy)
        self.chin.set_data(s.chin[:, 0], s.chin[:, 1])
        smooth = _smooth_profile(s.profile)
        self.profile.set_data(smooth[:, 0], smooth[:, 1])
        self.markers.set_data(s.profile[[4, 7], 0], s.profile[[4, 7], 1])
        return s


def _smooth_profile(points: NDArray[np.float64]) -> NDArray[np.float64]:
    # Chaikin corner cutting: a rounded profile without a spline library's overshoot.
    p = points
    for _ in range(3):
        q = 0.75 * p[:-1] + 0.25 * p[1:]
        r = 0.25 * p[:-1] + 0.75 * p[1:]
        p = np.vstack([p[:1], np.column_stack([q, r]).reshape(-1, 2), p[-1:]])
    return p


def _posture(animation: Animation, k: int) -> dict[str, float]:
    return {c: float(animation.channels[c][k]) for c in CHANNELS}


def _label_at(animation: Animation, t: float) -> str:
    seg = animation.segments
    i = int(np.searchsorted(seg.ends, t, side="right"))
    return seg.labels[min(i, len(seg) - 1)]


def _require_channels(animation: Animation) -> None:
    missing = [c for c in CHANNELS if c not in animation.channels]
    if missing:
        raise AnimationError(f"the preview needs all six channels; missing {', '.join(missing)}")


def _agg_figure(width: float, height: float, dpi: float) -> Figure:
    """A figure drawn by Agg, without pyplot (whose import and figure bookkeeping the pictures need not)."""
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


@lru_cache(maxsize=4)
def _caption_font(size_px: float) -> ImageFont.FreeTypeFont:
    # matplotlib's own default font (DejaVu Sans, shipped with it), so the caption matches the rest
    return ImageFont.truetype(findfont(FontProperties()), size_px)


def _frames(animation: Animation, neutral: Mapping[str, float], title: str) -> Iterator[Image.Image]:
    """RGB frames of the preview: front and side view over a trace of lip aperture with a cursor."""
    _require_channels(animation)
    fig = _agg_figure(6.4, 4.0, 80)
    canvas = fig.canvas
    gs = fig.add_gridspec(2, 2, height_ratios=[3, 1], hspace=0.25, wspace=0.05)
    face = FaceArtist(fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1]), neutral)
    trace = fig.add_subplot(gs[1, :])
    la = animation.channels["ULO"] + animation.channels["LLO"]
    trace.plot(animation.times, la, color=LIP, lw=1)
    trace.set_ylabel("ULO+LLO (mm)", fontsize=7)
    trace.tick_params(labelsize=6)
    trace.set_xlim(0, max(animation.duration, 1e-3))
    mark_segments([trace], animation.segments, color="0.8", fontsize=6, label_y=1.0)
    cursor = trace.axvline(0.0, color="k", lw=1)
    # Blitting: everything that does not move (axes, trace, labels, nose) is drawn once and kept as a
    # background; each frame restores it and draws only the moving artists. The caption, new text
    # every frame, is set by Pillow in matplotlib's font where it puts a suptitle (top centre, 2 %
    # below the edge): matplotlib lays out and renders text anew on each draw, which took half of
    # the frame's time (bench/runtime_speed.py).
    moving = [face.upper, face.lower, face.mouth, face.chin, face.profile, face.markers, cursor]
    for a in moving:
        a.set_animated(True)
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)  # type: ignore[attr-defined]
    size = canvas.get_width_height()
    font = _caption_font(9 * fig.dpi / 72)
    at = (0.5 * size[0], 0.02 * size[1])
    for k in range(animation.n_frames):
        t = float(animation.times[k])
        face.update(_posture(animation, k))
        cursor.set_xdata([t, t])
        canvas.restore_region(background)  # type: ignore[attr-defined]
        for a in moving:
            fig.draw_artist(a)
        rgba = canvas.buffer_rgba()  # type: ignore[attr-defined]
        frame = Image.frombuffer("RGBA", size, rgba, "raw", "RGBA", 0, 1).convert("RGB")
        ImageDraw.Draw(frame).text(at, f"{title}   t = {t:6.3f} s   /{_label_at(animation, t)}/", fill="black",
                                   font=font, anchor="ma")
        yield frame


def gif_palette() -> Image.Image:
    """One palette for every GIF frame: the preview's colours and their anti-aliasing blends.

    The preview draws with a handful of fixed colours, so mapping each frame to them (no dither)
    takes well under a millisecond, against ~15 ms for a median-cut palette per frame.
    """
    base = [np.array(to_rgb(c)) for c in (SKIN, LIP, MOUTH, EDGE, "white", "black", "0.8", "0.5")]
    colors = list(base)
    for i in range(len(base)):
        for j in range(i + 1, len(base)):
            colors += [(1 - f) * base[i] + f * base[j] for f in (0.25, 0.5, 0.75)]
    rgb = np.clip(np.rint(np.array(colors) * 255), 0, 255).astype(np.uint8)
    pal = Image.new("P", (1, 1))
    pal.putpalette(rgb.ravel().tolist() + [0] * (768 - rgb.size))
    return pal


def render_preview(
    animation: Animation,
    neutral: Mapping[str, float],
    path: str | Path,
    *,
    title: str = "coartic",
    progress: Progress | None = None,
    audio: Path | None = None,
) -> Path:
    """Animated preview as GIF (`.gif`) or MP4 (`.mp4`, through ffmpeg); written atomically.

    `audio` (a WAV) becomes the MP4's sound track, so that lip sync can be judged by eye and ear.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise AnimationError(f"{path}: preview format must be .gif or .mp4")
    if suffix == ".gif" and animation.n_frames > GIF_MAX_FRAMES:
        raise AnimationError(
            f"{path}: a GIF of {animation.n_frames} frames is held in memory whole (> {GIF_MAX_FRAMES} frames, "
            "about 160 kB each); write the preview as .mp4 (--preview mp4), which is streamed"
        )
    task = progress.add_task(f"preview {path.name}", total=animation.n_frames) if progress else None
    frames = _frames(animation, neutral, title)

    def advance() -> None:
        if progress is not None and task is not None:
            progress.advance(task)

    # interrupted or failed: no half-written preview left behind (the other outputs are complete)
    with atomic_path(path) as tmp:
        if suffix == ".gif":
            palette = gif_palette()
            images = []
            for frame in frames:
                images.append(frame.quantize(palette=palette, dither=Image.Dither.NONE))
                advance()
            images[0].save(tmp, save_all=True, append_images=images[1:], loop=0,
                           duration=round(1000.0 / animation.fps), optimize=False)
        else:
            _write_mp4(tmp, frames, animation.fps, advance, audio)
    return path


def _write_mp4(
    path: Path, frames: Iterator[Image.Image], fps: float, advance: Callable[[], None], audio: Path | None
) -> None:
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise AnimationError("ffmpeg is not on PATH: write the preview as .gif, or install ffmpeg")
    first = next(frames)
    w, h = first.size
    cmd = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
           "-r", repr(float(fps)), "-i", "-"]
    # "file:" makes every path a path: ffmpeg reads "-odd/x.mp4" as an option and "take:2/x.mp4"
    # as a protocol otherwise
    if audio is not None:
        cmd += ["-i", f"file:{audio}", "-c:a", "aac", "-b:a", "96k"]
    # veryfast: the preview is for looking at, and x264's default preset makes the encoder the bottleneck
    cmd += ["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-preset", "veryfast", "-f", "mp4",
            f"file:{path}"]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdin is not None
    try:
        for frame in _chain(first, frames):
            proc.stdin.write(frame.tobytes())
            advance()
    except BrokenPipeError:
        pass  # ffmpeg stopped reading: its exit code and message say why, below
    finally:
        try:
            proc.stdin.close()
        except BrokenPipeError:
            pass
        err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        code = proc.wait()
    if code != 0:
        raise AnimationError(f"ffmpeg failed writing {path} (exit {code}): {err.strip()[-300:] or 'no message'}")


def face_frames(animation: Animation, neutral: Mapping[str, float], size_px: int = 320) -> Iterator[Image.Image]:
    """RGB frames of the face alone, front and side view, for perceptual tests (coartic.perceive):
    no trace, no caption, no axis titles, nothing that names the phoneme on screen."""
    _require_channels(animation)
    fig = _agg_figure(2 * size_px / 80, size_px / 80, 80)
    front, side = fig.add_axes((0.0, 0.0, 0.5, 1.0)), fig.add_axes((0.5, 0.0, 0.5, 1.0))
    face = FaceArtist(front, side, neutral)
    for ax in (front, side):
        ax.set_title("")
    canvas = fig.canvas
    moving = [face.upper, face.lower, face.mouth, face.chin, face.profile, face.markers]
    for a in moving:
        a.set_animated(True)
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)  # type: ignore[attr-defined]
    size = canvas.get_width_height()
    for k in range(animation.n_frames):
        face.update(_posture(animation, k))
        canvas.restore_region(background)  # type: ignore[attr-defined]
        for a in moving:
            fig.draw_artist(a)
        rgba = canvas.buffer_rgba()  # type: ignore[attr-defined]
        yield Image.frombuffer("RGBA", size, rgba, "raw", "RGBA", 0, 1).convert("RGB")


def render_face_video(animation: Animation, neutral: Mapping[str, float], path: str | Path, audio: Path | None,
                      size_px: int = 320) -> Path:
    """The face alone (`face_frames`) as an MP4 with `audio` as its sound track; written atomically."""
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise AnimationError(f"{path}: a face video is written as .mp4")
    with atomic_path(path) as tmp:
        _write_mp4(tmp, face_frames(animation, neutral, size_px), animation.fps, lambda: None, audio)
    return path


def _chain(first: Image.Image, rest: Iterator[Image.Image]) -> Iterator[Image.Image]:
    yield first
    yield from rest


def render_strip(
    animation: Animation,
    table: ParameterTable,
    path: str | Path,
    *,
    max_panels: int = 40,
    per_row: int = 10,
    speaker: SpeakerMapping | None = None,
) -> Path:
    """PNG strip: the front view at each non-pause segment's target time, labelled with its phoneme
    (as the table's ``speaker`` says it, when given: coartic.speakers)."""
    _require_channels(animation)
    from coartic.runtime.animate import evaluate

    if speaker is not None:
        table = speaker.evaluation_table(table)
    neutral = neutral_posture(table)
    seg = animation.segments
    idx = [i for i, lab in enumerate(seg.labels) if lab != PAUSE][:max_panels]
    if not idx:
        raise AnimationError("the utterance has only pauses: nothing to show in a strip")
    modelled = animation.modelled
    t = target_times(table, seg, "LLO" if "LLO" in modelled else modelled[0])[idx]
    values = evaluate(table, seg, t, modelled)
    if speaker is not None:
        values = {c: speaker.apply(c, v) for c, v in values.items()}
        neutral = {c: float(speaker.apply(c, np.array([v]))[0]) if c in modelled else v for c, v in neutral.items()}
    values.update({c: np.full(t.size, neutral[c]) for c in CHANNELS if c not in values})
    cols = min(len(idx), per_row)
    rows = -(-len(idx) // per_row)
    # One axes for the whole strip, in inches from the top left corner, a panel per phoneme drawn
    # into it: an axes each (with its ticks machinery) and tight_layout made the strip cost as much
    # as the whole GIF. Each panel is the front view's window (a preview frame's, cut below the nose).
    fig = _agg_figure(STRIP_CELL[0] * cols, STRIP_CELL[1] * rows + 0.2, 100)
    width, height = fig.get_size_inches()
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    ax.set_xlim(0.0, width)
    ax.set_ylim(-height, 0.0)
    half, bottom, top = _front_half_width(neutral), -CHIN_BELOW_LIPS - 20.0, 25.0
    scale = min(STRIP_PANEL[0] / (2 * half), STRIP_PANEL[1] / (top - bottom))  # inches per mm
    pw, ph = 2 * half * scale, (top - bottom) * scale
    title_at = offset_copy(ax.transData, fig=fig, y=6, units="points")  # an axes title's pad
    # add_artist, not add_patch: the limits are fixed above, and add_patch walked every patch's
    # Bézier segments to widen them (a fifth of the strip's time)
    for j, i in enumerate(idx):
        row, col = divmod(j, per_row)
        cx = (col + 0.5) * STRIP_CELL[0]
        y_top = -0.1 - row * STRIP_CELL[1] - 0.5 * (STRIP_CELL[1] - ph) - 0.06  # room for the title above
        window = Rectangle((cx - 0.5 * pw, y_top - ph), pw, ph, fc=SKIN, ec="none", zorder=0)
        ax.add_artist(window)
        s = mouth_shape({c: float(values[c][j]) for c in CHANNELS}, neutral)
        origin = np.array([cx, y_top - scale * top])  # mm on the face -> inches on the strip
        upper, lower, mouth = front_outlines(s)
        for xy, style in ((upper, {"fc": LIP, "ec": EDGE, "lw": 1}), (lower, {"fc": LIP, "ec": EDGE, "lw": 1}),
                          (mouth, {"fc": MOUTH, "ec": "none"})):
            ax.add_artist(Polygon(origin + scale * xy, closed=True, clip_path=window, **style))
        chin = origin + scale * s.chin
        ax.plot(chin[:, 0], chin[:, 1], color=EDGE, lw=1.5, clip_path=window)
        ax.add_artist(Rectangle((cx - 0.5 * pw, y_top - ph), pw, ph, fc="none", ec="black", lw=0.8, zorder=3))
        ax.text(cx, y_top, f"/{seg.labels[i]}/ {t[j]:.2f}s", transform=title_at, ha="center", va="baseline",
                fontsize=8)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    return path


def plot_channels(animation: Animation, path: str | Path, title: str = "") -> Path:
    """The six channels over time with the segment labels: the numbers behind the preview."""
    names: Sequence[str] = [c for c in CHANNELS if c in animation.modelled]
    fig = _agg_figure(8, 1.3 * len(names) + 0.6, 100)
    axes = np.atleast_1d(fig.subplots(len(names), 1, sharex=True))
    for ax, c in zip(axes, names):
        ax.plot(animation.times, animation.channels[c], color=LIP, lw=1.2)
        ax.set_ylabel(f"{c} (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
    note = mark_segments(list(axes), animation.segments, color="0.85", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    if title or note:
        fig.suptitle("   ".join(t for t in (title, note) if t), fontsize=9)
    _fit_margins(fig, list(axes))
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    return path


def _fit_margins(fig: Figure, axes: list[Axes]) -> None:
    """Margins for a column of axes sharing x, with labels above the first (mark_segments) and a
    suptitle: fixed in inches where the text has a fixed size, the left one from the widest
    y-axis (its tick labels depend on the data). What tight_layout gives, without its second full
    layout of every text (a third of the figure's cost)."""
    width, height = fig.get_size_inches()
    left, pad = 0.75, 0.09  # inches; the ink then starts where tight_layout put it
    fig.subplots_adjust(left=left / width, right=1 - 0.15 / width, top=1 - 0.56 / height, bottom=0.54 / height,
                        hspace=0.22 / ((height - 1.1 - 0.22 * (len(axes) - 1)) / len(axes)))
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    x0 = min(b.x0 for b in (ax.yaxis.get_tightbbox(renderer) for ax in axes) if b is not None) / fig.dpi
    fig.subplots_adjust(left=(left + pad - x0) / width)


def mark_segments(
    axes: Sequence[Axes], segments: Segments, *, color: str = "0.85", fontsize: float = 7,
    label_y: float = 1.02,
) -> str:
    """Segment boundaries on every axis and the (non-pause) labels above the first, with bounded
    work: one line collection per axis, nothing past MAX_SEGMENT_BOUNDARIES / _LABELS segments.
    Returns what was left out ("" when everything was drawn), for the figure's title."""
    n = len(segments)
    left_out = []
    if n - 1 <= MAX_SEGMENT_BOUNDARIES:
        for ax in axes:
            ax.vlines(segments.starts[1:], 0.0, 1.0, transform=ax.get_xaxis_transform(), colors=color,
                      lw=0.5, zorder=0)
    else:
        left_out.append("boundaries")
    if n <= MAX_SEGMENT_LABELS:
        for lab, s, e in zip(segments.labels, segments.starts, segments.ends):
            if lab != PAUSE:
                axes[0].text(0.5 * (s + e), label_y, lab, transform=axes[0].get_xaxis_transform(),
                             ha="center", va="bottom", fontsize=fontsize)
    else:
        left_out.append("labels")
    return f"({n} segments: {' and '.join(left_out)} not drawn)" if left_out else ""


def export_plot(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter (coartic.runtime.exporters): channels.png."""
    animation = fed.animation
    return {"plot": plot_channels(animation, settings.out / "channels.png", title=settings.name)}


def export_preview(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter: strip.png and preview.gif / .mp4 (settings.preview), the MP4 with the sound."""
    animation = fed.animation
    strip = render_strip(animation, settings.table, settings.out / "strip.png", speaker=settings.mapping)
    preview = render_preview(animation, animation.neutral, settings.out / f"preview.{settings.preview}",
                             title=settings.name, progress=settings.progress, audio=settings.audio)
    return {"strip": strip, "preview": preview}
