"""MPEG-4 Facial Animation Parameters: FAPU, the channel → FAP mapping, and the FAP text file.

The mapping and its sign conventions are written down in docs/RUNTIME.md; keep the two in step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from coartic.runtime.errors import AnimationError, FapFormatError

if TYPE_CHECKING:
    from coartic.runtime.animate import Animation

N_FAPS = 68

# ISO/IEC 14496-2 FAP names, FAP 1 first.
FAP_NAMES: tuple[str, ...] = (
    "viseme", "expression", "open_jaw", "lower_t_midlip", "raise_b_midlip",
    "stretch_l_cornerlip", "stretch_r_cornerlip", "lower_t_lip_lm", "lower_t_lip_rm",
    "raise_b_lip_lm", "raise_b_lip_rm", "raise_l_cornerlip", "raise_r_cornerlip",
    "thrust_jaw", "shift_jaw", "push_b_lip", "push_t_lip", "depress_chin",
    "close_t_l_eyelid", "close_t_r_eyelid", "close_b_l_eyelid", "close_b_r_eyelid",
    "yaw_l_eyeball", "yaw_r_eyeball", "pitch_l_eyeball", "pitch_r_eyeball",
    "thrust_l_eyeball", "thrust_r_eyeball", "dilate_l_pupil", "dilate_r_pupil",
    "raise_l_i_eyebrow", "raise_r_i_eyebrow", "raise_l_m_eyebrow", "raise_r_m_eyebrow",
    "raise_l_o_eyebrow", "raise_r_o_eyebrow", "squeeze_l_eyebrow", "squeeze_r_eyebrow",
    "puff_l_cheek", "puff_r_cheek", "lift_l_cheek", "lift_r_cheek", "shift_tongue_tip",
    "raise_tongue_tip", "thrust_tongue_tip", "raise_tongue", "tongue_roll", "head_pitch",
    "head_yaw", "head_roll", "lower_t_midlip_o", "raise_b_midlip_o", "stretch_l_cornerlip_o",
    "stretch_r_cornerlip_o", "lower_t_lip_lm_o", "lower_t_lip_rm_o", "raise_b_lip_lm_o",
    "raise_b_lip_rm_o", "raise_l_cornerlip_o", "raise_r_cornerlip_o", "stretch_l_nose",
    "stretch_r_nose", "raise_nose", "bend_nose", "raise_l_ear", "raise_r_ear", "pull_l_ear",
    "pull_r_ear",
)
assert len(FAP_NAMES) == N_FAPS

# The lip-mid points (FAP 8-11) sit halfway between the midline and a corner; on the elliptic lip
# contour the preview also draws, a point at half the half-width moves sqrt(1 - 0.5^2) of the midline.
LIP_MID_FRACTION = math.sqrt(3.0) / 2.0

# FAP number → (channel, factor) with FAP value = factor * (channel - neutral) / FAPU. Factors carry
# the MPEG-4 sign (open_jaw and lower_t_* positive down, raise_b_* positive up, stretch_* outwards,
# push_* forwards) against the channel's own sign (ULO, LLO positive away from the lip midline,
# ULP, LLP positive forwards, LR the corner-to-corner width, JO the nose-chin distance).
_INNER: dict[int, tuple[str, float]] = {
    3: ("JO", 1.0),
    4: ("ULO", -1.0),
    5: ("LLO", -1.0),
    6: ("LR", 0.5),
    7: ("LR", 0.5),
    8: ("ULO", -LIP_MID_FRACTION),
    9: ("ULO", -LIP_MID_FRACTION),
    10: ("LLO", -LIP_MID_FRACTION),
    11: ("LLO", -LIP_MID_FRACTION),
    16: ("LLP", 1.0),
    17: ("ULP", 1.0),
}
# The vermilion markers cannot tell the inner from the outer contour, so the lips translate rigidly:
# each outer-lip twin (51-60) carries the value of its inner FAP.
OUTER_TWIN: dict[int, int] = {51: 4, 52: 5, 53: 6, 54: 7, 55: 8, 56: 9, 57: 10, 58: 11, 59: 12, 60: 13}
# No channel measures the corners' vertical position: 12/13 (and 59/60) are sent as 0 so that a
# player holds the corners at neutral instead of keeping whatever an earlier stream left there.
CORNER_LIFTS: tuple[int, ...] = (12, 13)
# Viseme and expression carry several values each (selects, blend, intensities). coartic drives the
# lips with the low-level FAPs and does not write the viseme (FAP 1, refused when read); it writes
# the expression (FAP 2) of an emotion it speaks with, alongside the low-level FAPs of the brows,
# lids, cheeks and corners (coartic.runtime.expression). In the FAP text file a sent FAP 2 takes
# these six values in its place (ISO/IEC 14496-2 C.1.3, the FAP 2 fields, and Xface's FAP file loader):
# expression_select1 (EXPRESSION_SELECT: 0 none .. 6 surprise), expression_intensity1 (0-63),
# expression_select2, expression_intensity2, init_face and expression_def (0 or 1 each).
HIGH_LEVEL_FAPS: tuple[int, ...] = (1, 2)
EXPRESSION_FAP = 2
EXPRESSION_FIELDS: tuple[str, ...] = ("expression_select1", "expression_intensity1", "expression_select2",
                                      "expression_intensity2", "init_face", "expression_def")
EXPRESSION_SELECT: dict[str, int] = {"joy": 1, "sadness": 2, "anger": 3, "fear": 4, "disgust": 5, "surprise": 6}
EXPRESSION_INTENSITY_MAX = 63
# each field's (lowest, highest) value
_EXPRESSION_RANGE: tuple[tuple[int, int], ...] = ((0, 6), (0, EXPRESSION_INTENSITY_MAX), (0, 6),
                                                  (0, EXPRESSION_INTENSITY_MAX), (0, 1), (0, 1))


def expression_field_error(row: NDArray[np.int64] | list[int]) -> str | None:
    """What is wrong with one frame's six FAP 2 values (EXPRESSION_FIELDS), or None."""
    for name, v, (lo, hi) in zip(EXPRESSION_FIELDS, row, _EXPRESSION_RANGE):
        if not lo <= int(v) <= hi:
            return f"{name} = {int(v)} is not within {lo}-{hi}"
    return None
MW_FAPS: frozenset[int] = frozenset({6, 7, 53, 54, 43, 45})
LIP_JAW_FAPS: tuple[int, ...] = tuple(sorted({*_INNER, *CORNER_LIFTS, *OUTER_TWIN}))
FAP_CHANNELS: tuple[str, ...] = ("ULO", "LLO", "ULP", "LLP", "LR", "JO")
# FAP values are integers that players read as 32-bit; beyond that a value wraps (the int64 cast of
# 1e21 FAPU gave INT64_MIN). docs/LIMITS.md.
FAP_VALUE_LIMIT = 2**31 - 1
# MNS and MW of a face, mm: a face unit outside this is a typo (--mns 1e-300), not a face.
FACE_UNIT_RANGE_MM = (1.0, 1000.0)


@dataclass(frozen=True)
class FaceUnits:
    """A face's neutral mouth-nose separation and mouth width (mm); one FAPU is distance / 1024."""

    mns_mm: float = 30.0
    mw_mm: float = 50.0

    def __post_init__(self) -> None:
        lo, hi = FACE_UNIT_RANGE_MM
        for name, value in (("mns_mm", self.mns_mm), ("mw_mm", self.mw_mm)):
            if not (math.isfinite(value) and value > 0.0):
                raise AnimationError(f"face unit {name} must be a positive length in mm, got {value!r}")
            if not lo <= value <= hi:
                raise AnimationError(f"face unit {name} = {value:g} mm is not a face's (a mouth-nose "
                                     f"separation or mouth width lies within {lo:g}-{hi:g} mm)")

    @property
    def mns(self) -> float:
        return self.mns_mm / 1024.0

    @property
    def mw(self) -> float:
        return self.mw_mm / 1024.0

    def unit_of(self, fap: int) -> float:
        """FAPU (mm) of a lip or jaw FAP."""
        return self.mw if fap in MW_FAPS else self.mns


@dataclass
class FapSequence:
    """Frames of FAP values: `mask[f, j]` says whether FAP j+1 is sent in frame f."""

    name: str
    fps: float
    mask: NDArray[np.bool_]
    values: NDArray[np.int64]
    first_frame: int = 0
    # FAP 2's six values per frame (EXPRESSION_FIELDS), where the mask sends FAP 2; None: not sent
    expression: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        self.mask = np.ascontiguousarray(self.mask, dtype=bool)
        self.values = np.ascontiguousarray(self.values, dtype=np.int64)
        if self.mask.ndim != 2 or self.mask.shape[1] != N_FAPS or self.values.shape != self.mask.shape:
            raise AnimationError(
                f"FAP sequence {self.name!r}: mask and values must both be (frames, {N_FAPS}), "
                f"got {self.mask.shape} and {self.values.shape}"
            )
        if not self.name or any(c.isspace() for c in self.name):
            raise AnimationError(f"FAP sequence name must be one word without spaces, got {self.name!r}")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise AnimationError(f"FAP sequence {self.name!r}: fps must be positive, got {self.fps!r}")
        if self.mask[:, 0].any():
            raise AnimationError(
                f"FAP sequence {self.name!r}: FAP 1 ({FAP_NAMES[0]}) is a high-level FAP with several values per "
                "frame; coartic drives the lips with the low-level FAPs 3-68 and writes no viseme"
            )
        sent = self.mask[:, EXPRESSION_FAP - 1]
        if self.expression is not None:
            self.expression = np.ascontiguousarray(self.expression, dtype=np.int64)
            if self.expression.shape != (self.n_frames, len(EXPRESSION_FIELDS)):
                raise AnimationError(f"FAP sequence {self.name!r}: the expression (FAP 2) must be (frames, "
                                     f"{len(EXPRESSION_FIELDS)}), got {self.expression.shape}")
            self.expression[~sent] = 0
            for f in np.flatnonzero(sent):
                why = expression_field_error(self.expression[f])
                if why is not None:
                    raise AnimationError(f"FAP sequence {self.name!r}, frame {int(f)}: FAP 2 (expression): {why}")
        elif sent.any():
            raise AnimationError(f"FAP sequence {self.name!r}: FAP 2 (expression) is sent without its six values "
                                 f"({', '.join(EXPRESSION_FIELDS)})")
        self.values[~self.mask] = 0
        self.values[:, EXPRESSION_FAP - 1] = 0  # FAP 2's values are its six fields'

    def with_arrays(self, mask: NDArray[np.bool_], values: NDArray[np.int64]) -> FapSequence:
        """The same sequence (name, rate, first frame, FAP 2) with another mask and values."""
        return FapSequence(name=self.name, fps=self.fps, mask=mask, values=values, first_frame=self.first_frame,
                           expression=self.expression)

    @property
    def n_frames(self) -> int:
        return int(self.mask.shape[0])

    def column(self, fap: int) -> NDArray[np.int64]:
        """Values of FAP `fap` (1-based number) over the frames."""
        if not 1 <= fap <= N_FAPS:
            raise AnimationError(f"FAP number must be in 1..{N_FAPS}, got {fap}")
        return self.values[:, fap - 1]

    def same_as(self, other: FapSequence) -> bool:
        return (
            self.name == other.name
            and self.fps == other.fps
            and (self.first_frame == other.first_frame or self.n_frames == 0)  # no frame, no number
            and np.array_equal(self.mask, other.mask)
            and np.array_equal(self.values, other.values)
            and np.array_equal(self._fields(), other._fields())
        )

    def _fields(self) -> NDArray[np.int64]:
        return (self.expression if self.expression is not None
                else np.zeros((self.n_frames, len(EXPRESSION_FIELDS)), dtype=np.int64))


def channels_to_faps(
    channels: Mapping[str, NDArray[np.float64]],
    neutral: Mapping[str, float],
    face: FaceUnits,
    name: str,
    fps: float,
) -> FapSequence:
    """Lip and jaw FAPs (see LIP_JAW_FAPS) from channel trajectories in mm and the neutral posture."""
    missing = [c for c in FAP_CHANNELS if c not in channels]
    if missing:
        raise AnimationError(f"FAPs need the channels {', '.join(FAP_CHANNELS)}; missing {', '.join(missing)}")
    missing = [c for c in FAP_CHANNELS if c not in neutral]
    if missing:
        raise AnimationError(f"the neutral posture has no value for channel(s) {', '.join(missing)}")
    n = len(channels[FAP_CHANNELS[0]])
    for c in FAP_CHANNELS:
        y = np.asarray(channels[c], dtype=float)
        if y.shape != (n,):
            raise AnimationError(f"channel {c} has shape {y.shape}, expected ({n},) like {FAP_CHANNELS[0]}")
        bad = np.flatnonzero(~np.isfinite(y))
        if bad.size:
            raise AnimationError(f"channel {c} is not finite at frame {int(bad[0])}: cannot convert to FAPs")
    mask = np.zeros((n, N_FAPS), dtype=bool)
    values = np.zeros((n, N_FAPS), dtype=np.int64)
    for fap, (channel, factor) in _INNER.items():
        mm = factor * (np.asarray(channels[channel], dtype=float) - float(neutral[channel]))
        if fap == 3:
            # open_jaw is unidirectional in MPEG-4: the jaw does not close past the neutral face.
            mm = np.maximum(mm, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):
            fapu = np.rint(mm / face.unit_of(fap))
        over = ~(np.abs(fapu) <= FAP_VALUE_LIMIT)
        if over.any():
            k = int(np.flatnonzero(over)[0])
            raise AnimationError(
                f"FAP {fap} ({FAP_NAMES[fap - 1]}) would be {fapu[k]:.4g} FAPU at frame {k} "
                f"({channel} {mm[k] / factor:+.6g} mm from the neutral face, FAPU {face.unit_of(fap):.4g} mm), "
                f"beyond the ±{FAP_VALUE_LIMIT} a FAP file holds: check the table's {channel} targets "
                "and the face units (--mns, --mw)")
        values[:, fap - 1] = fapu.astype(np.int64)
        mask[:, fap - 1] = True
    for fap in CORNER_LIFTS:
        mask[:, fap - 1] = True
    for outer, inner in OUTER_TWIN.items():
        values[:, outer - 1] = values[:, inner - 1]
        mask[:, outer - 1] = True
    return FapSequence(name=name, fps=fps, mask=mask, values=values)


def _format_fps(fps: float) -> str:
    return str(int(fps)) if float(fps).is_integer() else repr(float(fps))


def write_fap(path: str | Path, seq: FapSequence) -> None:
    """Write `seq` as a FAP text file (header, then a mask line and a value line per frame)."""
    lines = [f"2.1 {seq.name} {_format_fps(seq.fps)} {seq.n_frames}"]
    for f in range(seq.n_frames):
        m = seq.mask[f]
        lines.append(" ".join("1" if b else "0" for b in m))
        values = [str(int(v)) for v in seq.values[f][m]]
        if m[EXPRESSION_FAP - 1] and seq.expression is not None:  # FAP 2: its six fields in its place
            values[0:1] = [str(int(v)) for v in seq.expression[f]]
        lines.append(" ".join([str(seq.first_frame + f), *values]))
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def read_fap(path: str | Path) -> FapSequence:
    """Read a FAP text file; any deviation is a FapFormatError naming the file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as err:
        raise FapFormatError(f"{path}: not an ASCII FAP file ({err})") from None
    except OSError as err:
        raise FapFormatError(f"{path}: cannot read ({err.strerror})") from None
    raw = text.splitlines()
    # Blank lines carry nothing; keep the original line numbers for the messages.
    lines = [(i + 1, ln.split()) for i, ln in enumerate(raw) if ln.strip()]
    if not lines:
        raise FapFormatError(f"{path}: empty file, expected a header '2.1 <name> <fps> <nframes>'")
    lineno, head = lines[0]
    if len(head) != 4 or head[0] != "2.1":
        raise FapFormatError(
            f"{path}, line {lineno}: header must be '2.1 <name> <fps> <nframes>', got {raw[lineno - 1]!r}"
        )
    name = head[1]
    try:
        fps = float(head[2])
    except ValueError:
        raise FapFormatError(f"{path}, line {lineno}: fps {head[2]!r} is not a number") from None
    if not (math.isfinite(fps) and fps > 0):
        raise FapFormatError(f"{path}, line {lineno}: fps must be positive, got {head[2]!r}")
    try:
        n = int(head[3])
    except ValueError:
        raise FapFormatError(f"{path}, line {lineno}: frame count {head[3]!r} is not an integer") from None
    if n < 0:
        raise FapFormatError(f"{path}, line {lineno}: frame count must not be negative, got {n}")
    body = lines[1:]
    if len(body) != 2 * n:
        raise FapFormatError(
            f"{path}: header (line {lineno}) announces {n} frames = {2 * n} lines after it, "
            f"found {len(body)} non-blank lines"
        )
    mask = np.zeros((n, N_FAPS), dtype=bool)
    values = np.zeros((n, N_FAPS), dtype=np.int64)
    expression: NDArray[np.int64] | None = None
    first_frame = 0
    for f in range(n):
        mline, mtok = body[2 * f]
        if len(mtok) != N_FAPS or any(t not in ("0", "1") for t in mtok):
            raise FapFormatError(
                f"{path}, line {mline}: frame {f} mask must be {N_FAPS} zeros and ones, "
                f"got {len(mtok)} fields"
                + ("" if len(mtok) != N_FAPS else f" including {next(t for t in mtok if t not in ('0', '1'))!r}")
            )
        m = np.array([t == "1" for t in mtok])
        if m[0]:
            raise FapFormatError(
                f"{path}, line {mline}: FAP 1 ({FAP_NAMES[0]}) is set; the viseme (several values per frame) "
                "is not read, only the expression (FAP 2) and the low-level FAPs 3-68"
            )
        vline, vtok = body[2 * f + 1]
        try:
            ints = [int(t) for t in vtok]
        except ValueError:
            bad = next(t for t in vtok if not t.lstrip("+-").isdigit())
            raise FapFormatError(f"{path}, line {vline}: {bad!r} is not an integer FAP value") from None
        if f == 0:
            first_frame = ints[0]
        elif ints[0] != first_frame + f:
            raise FapFormatError(
                f"{path}, line {vline}: frame number {ints[0]}, expected {first_frame + f} (frames are consecutive)"
            )
        extra = len(EXPRESSION_FIELDS) - 1 if m[EXPRESSION_FAP - 1] else 0  # FAP 2 takes six values
        if len(ints) - 1 != int(m.sum()) + extra:
            raise FapFormatError(
                f"{path}, line {vline}: frame {ints[0]} has {len(ints) - 1} values but its mask "
                f"(line {mline}) selects {int(m.sum())} FAPs"
                + (f" ({int(m.sum()) + extra} values: FAP 2 takes {len(EXPRESSION_FIELDS)})" if extra else "")
            )
        mask[f] = m
        rest = ints[1:]
        if extra:
            fields = rest[: len(EXPRESSION_FIELDS)]
            why = expression_field_error(fields)
            if why is not None:
                raise FapFormatError(f"{path}, line {vline}: frame {ints[0]}: FAP 2 (expression): {why}")
            if expression is None:
                expression = np.zeros((n, len(EXPRESSION_FIELDS)), dtype=np.int64)
            expression[f] = fields
            rest = [0, *rest[len(EXPRESSION_FIELDS):]]
        values[f, m] = rest
    return FapSequence(name=name, fps=fps, mask=mask, values=values, first_frame=first_frame, expression=expression)


# Tongue channels (docs/DATA.md: EMA tongue tip and body, head frame, mm from rest) → MPEG-4 tongue
# FAPs: raise_tongue_tip (44, MNS, up), thrust_tongue_tip (45, MW, forwards), raise_tongue (46, MNS,
# up). Tongue-body advancement (TBA) has no MPEG-4 FAP; shift_tongue_tip (43) and tongue_roll (47)
# have no channel and are sent as 0.
TONGUE_FAP_CHANNELS: dict[int, str] = {44: "TTH", 45: "TTA", 46: "TBH"}
TONGUE_ZERO_FAPS: tuple[int, ...] = (43, 47)
# Blinks: close_t_l_eyelid (19) and close_t_r_eyelid (20), IRISD units (iris diameter / 1024). A
# blink lowers the lid by BLINK_CLOSED (a little more than an iris: the eye shuts), closing in
# 80 ms, shut for 40 ms, opening in 160 ms, every 2.4-5 s (a fixed sequence of intervals, so
# that every run of the same input gives the same file); the first comes 0.6 s in.
BLINK_FAPS: tuple[int, int] = (19, 20)
BLINK_CLOSED = 1100
BLINK_SHAPE_S = (0.08, 0.04, 0.16)
BLINK_INTERVALS_S = (3.2, 4.1, 2.6, 4.8, 3.5, 2.4, 4.4)
BLINK_FIRST_S = 0.6


def add_tongue_faps(seq: FapSequence, channels: Mapping[str, NDArray[np.float64]], neutral: Mapping[str, float],
                    face: FaceUnits) -> FapSequence:
    """`seq` with the tongue FAPs 43-47 from the tongue channels (TONGUE_FAP_CHANNELS), mm in the
    head frame, measured from `neutral` (the face at rest)."""
    mask, values = seq.mask.copy(), seq.values.copy()
    for fap, channel in TONGUE_FAP_CHANNELS.items():
        y = np.asarray(channels[channel], dtype=float)
        if y.shape != (seq.n_frames,):
            raise AnimationError(f"tongue channel {channel} has shape {y.shape}, expected ({seq.n_frames},)")
        bad = np.flatnonzero(~np.isfinite(y))
        if bad.size:
            raise AnimationError(f"tongue channel {channel} is not finite at frame {int(bad[0])}")
        fapu = np.rint((y - float(neutral[channel])) / face.unit_of(fap))
        if not (np.abs(fapu) <= FAP_VALUE_LIMIT).all():
            raise AnimationError(f"FAP {fap} ({FAP_NAMES[fap - 1]}) from {channel} is beyond ±{FAP_VALUE_LIMIT} FAPU: "
                                 f"check the table's {channel} targets")
        values[:, fap - 1] = fapu.astype(np.int64)
        mask[:, fap - 1] = True
    for fap in TONGUE_ZERO_FAPS:
        values[:, fap - 1] = 0
        mask[:, fap - 1] = True
    return seq.with_arrays(mask, values)


def blink_profile(times: NDArray[np.float64]) -> NDArray[np.float64]:
    """How closed the eyelids are (0 open .. 1 shut) at `times` (s) under the blink schedule."""
    close, hold, opening = BLINK_SHAPE_S
    out = np.zeros(np.shape(times))
    t0, k = BLINK_FIRST_S, 0
    end = float(np.max(times)) if np.size(times) else 0.0
    while t0 <= end:
        d = np.asarray(times) - t0
        shape = np.where(d < 0, 0.0, np.where(d < close, d / close, np.where(
            d < close + hold, 1.0, np.clip(1.0 - (d - close - hold) / opening, 0.0, 1.0))))
        out = np.maximum(out, 0.5 - 0.5 * np.cos(np.pi * shape))  # eased in and out
        t0 += BLINK_INTERVALS_S[k % len(BLINK_INTERVALS_S)]
        k += 1
    return out


def add_blinks(seq: FapSequence) -> FapSequence:
    """`seq` with both upper eyelids (FAPs 19, 20) blinking on the fixed schedule (BLINK_*)."""
    mask, values = seq.mask.copy(), seq.values.copy()
    closed = np.rint(BLINK_CLOSED * blink_profile(np.arange(seq.n_frames) / seq.fps)).astype(np.int64)
    for fap in BLINK_FAPS:
        values[:, fap - 1] = closed
        mask[:, fap - 1] = True
    return seq.with_arrays(mask, values)


def animation_faps(animation: Animation, face: FaceUnits, name: str) -> FapSequence:
    """The animation's FAPs in `face`'s units: lips and jaw from its channels and neutral face, the
    tongue from its table's tongue channels or the default (coartic.runtime.tongue), blinks, and the
    expression of an emotion it speaks with (coartic.runtime.expression)."""
    from coartic.runtime.expression import expression_fap_offsets
    from coartic.runtime.tongue import tongue_channels

    faps = channels_to_faps(animation.channels, animation.neutral, face, name, animation.fps)
    tongue, rest, _ = tongue_channels(animation)
    # an emotion's brows, lids, cheeks and corners (coartic.runtime.expression), over the blinks, and
    # the same emotion as the high-level expression (FAP 2) for players that render it
    expression = expression_fap_offsets(animation, face.mns_mm, face.mw_mm)
    # the lips translate rigidly (OUTER_TWIN): a corner moved by the emotion moves both contours
    expression.update({outer: expression[inner] for outer, inner in OUTER_TWIN.items() if inner in expression})
    low = add_fap_offsets(add_blinks(add_tongue_faps(faps, tongue, rest, face)), expression)
    return with_expression(low, expression_fap2(animation))


def expression_fap2(animation: Animation) -> NDArray[np.int64] | None:
    """FAP 2's six values per frame (EXPRESSION_FIELDS) of the emotion the animation speaks with
    (``coartic.runtime.expression``'s docstring: the two strongest per frame, intensities on 0-63);
    None without one (the FAP file then does not send FAP 2)."""
    from coartic.emotions import expression_weights

    weights = {e: w for e, w in expression_weights(animation.table, animation.times).items()
               if e in EXPRESSION_SELECT}
    if not weights:
        return None
    names = list(weights)
    w = np.stack([np.asarray(weights[e], dtype=np.float64) for e in names], axis=1)  # (frames, emotions)
    q = np.rint(np.clip(w, 0.0, 1.0) * EXPRESSION_INTENSITY_MAX).astype(np.int64)
    order = np.argsort(-w, axis=1, kind="stable")
    out = np.zeros((animation.n_frames, len(EXPRESSION_FIELDS)), dtype=np.int64)
    codes = np.array([EXPRESSION_SELECT[e] for e in names], dtype=np.int64)
    rows = np.arange(animation.n_frames)
    for slot in range(min(2, len(names))):
        k = order[:, slot]
        level = q[rows, k]
        out[:, 2 * slot] = np.where(level > 0, codes[k], 0)
        out[:, 2 * slot + 1] = level
    return out


def with_expression(seq: FapSequence, fields: NDArray[np.int64] | None) -> FapSequence:
    """``seq`` sending FAP 2 in every frame with ``fields`` (frames, 6: EXPRESSION_FIELDS); ``seq``
    itself for None."""
    if fields is None:
        return seq
    mask = seq.mask.copy()
    mask[:, EXPRESSION_FAP - 1] = True
    return FapSequence(name=seq.name, fps=seq.fps, mask=mask, values=seq.values, first_frame=seq.first_frame,
                       expression=fields)


def add_fap_offsets(seq: FapSequence, offsets: Mapping[int, NDArray[np.float64]]) -> FapSequence:
    """``seq`` with ``offsets`` (FAP -> values per frame, FAP units) added, each FAP sent; ``seq``
    itself when there are none."""
    if not offsets:
        return seq
    mask, values = seq.mask.copy(), seq.values.copy()
    for fap, add in offsets.items():
        col = values[:, fap - 1].astype(np.float64) + np.asarray(add, dtype=np.float64)[: seq.n_frames]
        values[:, fap - 1] = np.clip(np.rint(col), -FAP_VALUE_LIMIT, FAP_VALUE_LIMIT).astype(np.int64)
        mask[:, fap - 1] = True
    return seq.with_arrays(mask, values)
