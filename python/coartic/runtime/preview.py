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
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw
from rich.progress import Progress

from coartic.io.labels import Segments
from coartic.outputs import atomic_path
from coartic.runtime import raster
from coartic.runtime.animate import Animation, neutral_posture, target_times
from coartic.runtime.errors import AnimationError
from coartic.runtime.raster import Box, Tile, equal_aspect, rgb
from coartic.speakers import SpeakerMapping
from coartic.table import CHANNELS, PAUSE, ParameterTable

if TYPE_CHECKING:
    from matplotlib.axes import Axes

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


# the front view's nose outline (mm), drawn in every front view of the preview
_NOSE = np.array([[-12, NOSE_ABOVE_LIPS], [0, NOSE_ABOVE_LIPS + 10], [12, NOSE_ABOVE_LIPS],
                  [0, NOSE_ABOVE_LIPS - 3]], dtype=float)
# what the face views show (mm): the front window is _front_half_width wide, the side one this
_VIEW_Y = (-CHIN_BELOW_LIPS - 35.0, NOSE_ABOVE_LIPS + 10.0)
_SIDE_X = (-60.0, 30.0)


def _front_box(cell: tuple[float, float, float, float], neutral: Mapping[str, float]) -> Box:
    half = _front_half_width(neutral)
    return equal_aspect(*cell, (-half, half), _VIEW_Y)


def _side_box(cell: tuple[float, float, float, float]) -> Box:
    return equal_aspect(*cell, _SIDE_X, _VIEW_Y)


def draw_front(tile: Tile, s: MouthShape, nose: bool = True) -> None:
    """The front view of posture `s` into `tile`: nose, both lips, the mouth opening, the chin."""
    if nose:
        tile.polygon(_NOSE, None, rgb(EDGE), 1.0)
    upper, lower, mouth = front_outlines(s)
    tile.polygon(upper, rgb(LIP), rgb(EDGE), 1.0)
    tile.polygon(lower, rgb(LIP), rgb(EDGE), 1.0)
    tile.polygon(mouth, rgb(MOUTH))
    tile.line(s.chin[:, 0], s.chin[:, 1], rgb(EDGE), 1.5)


def draw_side(tile: Tile, s: MouthShape) -> None:
    """The side view: the profile, and the lip markers on it."""
    smooth = _smooth_profile(s.profile)
    tile.line(smooth[:, 0], smooth[:, 1], rgb(EDGE), 1.5)
    tile.markers(s.profile[[4, 7], 0], s.profile[[4, 7], 1], rgb(LIP), 3.0)


def _face_views(picture: Image.Image, front: Box, side: Box, s: MouthShape, dpi: float) -> None:
    tile = Tile(front, rgb(SKIN), dpi)
    draw_front(tile, s)
    tile.paste_into(picture)
    tile = Tile(side, rgb(SKIN), dpi)
    draw_side(tile, s)
    tile.paste_into(picture)


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


def _grid(size: tuple[int, int], height_ratios: tuple[float, float] = (3.0, 1.0), hspace: float = 0.25,
          wspace: float = 0.05) -> tuple[tuple[float, float, float, float], ...]:
    """The cells (x0, y0, x1, y1 px) of a 2 × 2 grid in matplotlib's default figure margins
    (left .125, right .9, bottom .11, top .88) with its spacing rules: top left, top right, bottom
    row (both columns)."""
    w, h = size
    left, right, top, bottom = 0.125 * w, 0.9 * w, 0.12 * h, 0.89 * h
    cell_w = (right - left) / (2 + wspace)
    unit = (bottom - top) / (sum(height_ratios) + hspace * sum(height_ratios) / 2)
    row0 = (top, top + height_ratios[0] * unit)
    row1 = (row0[1] + hspace * sum(height_ratios) / 2 * unit, bottom)
    return ((left, row0[0], left + cell_w, row0[1]), (right - cell_w, row0[0], right, row0[1]),
            (left, row1[0], right, row1[1]))


def _frames(animation: Animation, neutral: Mapping[str, float], title: str) -> Iterator[Image.Image]:
    """RGB frames of the preview: front and side view over a trace of lip aperture with a cursor.

    Everything that does not move (axes, trace, labels) is drawn once as a background; each frame
    is a copy of it with the two face views, the cursor and the caption drawn on."""
    _require_channels(animation)
    dpi, size = 80.0, (512, 320)
    front_cell, side_cell, trace_cell = _grid(size)
    front, side = _front_box(front_cell, neutral), _side_box(side_cell)
    la = animation.channels["ULO"] + animation.channels["LLO"]
    trace = Box(*trace_cell, (0.0, max(animation.duration, 1e-3)), raster.with_margins(float(la.min()), float(la.max())))
    background = Image.new("RGB", size, raster.WHITE)
    draw = ImageDraw.Draw(background)
    tile = Tile(trace, raster.WHITE, dpi)
    boundaries, labels, _ = segment_marks(animation.segments)
    if boundaries:
        tile.vlines(animation.segments.starts[1:], rgb("0.8"), 0.5)
    tile.line(animation.times, la, rgb(LIP), 1.0)
    tile.paste_into(background)
    for box in (front, side, trace):
        raster.frame(draw, box, dpi)
    for box, name in ((front, "front"), (side, "side")):  # axes titles, 6 points above
        raster.text(draw, (0.5 * (box.x0 + box.x1), round(box.y0) - 6 * dpi / 72), name, 8, dpi)
    widest = raster.y_axis(draw, trace, dpi, 6)
    raster.x_axis(draw, trace, dpi, 6)
    reach = (raster.TICK_LENGTH + raster.TICK_PAD + raster.LABEL_PAD) * dpi / 72 + widest
    raster.vertical_text(background, (round(trace.x0) - reach - raster.line_height(7, dpi), 0.5 * (trace.y0 + trace.y1)),
                         "ULO+LLO (mm)", 7, dpi)
    if labels:
        raster.segment_labels_at(draw, trace, _segment_label_times(animation.segments), 6, dpi, 0.0)
    font = raster.font(9 * dpi / 72)
    at = (0.5 * size[0], 0.02 * size[1])
    cursor_top, cursor_bottom = round(trace.y0), round(trace.y0) + trace.height - 1
    for k in range(animation.n_frames):
        t = float(animation.times[k])
        frame = background.copy()
        _face_views(frame, front, side, mouth_shape(_posture(animation, k), neutral), dpi)
        fdraw = ImageDraw.Draw(frame)
        x = round(float(trace.px(t, 0.0)[0]))
        fdraw.line([(x, cursor_top), (x, cursor_bottom)], fill=raster.BLACK, width=1)
        fdraw.text(at, f"{title}   t = {t:6.3f} s   /{_label_at(animation, t)}/", fill="black", font=font, anchor="ma")
        yield frame


def _segment_label_times(segments: Segments) -> list[tuple[str, float]]:
    return [(lab, 0.5 * (s + e)) for lab, s, e in zip(segments.labels, segments.starts, segments.ends) if lab != PAUSE]


def gif_palette() -> Image.Image:
    """One palette for every GIF frame: the preview's colours and their anti-aliasing blends.

    The preview draws with a handful of fixed colours, so mapping each frame to them (no dither)
    takes well under a millisecond, against ~15 ms for a median-cut palette per frame.
    """
    base = [np.array(rgb(c)) / 255.0 for c in (SKIN, LIP, MOUTH, EDGE, "1.0", "0.0", "0.8", "0.5")]
    colors = list(base)
    for i in range(len(base)):
        for j in range(i + 1, len(base)):
            colors += [(1 - f) * base[i] + f * base[j] for f in (0.25, 0.5, 0.75)]
    levels = np.clip(np.rint(np.array(colors) * 255), 0, 255).astype(np.uint8)
    pal = Image.new("P", (1, 1))
    pal.putpalette(levels.ravel().tolist() + [0] * (768 - levels.size))
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
    dpi = 80.0
    front = _front_box((0.0, 0.0, float(size_px), float(size_px)), neutral)
    side = _side_box((float(size_px), 0.0, 2.0 * size_px, float(size_px)))
    background = Image.new("RGB", (2 * size_px, size_px), raster.WHITE)
    draw = ImageDraw.Draw(background)
    for box in (front, side):
        raster.frame(draw, box, dpi)
    for k in range(animation.n_frames):
        frame = background.copy()
        _face_views(frame, front, side, mouth_shape(_posture(animation, k), neutral), dpi)
        yield frame


def render_face_video(animation: Animation, neutral: Mapping[str, float], path: str | Path, audio: Path | None,
                      size_px: int = 320) -> Path:
    """The face alone (`face_frames`) as an MP4 with `audio` as its sound track; written atomically."""
    return write_video(path, face_frames(animation, neutral, size_px), animation.fps, audio)


def write_video(path: str | Path, frames: Iterable[Image.Image], fps: float, audio: Path | None) -> Path:
    """RGB frames (all of one size) as an MP4 at `fps` with `audio` as its sound track; written
    atomically. The 2-D face's (`render_face_video`) and the 3-D face's (coartic.perceive.stimuli)."""
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise AnimationError(f"{path}: a face video is written as .mp4")
    with atomic_path(path) as tmp:
        _write_mp4(tmp, iter(frames), fps, lambda: None, audio)
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
    # In inches from the top left corner, y up (as the strip was laid out on a matplotlib axes), a
    # panel per phoneme: the front view's window (a preview frame's, cut below the nose).
    dpi = 100.0
    width, height = STRIP_CELL[0] * cols, STRIP_CELL[1] * rows + 0.2
    picture = Image.new("RGB", (round(width * dpi), round(height * dpi)), raster.WHITE)
    draw = ImageDraw.Draw(picture)
    half, bottom, top = _front_half_width(neutral), -CHIN_BELOW_LIPS - 20.0, 25.0
    scale = min(STRIP_PANEL[0] / (2 * half), STRIP_PANEL[1] / (top - bottom))  # inches per mm
    pw, ph = 2 * half * scale, (top - bottom) * scale
    for j, i in enumerate(idx):
        row, col = divmod(j, per_row)
        cx = (col + 0.5) * STRIP_CELL[0]
        y_top = -0.1 - row * STRIP_CELL[1] - 0.5 * (STRIP_CELL[1] - ph) - 0.06  # room for the title above
        window = Box((cx - 0.5 * pw) * dpi, -y_top * dpi, (cx + 0.5 * pw) * dpi, (ph - y_top) * dpi, (-half, half),
                     (bottom, top))
        tile = Tile(window, rgb(SKIN), dpi)
        draw_front(tile, mouth_shape({c: float(values[c][j]) for c in CHANNELS}, neutral), nose=False)
        tile.paste_into(picture)
        raster.frame(draw, window, dpi)
        raster.text(draw, (cx * dpi, -y_top * dpi - 6 * dpi / 72), f"/{seg.labels[i]}/ {t[j]:.2f}s", 8, dpi)
    path = Path(path)
    with atomic_path(path) as tmp:
        raster.save_png(picture, tmp, dpi)
    return path


def plot_channels(animation: Animation, path: str | Path, title: str = "") -> Path:
    """The six channels over time with the segment labels: the numbers behind the preview.

    A column of axes sharing x, 8 × (1.3 n + 0.6) inches at 100 dpi: the margins in inches where the
    text has a fixed size (title, labels above the first axes, the time axis), the left one from
    the widest y-axis (its tick labels depend on the data)."""
    names: Sequence[str] = [c for c in CHANNELS if c in animation.modelled]
    dpi, n = 100.0, len(names)
    width, height = 8.0, 1.3 * n + 0.6
    top, bottom, right, gap = 0.56, 0.54, 0.15, 0.22  # inches
    axis_h = (height - top - bottom - gap * (n - 1)) / n
    t0, t1 = float(animation.times[0]), float(animation.times[-1])
    xlim = raster.with_margins(t0, t1)
    ylims = [raster.with_margins(float(np.min(animation.channels[c])), float(np.max(animation.channels[c])))
             for c in names]
    # the y-axis labels' left edge 0.09 inch from the picture's edge, as tight_layout put them
    probe = [Box(0.0, 0.0, 100.0, axis_h * dpi, xlim, ylim) for ylim in ylims]
    reach = max(raster.y_axis_width(b, dpi, 7) for b in probe) + raster.LABEL_PAD * dpi / 72
    x0 = 0.09 * dpi + raster.line_height(8, dpi) + reach
    boxes = [Box(x0, (top + k * (axis_h + gap)) * dpi, (width - right) * dpi, (top + k * (axis_h + gap) + axis_h) * dpi,
                 xlim, ylim) for k, ylim in enumerate(ylims)]
    picture = Image.new("RGB", (round(width * dpi), round(height * dpi)), raster.WHITE)
    draw = ImageDraw.Draw(picture)
    boundaries, labels, note = segment_marks(animation.segments)
    for k, (box, c) in enumerate(zip(boxes, names)):
        tile = Tile(box, raster.WHITE, dpi)
        if boundaries:
            tile.vlines(animation.segments.starts[1:], rgb("0.85"), 0.5)
        tile.line(animation.times, animation.channels[c], rgb(LIP), 1.2)
        tile.paste_into(picture)
        raster.frame(draw, box, dpi)
        raster.y_axis(draw, box, dpi, 7)
        raster.x_axis(draw, box, dpi, 7, labelled=k == n - 1)
        raster.vertical_text(picture, (0.09 * dpi, 0.5 * (box.y0 + box.y1)), f"{c} (mm)", 8, dpi)
    if labels:
        raster.segment_labels_at(draw, boxes[0], _segment_label_times(animation.segments), 7, dpi,
                                 0.02 * boxes[0].height)
    last = boxes[-1]
    below = (raster.TICK_LENGTH + raster.TICK_PAD + raster.LABEL_PAD) * dpi / 72 + raster.line_height(7, dpi)
    raster.text(draw, (0.5 * (last.x0 + last.x1), round(last.y0) + last.height + below), "time (s)", 10, dpi,
                anchor="mt")
    if title or note:
        raster.text(draw, (0.5 * width * dpi, 0.02 * height * dpi), "   ".join(t for t in (title, note) if t), 9, dpi,
                    anchor="mt")
    path = Path(path)
    with atomic_path(path) as tmp:
        raster.save_png(picture, tmp, dpi)
    return path


def segment_marks(segments: Segments) -> tuple[bool, bool, str]:
    """Whether to draw the segment boundaries and the labels, and what was left out ("" when
    nothing), for a title: past MAX_SEGMENT_BOUNDARIES / _LABELS segments they are not drawn."""
    n = len(segments)
    boundaries, labels = n - 1 <= MAX_SEGMENT_BOUNDARIES, n <= MAX_SEGMENT_LABELS
    left_out = [what for what, drawn in (("boundaries", boundaries), ("labels", labels)) if not drawn]
    return boundaries, labels, f"({n} segments: {' and '.join(left_out)} not drawn)" if left_out else ""


def mark_segments(
    axes: Sequence[Axes], segments: Segments, *, color: str = "0.85", fontsize: float = 7,
    label_y: float = 1.02,
) -> str:
    """On matplotlib axes (`coartic inspect --plot`): segment boundaries on every axis and the
    (non-pause) labels above the first, with bounded work (`segment_marks`): one line collection
    per axis. Returns what was left out ("" when everything was drawn), for the figure's title."""
    boundaries, labels, note = segment_marks(segments)
    if boundaries:
        for ax in axes:
            ax.vlines(segments.starts[1:], 0.0, 1.0, transform=ax.get_xaxis_transform(), colors=color,
                      lw=0.5, zorder=0)
    if labels:
        for lab, t in _segment_label_times(segments):
            axes[0].text(t, label_y, lab, transform=axes[0].get_xaxis_transform(), ha="center", va="bottom",
                         fontsize=fontsize)
    return note


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
