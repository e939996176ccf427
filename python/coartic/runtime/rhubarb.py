"""Rhubarb Lip Sync's mouth cues from one `Animation`, written as Rhubarb writes them (TSV, JSON, XML, DAT).

Rhubarb (github.com/DanielSWolf/rhubarb-lip-sync) animates at a fixed 100 frames per second and
writes times in centiseconds; so do these cues, whatever `--fps` the animation has:

1. **A shape every centisecond** of the sound (its duration truncated to 0.01 s, as Rhubarb's
   metadata gives it), from the animation itself: the model evaluated at every centisecond
   (`Animation.resampled`), so the cues are the same at every `--fps`, not tied to the frame grid.
   `shape_at` says which shape and why.
2. **Extended shapes** not chosen (`--extended-shapes`, any of G H X, all by default) become the
   basic shape Rhubarb puts in their place: G → A, H → C, X → A.
3. **Minimum durations**: no cue is shorter than `MIN_CUE_CS` (7 cs, Rhubarb's minimum shape
   duration), except the in-betweens below: a short cue first takes the time it lacks from
   neighbours that can spare it (a fast /p/'s closure stays a closure), otherwise it joins the
   longer neighbour.
4. **Tweens** (Rhubarb's in-betweens, with its timing): D → A, B, G or X through C, C or D ↔ F
   through E, H ↔ F through E; early (the last third of the first cue), centred (a quarter of the
   shorter cue across the boundary) or late (the first third of the second), at most 8 cs and
   left out when shorter than 4 cs (`TWEENS`, `MIN_TWEEN_CS`, `MAX_TWEEN_CS`).

The formats follow Rhubarb's README and exporters: TSV `start<TAB>shape` with a last line at the
end of the sound and a closed mouth (X, or A without X); JSON and XML `metadata` (soundFile,
duration) and `mouthCues` with start/end/value, times with two decimals; DAT (Moho, OpenToonz)
`MohoSwitch1` then `frame shape` lines, frame = 1 + floor(fps × start), a cue that falls on the
frame of the one before left out, and a last line with the closed mouth at the end (one frame
later if it shares its frame), at 24 to 100 fps, with Rhubarb's or Preston Blair's shape names.
Where Rhubarb writes the recording's absolute path, soundFile is the WAV's name beside the file
(an absolute path would name the staging directory the run was written in).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import escape, quoteattr

import numpy as np
from numpy.typing import NDArray

from coartic.outputs import atomic_write_text
from coartic.runtime.animate import Animation
from coartic.runtime.errors import AnimationError
from coartic.runtime.rigs import (
    ARKIT_NAMES,
    VISEMES,
    _deltas,
    _viseme_of,
    arkit_weights,
    lower_lip_roll,
    segment_shares,
    share_blocks,
)

if TYPE_CHECKING:
    from coartic.runtime.exporters import ExportSettings, FaceAnimation

BASIC_SHAPES = "ABCDEF"
EXTENDED_SHAPES = "GHX"
RHUBARB_SHAPES: tuple[str, ...] = tuple(BASIC_SHAPES + EXTENDED_SHAPES)
# what Rhubarb shows for an extended shape that is not drawn
BASIC_OF = {"G": "A", "H": "C", "X": "A"}
# Preston Blair's names of the shapes (Rhubarb's --datUsePrestonBlair)
PRESTON_BLAIR = {"A": "MBP", "B": "etc", "C": "E", "D": "AI", "E": "O", "F": "U", "G": "FV", "H": "L", "X": "rest"}
MIN_CUE_CS = 7  # Rhubarb's minimum shape duration (its tweens excepted)
MIN_TWEEN_CS = 4
MAX_TWEEN_CS = 8
# (from, to) -> (in-between, timing): Rhubarb's tweening rules; the mouth pops open without
# in-betweens and closes through them
TWEENS: dict[tuple[str, str], tuple[str, str]] = {
    ("D", "A"): ("C", "early"), ("D", "B"): ("C", "centred"), ("D", "G"): ("C", "early"),
    ("D", "X"): ("C", "late"), ("C", "F"): ("E", "centred"), ("F", "C"): ("E", "centred"),
    ("D", "F"): ("E", "centred"), ("H", "F"): ("E", "late"), ("F", "H"): ("E", "early"),
}
DAT_FPS_RANGE = (24.0, 100.0)  # Rhubarb's DAT frame rates
# Opening (ULO + LLO from neutral) as a fraction of the table's widest phoneme target, below which
# the mouth is shape B (teeth together, lips slightly apart) and C (open); above C it is D (wide).
RHUBARB_B_BELOW = 0.5
RHUBARB_C_BELOW = 0.75
# a pause in control with the lips within this fraction of closed is the idle mouth X
RHUBARB_REST_BELOW = 0.25
# rounding (mouthPucker + mouthFunnel) from which the mouth is F (puckered) or E (slightly rounded)
RHUBARB_ROUND_FROM = 0.25
# the lower lip rolled in under the upper teeth (coartic.runtime.rigs.lower_lip_roll) at least this
# far is shape G, whichever segment dominates: the teeth on the lip are what G draws
RHUBARB_G_ROLL = 0.5
# the lateral phonemes that Rhubarb's H (tongue raised behind the upper teeth) is drawn for
RHUBARB_H_PHONEMES = frozenset({"l", "L"})


@dataclass(frozen=True)
class MouthCue:
    """One cue, its times in centiseconds (Rhubarb's unit)."""

    start_cs: int
    end_cs: int
    value: str

    @property
    def start(self) -> float:
        return self.start_cs / 100.0

    @property
    def end(self) -> float:
        return self.end_cs / 100.0


def parse_extended_shapes(spec: str) -> str:
    """`--extended-shapes`: any of G H X (Rhubarb's extendedShapes; "" for the six basic shapes)."""
    letters = spec.replace(",", "").replace(" ", "").upper()
    bad = sorted(set(letters) - set(EXTENDED_SHAPES))
    if bad:
        raise AnimationError(f"--extended-shapes {spec!r}: {''.join(bad)} is no extended shape; choose any of "
                             "G H X (e.g. GX), or \"\" for the six basic shapes A-F")
    return "".join(s for s in EXTENDED_SHAPES if s in letters)


def centiseconds(seconds: float) -> int:
    """A time truncated to whole centiseconds, as Rhubarb truncates the sound's duration."""
    return int(np.floor(seconds * 100.0 + 1e-9))


def widest_opening(animation: Animation) -> float:
    """The widest lip opening (ULO + LLO from neutral, mm) among the table's phoneme targets."""
    table = animation.table
    if table is None:
        raise AnimationError("this animation does not carry the table that made it: no mouth cues")
    have = [c for c in ("ULO", "LLO") if c in table.channels]
    widest = max((sum(per[c]["target"] - animation.neutral[c] for c in have)
                  for per in table.values.values() if all(c in per for c in have)), default=0.0)
    if not have or not widest > 0.0:
        raise AnimationError(f"{table.source}: no phoneme opens the lips (ULO + LLO above the pause's): "
                             "Rhubarb's open shapes B-D cannot be scaled")
    return float(widest)


def _control(animation: Animation, times: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """At `times`: the viseme in control (index in VISEMES) and the share of /l L/ in it, from the
    frames' dominance shares interpolated between frames."""
    labels = animation.segments.labels
    cols = np.zeros((len(labels), len(VISEMES) + 1))
    for i, ph in enumerate(labels):
        cols[i, VISEMES.index(_viseme_of(ph))] = 1.0
        cols[i, -1] = float(ph in RHUBARB_H_PHONEMES)
    per_frame = np.empty((animation.n_frames, cols.shape[1]))
    for a, b in share_blocks(animation):
        per_frame[a:b] = segment_shares(animation, a, b) @ cols
    at = np.column_stack([np.interp(times, animation.times, per_frame[:, j]) for j in range(cols.shape[1])])
    top = np.argmax(at[:, :-1], axis=1)
    lateral = at[:, -1] / np.maximum(at[np.arange(times.size), top], np.finfo(float).tiny)
    return top.astype(np.int64), lateral


def shape_at(animation: Animation, times: NDArray[np.float64]) -> list[str]:
    """Rhubarb's shape at each of `times` (s), all nine shapes:

    X the idle mouth, when the pause is in control and the lips are within RHUBARB_REST_BELOW of the
    widest opening from closed; G when the lower lip is rolled under the upper teeth (at least
    RHUBARB_G_ROLL, /f v/); A (closed) when PP is in control or the lips are at or past contact;
    H when /l L/ hold most of the viseme in control; F (puckered) or E (rounded) from rounding
    RHUBARB_ROUND_FROM, F when less than half open; otherwise B, C or D by the opening as a fraction
    of the table's widest phoneme opening (below 0.5, below 0.75, above)."""
    times = np.asarray(times, dtype=np.float64)
    d = {c: np.interp(times, animation.times, v) for c, v in _deltas(animation).items()}
    ark = arkit_weights(animation)
    rounding = np.interp(times, animation.times,
                         ark[:, ARKIT_NAMES.index("mouthPucker")] + ark[:, ARKIT_NAMES.index("mouthFunnel")])
    opening = (d["ULO"] + d["LLO"]) / widest_opening(animation)
    roll = lower_lip_roll(d["LLP"], d["LLO"])
    top, lateral = _control(animation, times)
    shapes = []
    for k in range(times.size):
        vis = VISEMES[int(top[k])]
        if vis == "sil" and opening[k] < RHUBARB_REST_BELOW:
            shapes.append("X")
        elif roll[k] >= RHUBARB_G_ROLL:
            shapes.append("G")
        elif vis == "PP" or opening[k] <= 0.0:
            shapes.append("A")
        elif lateral[k] > 0.5:
            shapes.append("H")
        elif rounding[k] >= RHUBARB_ROUND_FROM:
            shapes.append("F" if opening[k] < RHUBARB_B_BELOW else "E")
        elif opening[k] < RHUBARB_B_BELOW:
            shapes.append("B")
        elif opening[k] < RHUBARB_C_BELOW:
            shapes.append("C")
        else:
            shapes.append("D")
    return shapes


def _runs(shapes: list[str]) -> list[MouthCue]:
    cues: list[MouthCue] = []
    for k, s in enumerate(shapes):
        if cues and cues[-1].value == s:
            cues[-1] = MouthCue(cues[-1].start_cs, k + 1, s)
        else:
            cues.append(MouthCue(k, k + 1, s))
    return cues


def hold_minimum(cues: list[MouthCue], minimum: int = MIN_CUE_CS) -> list[MouthCue]:
    """The cues with none shorter than `minimum` cs (when the whole is that long): the shortest short
    cue first takes what it lacks from neighbours that can spare it (each keeping `minimum`, the one
    before first), else joins its longer neighbour (neighbours of one shape then merge)."""
    starts = [c.start_cs for c in cues]
    ends = [c.end_cs for c in cues]
    values = [c.value for c in cues]

    def length(j: int) -> int:
        return ends[j] - starts[j] if 0 <= j < len(values) else -1

    while len(values) > 1:
        short = [j for j in range(len(values)) if length(j) < minimum]
        if not short:
            break
        i = min(short, key=lambda j: (length(j), j))
        lack = minimum - length(i)
        spare_left = max(length(i - 1) - minimum, 0) if i > 0 else 0
        spare_right = max(length(i + 1) - minimum, 0) if i + 1 < len(values) else 0
        if spare_left + spare_right >= lack:
            take_left = min(spare_left, lack)
            take_right = lack - take_left
            if take_left:
                ends[i - 1] -= take_left
                starts[i] = ends[i - 1]
            if take_right:
                starts[i + 1] += take_right
                ends[i] = starts[i + 1]
            continue
        if length(i - 1) >= length(i + 1):
            ends[i - 1] = ends[i]
        else:
            starts[i + 1] = starts[i]
        del starts[i], ends[i], values[i]
        for j in range(len(values) - 1, 0, -1):
            if values[j] == values[j - 1]:
                ends[j - 1] = ends[j]
                del starts[j], ends[j], values[j]
    return [MouthCue(a, b, v) for a, b, v in zip(starts, ends, values)]


def insert_tweens(cues: list[MouthCue]) -> list[MouthCue]:
    """Rhubarb's in-betweens (TWEENS) between adjacent cues, with its timing and bounds."""
    out = list(cues)
    k = 0
    while k + 1 < len(out):
        first, second = out[k], out[k + 1]
        rule = TWEENS.get((first.value, second.value))
        if rule is None:
            k += 1
            continue
        tween, timing = rule
        d1, d2 = first.end_cs - first.start_cs, second.end_cs - second.start_cs
        if timing == "early":
            length = min(d1 // 3, MAX_TWEEN_CS)
            start = first.end_cs - length
        elif timing == "centred":
            length = min(d1 // 4, d2 // 4, MAX_TWEEN_CS)
            start = first.end_cs - length // 2
        else:
            length = min(d2 // 3, MAX_TWEEN_CS)
            start = second.start_cs
        if length < MIN_TWEEN_CS:
            k += 1
            continue
        end = start + length
        out[k:k + 2] = [MouthCue(first.start_cs, start, first.value), MouthCue(start, end, tween),
                        MouthCue(end, second.end_cs, second.value)]
        k += 2
    return out


def mouth_cues(animation: Animation, extended: str = EXTENDED_SHAPES, minimum: int = MIN_CUE_CS) -> list[MouthCue]:
    """Rhubarb's cues for the animation, every centisecond of its sound (module docstring); no cue
    shorter than `minimum` cs but the tweens (Rhubarb's 7 cs, or a longer --rig-hold)."""
    extended = parse_extended_shapes(extended)
    total = centiseconds(animation.sound_duration)
    if total < 1:
        raise AnimationError(f"the animation lasts {animation.sound_duration:.4f} s: shorter than Rhubarb's 0.01 s")
    # the model at every centisecond, not the frames interpolated: the cues do not depend on --fps
    fine = animation.resampled(100.0)
    shapes = shape_at(fine, np.arange(total) / 100.0)
    shapes = [s if s in BASIC_SHAPES or s in extended else BASIC_OF[s] for s in shapes]
    return insert_tweens(hold_minimum(_runs(shapes), max(minimum, MIN_CUE_CS)))


def _t(cs: int) -> str:
    return f"{cs // 100}.{cs % 100:02d}"


def closed_shape(extended: str) -> str:
    """The closed mouth Rhubarb ends a TSV and DAT with: X, or A without X."""
    return "X" if "X" in extended else "A"


def rhubarb_tsv(cues: list[MouthCue], duration_cs: int, extended: str) -> str:
    lines = [f"{_t(c.start_cs)}\t{c.value}" for c in cues] + [f"{_t(duration_cs)}\t{closed_shape(extended)}"]
    return "\n".join(lines) + "\n"


def rhubarb_json(cues: list[MouthCue], duration_cs: int, sound: str) -> str:
    body = ",\n".join(f'    {{ "start": {_t(c.start_cs)}, "end": {_t(c.end_cs)}, "value": "{c.value}" }}' for c in cues)
    return (f'{{\n  "metadata": {{\n    "soundFile": {json.dumps(sound)},\n    "duration": {_t(duration_cs)}\n  }},\n'
            f'  "mouthCues": [\n{body}\n  ]\n}}\n')


def rhubarb_xml(cues: list[MouthCue], duration_cs: int, sound: str) -> str:
    rows = "".join(f"    <mouthCue start={quoteattr(_t(c.start_cs))} end={quoteattr(_t(c.end_cs))}>{c.value}</mouthCue>\n"
                   for c in cues)
    return ('<?xml version="1.0" encoding="utf-8"?>\n<rhubarbResult>\n  <metadata>\n'
            f"    <soundFile>{escape(sound)}</soundFile>\n    <duration>{_t(duration_cs)}</duration>\n"
            f"  </metadata>\n  <mouthCues>\n{rows}  </mouthCues>\n</rhubarbResult>\n")


def rhubarb_dat(cues: list[MouthCue], duration_cs: int, fps: float, extended: str, preston_blair: bool = False) -> str:
    """Moho switch data: the frame (from 1) each cue starts on; DAT_FPS_RANGE frames per second."""
    lo, hi = DAT_FPS_RANGE
    if not lo <= fps <= hi:
        raise AnimationError(f"Rhubarb's DAT (Moho, OpenToonz) takes {lo:g} to {hi:g} fps; this animation has "
                             f"{fps:g}: animate with --fps in that range, or leave dat out of --rhubarb-formats")

    def name(shape: str) -> str:
        return PRESTON_BLAIR[shape] if preston_blair else shape

    def frame(cs: int) -> int:
        return 1 + int(fps * cs / 100.0 + 1e-9)

    lines, last = ["MohoSwitch1"], 0
    for c in cues:
        f = frame(c.start_cs)
        if f == last:
            continue
        lines.append(f"{f} {name(c.value)}")
        last = f
    f = frame(duration_cs)
    lines.append(f"{f + 1 if f == last else f} {name(closed_shape(extended))}")
    return "\n".join(lines) + "\n"


RHUBARB_FORMATS: tuple[str, ...] = ("tsv", "json", "xml", "dat")


def parse_rhubarb_formats(spec: str | None) -> tuple[str, ...]:
    """`--rhubarb-formats tsv,json,xml,dat` (default tsv and json) → the names, checked."""
    names = [s.strip().lower() for s in (spec or "tsv,json").split(",") if s.strip()]
    bad = [n for n in names if n not in RHUBARB_FORMATS]
    if bad or not names:
        raise AnimationError(f"--rhubarb-formats {spec!r}: choose among {', '.join(RHUBARB_FORMATS)} (comma-separated)")
    return tuple(n for n in RHUBARB_FORMATS if n in names)


def export_rhubarb(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter (coartic.runtime.exporters): NAME.rhubarb.tsv / .json / .xml / .dat, those of
    `settings.rig.rhubarb_formats`, with the extended shapes `settings.rig.extended_shapes`."""
    animation = fed.animation
    extended = parse_extended_shapes(settings.rig.extended_shapes)
    formats = parse_rhubarb_formats(",".join(settings.rig.rhubarb_formats))
    cues = mouth_cues(animation, extended, int(round(settings.rig.hold * 100)))
    duration = centiseconds(animation.sound_duration)
    sound = settings.audio_name() or ""
    text = {"tsv": lambda: rhubarb_tsv(cues, duration, extended),
            "json": lambda: rhubarb_json(cues, duration, sound),
            "xml": lambda: rhubarb_xml(cues, duration, sound),
            "dat": lambda: rhubarb_dat(cues, duration, animation.fps, extended, settings.rig.preston_blair)}
    written = {f: text[f]() for f in formats}  # every format made before any is written (DAT may refuse)
    out = {}
    for f, body in written.items():
        path = settings.out / f"{settings.name}.rhubarb.{f}"
        atomic_write_text(path, body)
        out[f"rhubarb_{f}"] = path
    return out
