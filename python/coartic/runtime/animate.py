"""Parameter table + phonemes with times → channel trajectories at a frame rate.

The model itself is evaluated by the Rust core through `coartic.model.trajectories`; this module
checks the request (every phoneme present for every channel, before the core sees it), lays out
the frames, and keeps what a player needs next to the numbers (segments, neutral posture).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Container, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from coartic.io.labelmap import LabelMap
from coartic.io.labels import Segments
from coartic.runtime.errors import AnimationError, MissingPhonemeError
from coartic.table import CHANNELS, PAUSE, ParameterTable
from coartic.outputs import atomic_write_text

if TYPE_CHECKING:
    from coartic.speakers import SpeakerMapping


# The most frames one animation may have (11 hours at 25 fps): channels, FAP text (~200 bytes a
# frame) and preview grow with it, so a mistaken --fps 1e9 or a label ending at 1e6 s is refused
# before anything is allocated. docs/LIMITS.md.
MAX_FRAMES = 1_000_000
# A fitted k_R sits at its upper bound 1 only to the optimiser's tolerance (0.9999996 in a
# least-squares table): within this of 1 a target counts as a contact for snapping.
CONTACT_K_R_TOLERANCE = 1e-3
# A channel the table does not have is held at rest; only LR's absolute value matters to the
# preview (the mouth's width), and FAPs are displacements from it, i.e. 0.
# Animation.segment_shares takes the segments this close (s) to its frames; callers go through an
# animation SHARE_FRAMES frames at a time (memory: frames x segments of one block)
SHARE_MARGIN_S = 2.0
SHARE_FRAMES = 250
REST_DEFAULTS_MM: dict[str, float] = {"ULO": 0.0, "LLO": 0.0, "ULP": 0.0, "LLP": 0.0, "LR": 50.0, "JO": 0.0}


@dataclass(frozen=True)
class Animation:
    """Channel trajectories sampled at frame times `k / fps`, k = 0 .. n_frames - 1."""

    fps: float
    times: NDArray[np.float64]
    channels: dict[str, NDArray[np.float64]]
    segments: Segments
    substitutions: dict[str, str] = field(default_factory=dict)
    # channel -> the instants actually sampled, where contact snapping moved some frames
    sample_times: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    # channels the table does not have: held at the neutral posture in `channels`, not modelled
    at_rest: tuple[str, ...] = ()
    # the face at rest (the pause's targets, mm) that FAPs, rig weights and cues are measured from
    neutral: dict[str, float] = field(default_factory=dict)
    # the table that animated it (a speaker's own with --speaker): its dominance functions give
    # each segment's share of every frame (`segment_shares`)
    table: ParameterTable | None = None
    # the time the frames were laid over (the sound's duration, else the labels' end), s; the frames
    # cover it to within half a frame (`duration`), Rhubarb's cues cover it exactly
    span: float | None = None
    # the speaker of a multi-speaker table the channels are said as (a + b·F of `table`'s, coartic.speakers)
    speaker: SpeakerMapping | None = None

    @property
    def modelled(self) -> list[str]:
        """The channels the table animated (not held at rest), in `channels` order."""
        return [c for c in self.channels if c not in self.at_rest]

    @property
    def n_frames(self) -> int:
        return int(self.times.size)

    def segment_shares(self, channel: str, start: int = 0, stop: int | None = None) -> NDArray[np.float64]:
        """(frames, segments) for frames start..stop: each segment's share of `channel`, its
        dominance weight w_i = S_i R_i D_i / Σ_j R_j D_j (coartic.model.segment_weights)
        normalised to sum 1, at the instants the frames sampled. Only the segments within
        SHARE_MARGIN_S of those frames enter (a dominance function that far away is below 1e-4
        of its peak for any θ ≥ 5 /s), so a long animation costs frames × nearby segments."""
        from coartic.model import segment_weights

        if self.table is None:
            raise AnimationError("this animation does not carry the table that made it: no dominance weights")
        times = self.sample_times.get(channel, self.times)[start:stop]
        seg = self.segments
        out = np.zeros((times.size, len(seg)))
        if times.size == 0:
            return out
        near = np.flatnonzero((seg.ends >= times[0] - SHARE_MARGIN_S) & (seg.starts <= times[-1] + SHARE_MARGIN_S))
        if near.size == 0:  # frames past the last segment: the nearest one holds
            near = np.array([int(np.argmin(np.abs(seg.starts - times[0])))])
        w = segment_weights(self.table, channel, [seg.labels[i] for i in near], seg.starts[near], seg.ends[near],
                            times).T
        w = np.maximum(w, 0.0)
        out[:, near] = w / np.maximum(w.sum(axis=1, keepdims=True), np.finfo(float).tiny)
        return out

    def resampled(self, fps: float) -> Animation:
        """The same animation at another frame rate: the model evaluated anew at the new frames over
        the same span (not the frames interpolated), as the speaker says it, with the same neutral
        face. For cues finer than the frames (Rhubarb's centiseconds, coartic.runtime.rhubarb), so
        that they do not depend on --fps. No contact snapping: it moves a frame by at most half of
        one, which at such rates is below the cues' resolution."""
        if self.table is None:
            raise AnimationError("this animation does not carry the table that made it: it cannot be resampled")
        fine = animate(self.table, self.segments, fps, duration=self.sound_duration, channels=self.modelled,
                       substitutions=self.substitutions, snap_contacts=False)
        channels = {}
        for c, v in self.channels.items():
            if c not in fine.channels:  # held at rest
                channels[c] = np.full(fine.n_frames, v[0])
            elif self.speaker is not None:
                channels[c] = self.speaker.apply(c, fine.channels[c])
            else:
                channels[c] = fine.channels[c]
        return replace(fine, channels=channels, at_rest=self.at_rest, neutral=self.neutral, span=self.span,
                       speaker=self.speaker)

    @property
    def duration(self) -> float:
        """Playing time: n_frames frames of 1 / fps each."""
        return self.n_frames / self.fps

    @property
    def sound_duration(self) -> float:
        """The time animated (`span`), or the frames' playing time when it was not recorded."""
        return self.span if self.span is not None else self.duration


def frame_times(duration: float, fps: float) -> NDArray[np.float64]:
    """Frame times for `duration` seconds: round(duration * fps) frames (so within half a frame)."""
    if not (math.isfinite(fps) and fps > 0):
        raise AnimationError(f"frame rate must be a positive number of frames per second, got {fps!r}")
    if not (math.isfinite(duration) and duration > 0):
        raise AnimationError(f"duration must be positive, got {duration!r} s")
    n_exact = duration * fps
    if not math.isfinite(n_exact) or n_exact > MAX_FRAMES:
        raise AnimationError(
            f"{duration:g} s at {fps:g} fps is {n_exact:.3g} frames, more than the {MAX_FRAMES} an "
            "animation may have (docs/LIMITS.md): lower --fps or check the label times")
    n = max(1, int(round(n_exact)))
    return np.arange(n, dtype=np.float64) / fps


def table_channels(table: ParameterTable) -> list[str]:
    """The runtime's channels (ULO..JO) that `table` has; a table with none cannot be animated."""
    have = [c for c in CHANNELS if c in table.channels]
    if not have:
        raise MissingPhonemeError(
            f"{table.source} has none of the channels {', '.join(CHANNELS)} (it has "
            f"{', '.join(table.channels)}): nothing to animate")
    return have


def _segment_where(segments: Segments, i: int) -> str:
    src = f" of {segments.source}" if segments.source is not None else ""
    line = segments.lines[i] if i < len(segments.lines) else None
    at = f", line {line}" if line is not None else ""
    return f"segment {i + 1}{src}{at} ({segments.starts[i]:.3f}-{segments.ends[i]:.3f} s)"


def check_phonemes(table: ParameterTable, segments: Segments, channels: Sequence[str]) -> None:
    """Raise MissingPhonemeError naming the first phoneme or channel the table cannot animate."""
    missing_ch = [c for c in channels if c not in table.channels]
    if missing_ch:
        raise MissingPhonemeError(
            f"{table.source}: channel(s) {', '.join(missing_ch)} not in the table "
            f"(it has {', '.join(table.channels)})"
        )
    for i, ph in enumerate(segments.labels):
        have = table.values.get(ph, {})
        lacking = [c for c in channels if c not in have]
        if lacking:
            what = "phoneme" if not have else f"phoneme with channel(s) {', '.join(lacking)}:"
            raise MissingPhonemeError(
                f"{table.source} has no {what} {ph!r}, needed by {_segment_where(segments, i)}; "
                f"the table's phonemes are {' '.join(table.phonemes)}",
                segment=i,
            )


# A fallback that is no phoneme: the segment shows the phoneme of the segment after it (the one
# before it when a pause or the end follows). For sounds with no oral posture of their own, such as
# English /h/, a voiceless onset of the vowel that follows (phones_english.tsv).
NEXT_PHONEME = ">"


def substitute(
    segments: Segments,
    table: ParameterTable,
    channels: Sequence[str],
    fallbacks: Mapping[str, Sequence[str]],
) -> tuple[Segments, dict[str, str]]:
    """Replace phonemes the table lacks by their first fallback it has; report what was replaced.

    A phoneme with no usable fallback stays, so that check_phonemes names it. The fallback
    ``NEXT_PHONEME`` takes the neighbouring segment's phoneme (reported as ``NEXT_PHONEME``).
    """
    used = substitutions(segments.labels, table, channels, fallbacks)
    if not used:
        return segments, used
    labels = [used.get(ph, ph) for ph in segments.labels]
    # NEXT_PHONEME: the segment after decides (resolved from the end, so a run of them takes the same
    # phoneme); before a pause or at the end, the segment before (resolved from the start)
    for i in reversed(range(len(labels))):
        if labels[i] == NEXT_PHONEME and i + 1 < len(labels) and labels[i + 1] not in (PAUSE, NEXT_PHONEME):
            labels[i] = labels[i + 1]
    for i, ph in enumerate(labels):
        if ph == NEXT_PHONEME:
            labels[i] = labels[i - 1] if i > 0 else PAUSE
    return segments.with_labels(labels), used


def substitutions(
    labels: Sequence[str], table: ParameterTable, channels: Sequence[str], fallbacks: Mapping[str, Sequence[str]]
) -> dict[str, str]:
    """Each of `labels` the table lacks (on any of `channels`) → its first fallback the table has
    (the phonetic class's, e.g. phones_italian.tsv); a phoneme with none is left out."""
    complete = {p for p, per in table.values.items() if all(c in per for c in channels)}
    used: dict[str, str] = {}
    for ph in labels:
        # NEXT_PHONEME is not a phoneme of any table: it is available wherever a phone map names it
        choice = _first_available(ph, fallbacks.get(ph, ()), complete | {NEXT_PHONEME})
        if choice != ph:
            used[ph] = choice
    return used


def _first_available(phoneme: str, fallbacks: Sequence[str], available: Container[str]) -> str:
    for candidate in (phoneme, *fallbacks):
        if candidate in available:
            return candidate
    return phoneme


# How long the pause after the last word lasts for the model (s). A pause's target time lies in
# its middle (MODEL.md §1), so the longer the silence a WAV or label file carries after the last
# word, the later the model aims the return to rest, and the mouth went on opening after the voice
# had stopped (44 ms after the last /a/ of "Il babbo mangia la pappa.", Festival's 0.43-s final
# pause). Silence is not articulation: the final pause is given this span and the rest of the
# silence is a second pause, held at rest. bench/runtime_lag.py measures it over sentences and rates.
FINAL_PAUSE_S = 0.1


def split_final_pause(segments: Segments, span: float = FINAL_PAUSE_S) -> tuple[Segments, list[int]]:
    """The segments with an utterance-final pause longer than `span` split in two, the first part
    lasting `span`; and for each new segment the index of the one it came from (to carry
    per-segment columns along). Without a final pause after speech, the segments as they are."""
    n = len(segments)
    origin = list(range(n))
    speech = [i for i, p in enumerate(segments.labels) if p != PAUSE]
    if not speech or speech[-1] != n - 2 or segments.ends[-1] - segments.starts[-1] <= span:
        return segments, origin
    cut = float(segments.starts[-1]) + span
    out = Segments((*segments.labels, PAUSE), np.append(segments.starts, cut),
                   np.append(np.append(segments.ends[:-1], cut), segments.ends[-1]), source=segments.source,
                   lines=(*segments.lines, segments.lines[-1]), tier=segments.tier)
    return out, [*origin, n - 1]


def evaluate(
    table: ParameterTable, segments: Segments, times: NDArray[np.float64], channels: Sequence[str] = CHANNELS
) -> dict[str, NDArray[np.float64]]:
    """The channels at arbitrary times (the Rust core through coartic.model), after checking the input."""
    from coartic.model import ModelInputError, trajectories

    check_phonemes(table, segments, channels)
    try:
        # the segments are the table's phonemes already (the label map was applied when reading)
        out = trajectories(table, list(segments.labels), segments.starts, segments.ends,
                           np.ascontiguousarray(times, dtype=np.float64), channels=list(channels),
                           label_map=LabelMap.identity(table.phonemes, str(table.source)))
    except ModelInputError as err:
        where = f"{segments.source}: " if segments.source is not None else ""
        raise AnimationError(f"{where}{err}") from None
    return {c: np.asarray(out[c], dtype=np.float64) for c in channels}


def animate(
    table: ParameterTable,
    segments: Segments,
    fps: float,
    *,
    duration: float | None = None,
    channels: Sequence[str] | None = None,
    substitutions: Mapping[str, str] | None = None,
    snap_contacts: bool = True,
) -> Animation:
    """Trajectories of `channels` for `segments` at `fps` over `duration` (default: to the last end).

    `channels` defaults to the six runtime channels; those the table does not have are held at the
    neutral posture (listed in `Animation.at_rest`), so a table fitted on some channels animates.
    With `snap_contacts`, the frame nearest to the target time of a phoneme with k_R = 1 on a
    channel shows that channel at the target time itself (at most half a frame away): a /p/ of
    30 ms falls between two frames at 25 fps, and uniform sampling would show lips that never close.
    """
    total = segments.end_time if duration is None else duration
    times = frame_times(total, fps)
    longest = float(np.max(segments.ends - segments.starts)) if len(segments) else 0.0
    if longest * fps < 1.0:
        # every phoneme would fall between two frames: the frames would show none of them
        raise AnimationError(
            f"{segments.source}: at {fps:g} fps a frame lasts {1 / fps:.3g} s, longer than every phoneme "
            f"(the longest lasts {longest:.3g} s): no phoneme would be shown; use --fps {math.ceil(1 / longest) if longest > 0 else 25} "
            "or more (25 is usual)")
    if channels is None:
        modelled = table_channels(table)
        at_rest = tuple(c for c in CHANNELS if c not in modelled)
    else:
        modelled, at_rest = list(channels), ()
    check_phonemes(table, segments, modelled)
    values: dict[str, NDArray[np.float64]] = {}
    snapped: dict[str, NDArray[np.float64]] = {}
    rest = neutral_posture(table, at_rest) if at_rest else {}
    neutral = neutral_posture(table, [*modelled, *at_rest]) if PAUSE in table.values else {}
    for ch in (CHANNELS if channels is None else channels):
        if ch in at_rest:
            values[ch] = np.full(times.size, rest[ch])
            continue
        sample = contact_sample_times(table, segments, ch, times, fps) if snap_contacts else times
        values[ch] = evaluate(table, segments, sample, [ch])[ch]
        values[ch] = values[ch] + emotion_spans_deviation(table, segments, sample, ch, values[ch])
        if not np.array_equal(sample, times):
            snapped[ch] = sample
    return Animation(fps=float(fps), times=times, channels=values, segments=segments,
                     substitutions=dict(substitutions or {}), sample_times=snapped, at_rest=at_rest,
                     neutral=neutral, table=table, span=float(total))


def emotion_spans_deviation(table: ParameterTable, segments: Segments, times: NDArray[np.float64], channel: str,
                            neutral: NDArray[np.float64]) -> NDArray[np.float64]:
    """What a table's emotion spans (``coartic.emotions.with_emotion_spans``) add to the neutral
    trajectory ``neutral`` of ``channel``: each emotion's deviation trajectory F_e − F_neutral
    weighted by its ramped intensity at ``times`` (the model is linear in the targets and the emotions
    share the dynamics, so a constant span gives the emotion's own trajectory; the contacts, kept
    neutral in every emotion's table, stay where they are; a table fitted with emotions =
    "targets+dynamics" has its own rates per emotion, and a span below intensity 1 then blends the two
    trajectories rather than the rates, as the ramps do anyway). Zeros without spans."""
    meta = (table.metadata or {}).get("expression")
    out = np.zeros_like(neutral)
    if not isinstance(meta, dict) or "spans" not in meta:
        return out
    from coartic.emotions import emotion_table, span_weights

    for emotion, w in span_weights(meta["spans"], times).items():
        if np.any(w != 0.0):
            out += w * (evaluate(emotion_table(table, emotion, 1.0), segments, times, [channel])[channel] - neutral)
    return out


def contact_sample_times(
    table: ParameterTable, segments: Segments, channel: str, times: NDArray[np.float64], fps: float
) -> NDArray[np.float64]:
    """Frame times, except that the frame nearest each k_R = 1 target time samples that time.

    k_R counts as 1 within CONTACT_K_R_TOLERANCE (a fitted table holds 0.9999996, not 1.0). The
    first target claims a frame (a geminate /p p/ at speed can share one); frames stay in order
    because a target time moves its frame by at most half a frame.
    """
    sample = times.copy()
    claimed = np.zeros(times.size, dtype=bool)
    t_target = target_times(table, segments, channel)
    for i, ph in enumerate(segments.labels):
        if table.values[ph][channel]["k_r"] < 1.0 - CONTACT_K_R_TOLERANCE:
            continue
        k = min(max(int(round(t_target[i] * fps)), 0), times.size - 1)
        # the tolerance lets a target exactly between two frames (rounded either way) take one
        if not claimed[k] and abs(t_target[i] - times[k]) <= 0.5 / fps + 1e-9:
            sample[k] = t_target[i]
            claimed[k] = True
    return sample


def neutral_posture(table: ParameterTable, channels: Sequence[str] = CHANNELS) -> dict[str, float]:
    """The face at rest: the pause phoneme's targets, the posture MPEG-4's neutral face stands for.

    A channel the table does not have at all takes REST_DEFAULTS_MM (it is held there)."""
    modelled = [c for c in channels if c in table.channels]
    rest = table.values.get(PAUSE)
    if rest is None and modelled:
        raise MissingPhonemeError(
            f"{table.source} has no pause phoneme {PAUSE!r}: its targets are the neutral face that FAPs "
            "are measured from"
        )
    lacking = [c for c in modelled if rest is None or c not in rest]
    if lacking:
        raise MissingPhonemeError(f"{table.source}: pause phoneme {PAUSE!r} has no channel(s) {', '.join(lacking)}")
    return {c: float(rest[c]["target"]) if rest is not None and c in modelled else REST_DEFAULTS_MM[c]
            for c in channels}


def target_times(table: ParameterTable, segments: Segments, channel: str) -> NDArray[np.float64]:
    """t_i = s_i + a (e_i - s_i) + δ, clamped into the segment (MODEL.md §1): where targets are aimed."""
    a = table.channels[channel].apex_fraction
    delta = np.array([table.values[p][channel]["delta"] for p in segments.labels])
    t = segments.starts + a * (segments.ends - segments.starts) + delta
    clamped: NDArray[np.float64] = np.clip(t, segments.starts, segments.ends)
    return clamped


def write_channels_csv(path: str | Path, animation: Animation) -> None:
    """`frame,time,<channel>...` in mm, floats with repr (read back bit for bit)."""
    names = animation.modelled  # channels held at rest are constants, not model output
    rows = [["frame", "time", *names]]
    for k, t in enumerate(animation.times):
        rows.append([str(k), repr(float(t)), *(repr(float(animation.channels[c][k])) for c in names)])
    atomic_write_text(path, "".join(",".join(r) + "\n" for r in rows))


def read_channels_csv(path: str | Path) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]]]:
    """Frame times and channels of a file written by write_channels_csv."""
    path = Path(path)
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows or rows[0][:2] != ["frame", "time"]:
        raise AnimationError(f"{path}, line 1: expected a header 'frame,time,<channel>...'")
    names = rows[0][2:]
    try:
        data = np.array([[float(x) for x in r[1:]] for r in rows[1:]], dtype=np.float64).reshape(-1, len(names) + 1)
    except ValueError as err:
        raise AnimationError(f"{path}: not a channel table written by coartic ({err})") from None
    return data[:, 0], {c: data[:, j + 1] for j, c in enumerate(names)}


def write_segments_tsv(path: str | Path, segments: Segments, requested: Sequence[str], source: Sequence[str]) -> None:
    """`start end phoneme shown_as source`: the phoneme asked for, what the table animated it as
    (a fallback, or the same), and the corpus or Festival label. Label readers take the first three
    columns, so the file animates again with `coartic animate` (with another table, say)."""
    lines = ["start\tend\tphoneme\tshown_as\tsource"]
    for i, (shown, s, e) in enumerate(zip(segments.labels, segments.starts, segments.ends)):
        lines.append(f"{float(s)!r}\t{float(e)!r}\t{requested[i]}\t{shown}\t{source[i]}")
    atomic_write_text(path, "\n".join(lines) + "\n")
