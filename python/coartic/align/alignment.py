"""An alignment (phones with times in the recording, their words and model phonemes, a confidence)
and alignment by synthesis: the transcript said by a TTS, its MFCC sequence warped onto the
recording's by dynamic time warping (dtw-python), its phone boundaries carried across the warp.

Long recordings are aligned part by part (`split_text`): each part of the transcript is said
alone and warped onto a window of the recording that starts where the previous part ended and
reaches well past where it should end (open end), so memory and time grow with the recording, not
its square.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from coartic.align.audio import HOP, RATE, SILENCE_DBFS, WINDOW, Recording, frame_levels, mfcc, speech_frames
from coartic.align.errors import AlignError
from coartic.align.synthesis import Spoken, speak_transcript, split_text
from coartic.io.labels import Segments
from coartic.runtime.festival import PhoneMap
from coartic.table import PAUSE

# Warp distance relative to the distance between unrelated frames of the two recordings, above which
# the transcript probably does not say what the recording says (docs/ALIGN.md: on the three German EMA
# recordings the right transcript gives 0.79-0.82, another German sentence 0.86-0.90).
MISMATCH_RATIO = 0.84
# A part of the recording is searched up to this many times its synthetic duration, plus SLACK s.
SEARCH_FACTOR = 2.5
SLACK = 3.0
# dtw-python's step pattern of the warp (chosen on the German recordings: bench/align_accuracy.py)
STEP_PATTERN = "symmetricP1"
OPEN_END_PATTERN = "asymmetricP1"
# Speech is louder than the noise floor by this fraction of the floor-to-speech range.
SPEECH_ABOVE_FLOOR = 0.25
# A pause this long (s) in the recording may end a part of a long transcript.
PART_PAUSE = 0.2
MIN_PHONE = 0.01  # s: the shortest phone an alignment gives (one frame)
# Speech left after the transcript's end (s) that makes the transcript look incomplete.
LEFTOVER_SPEECH = 0.5

Progress = Callable[[int, int], None]  # (parts done, parts)


@dataclass
class Alignment:
    """Phones of the transcript with their times in the recording."""

    phones: tuple[str, ...]  # in the aligner's phone set ("" for a pause)
    phonemes: tuple[str, ...]  # the model's
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]
    word_of: tuple[int, ...]  # index into words, -1 for a pause
    words: tuple[str, ...]
    duration: float  # of the recording, s
    method: str  # how it was aligned, in words, for the report
    phone_map: PhoneMap  # the fallbacks of its phonemes
    confidence: float | None = None  # warp distance ratio (alignment by synthesis; lower is better)
    warnings: list[str] = field(default_factory=list)
    # the parts a long transcript was aligned in: (start, end) in the recording (s) and the part's words
    parts: list[tuple[float, float, str]] = field(default_factory=list)

    def segments(self) -> Segments:
        """The model phonemes as Segments (what the runtime animates)."""
        return Segments(self.phonemes, self.starts, self.ends)

    def word_intervals(self) -> list[tuple[str, float, float]]:
        """(word, start, end) of each word, "" between them, covering the recording."""
        out: list[tuple[str, float, float]] = []
        for i, w in enumerate(self.word_of):
            label = self.words[w] if w >= 0 else ""
            if out and i > 0 and self.word_of[i - 1] == w:
                out[-1] = (label, out[-1][1], float(self.ends[i]))
            else:
                out.append((label, float(self.starts[i]), float(self.ends[i])))
        return out


def _frame_time(i: NDArray[np.float64] | float) -> NDArray[np.float64]:
    return np.asarray(np.asarray(i, dtype=np.float64) * HOP + WINDOW / 2)


def _warp(synth: NDArray[np.float64], real: NDArray[np.float64], open_end: bool, step_pattern: str = "symmetric2") -> tuple[
        NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], float]:
    """The warping path (synthetic frame, real frame), the local distance along it, and the warp's
    normalised distance (inf where no path fits)."""
    from dtw import dtw
    from scipy.spatial.distance import cdist

    local = cdist(synth, real)
    if open_end and local.shape[1] < local.shape[0] / 2:
        open_end = False  # too little recording left to leave its end open
    try:
        found = dtw(local, step_pattern=_step_pattern(step_pattern), open_end=open_end)
    except ValueError:  # no path within the slope limits: the speech is far shorter than the text's
        if step_pattern == "symmetric2":
            raise AlignError("the recording is far too short for the transcript: is the transcript for this "
                             "recording?") from None
        return _warp(synth, real, open_end, "symmetric2")
    i = np.asarray(found.index1, dtype=np.int64)
    j = np.asarray(found.index2, dtype=np.int64)
    return i, j, np.asarray(local[i, j], dtype=np.float64), float(found.normalizedDistance)


def _step_pattern(name: str) -> object:
    import dtw

    pattern = getattr(dtw, name, None)
    if pattern is None or not isinstance(pattern, dtw.StepPattern):
        raise AlignError(f"dtw-python has no step pattern {name!r}")
    return pattern


def _carry(times: NDArray[np.float64], i: NDArray[np.int64], j: NDArray[np.int64], n_synth: int) -> NDArray[np.float64]:
    """Synthetic times → real times (s, from the window's start) through the path: each synthetic
    frame goes to the mean of the real frames it was matched with, and times between frames are
    interpolated."""
    sums = np.bincount(i, weights=j.astype(np.float64), minlength=n_synth)
    counts = np.bincount(i, minlength=n_synth)
    real_of = sums / np.maximum(counts, 1)
    frames = (times - WINDOW / 2) / HOP
    return np.asarray(np.interp(frames, np.arange(n_synth), real_of) * HOP + WINDOW / 2)


def _tidy(bounds: NDArray[np.float64], end: float) -> NDArray[np.float64]:
    """Boundaries made increasing by at least MIN_PHONE (and within [0, end])."""
    b = np.clip(bounds, 0.0, end).copy()
    b[0], b[-1] = 0.0, end
    for k in range(1, len(b)):
        b[k] = max(b[k], b[k - 1] + MIN_PHONE)
    if b[-1] > end:
        b[-1] = end
        for k in range(len(b) - 2, -1, -1):
            b[k] = min(b[k], b[k + 1] - MIN_PHONE)
        if b[0] < 0:
            raise AlignError(f"the recording ({end:.2f} s) is too short for the {len(b) - 1} phones of the transcript")
    return b


def _mismatch_ratio(synth: NDArray[np.float64], real: NDArray[np.float64], path_cost: NDArray[np.float64]) -> float:
    """Mean distance along the warp / mean distance between unrelated frames (a fixed sample of pairs)."""
    rng = np.random.default_rng(0)
    a = synth[rng.integers(0, len(synth), 4000)]
    b = real[rng.integers(0, len(real), 4000)]
    unrelated = float(np.mean(np.linalg.norm(a - b, axis=1)))
    return float(np.mean(path_cost)) / unrelated


def pause_starts(samples: NDArray[np.float64], min_pause: float = PART_PAUSE) -> NDArray[np.int64]:
    """Frames where a pause of at least `min_pause` s starts (quiet by the threshold of `speech_span`)."""
    levels = frame_levels(samples)
    floor, peak = np.percentile(levels, [10, 95])
    quiet = levels <= max(floor + SPEECH_ABOVE_FLOOR * (peak - floor), SILENCE_DBFS - 15)
    edges = np.diff(np.concatenate([[0], quiet.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return np.asarray(starts[(ends - starts) * HOP >= min_pause], dtype=np.int64)


def _part_end(synth: NDArray[np.float64], real: NDArray[np.float64], window: NDArray[np.float64],
              step_pattern: str) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """The warp of a part that is not the last: its end is the pause of the recording (between half
    and twice the part's synthetic length) that gives the least warp distance; without such a
    pause, an open end. (A warp normalised by both lengths with an open end runs on into the next
    part's speech.)"""
    n = len(synth)
    ends = [int(e) for e in pause_starts(window) if n / 2 <= e <= 2 * n and e <= len(real)]
    best: tuple[float, tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]] | None = None
    for e in ends:
        i, j, cost, distance = _warp(synth, real[:e], open_end=False, step_pattern=step_pattern)
        if best is None or distance < best[0]:
            best = (distance, (i, j, cost))
    if best is not None:
        return best[1]
    i, j, cost, _ = _warp(synth, real, open_end=True, step_pattern=OPEN_END_PATTERN)
    return i, j, cost


def speech_span(samples: NDArray[np.float64]) -> tuple[int, int] | None:
    """First and last sample of speech (frames louder than a threshold set between the recording's
    noise floor and its speech level), with a 30 ms margin; None if there is none."""
    levels = frame_levels(samples)
    if len(levels) == 0:
        return None
    floor, peak = np.percentile(levels, [10, 95])
    loud = np.flatnonzero(levels > max(floor + SPEECH_ABOVE_FLOOR * (peak - floor), SILENCE_DBFS - 15))
    if len(loud) == 0:
        return None
    margin = int(0.03 * RATE)
    hop = int(HOP * RATE)
    return max(0, loud[0] * hop - margin), min(len(samples), loud[-1] * hop + int(WINDOW * RATE) + margin)


def align_by_synthesis(recording: Recording, text: str, lang: str, engine: str | None = None,
                       progress: Progress | None = None, step_pattern: str = STEP_PATTERN) -> Alignment:
    """Phones of `text` located in `recording` by warping a TTS's saying of it (module docstring).

    The speech of each part (from its first to its last phone that is not a pause) is warped onto
    the recording's speech: silence before the first and after the last loud frame is a pause of
    its own, not stretched onto a phone."""
    parts = split_text(text)
    if not parts:
        raise AlignError("the transcript is empty: give the words the recording says (--text or --transcript)")
    samples = recording.samples
    n_real = len(samples)
    phones: list[str] = [""]
    phonemes: list[str] = [PAUSE]
    bounds: list[float] = [0.0]  # start of each phone in the recording, s
    word_of: list[int] = [-1]
    words: list[str] = []
    ratios: list[tuple[float, float]] = []  # (ratio, weight)
    pos = 0  # sample where the next part is searched from
    part_spans: list[tuple[float, float, str]] = []
    spoken: Spoken | None = None
    for k, part in enumerate(parts):
        spoken = speak_transcript(part, lang, engine)
        last = k == len(parts) - 1
        reach = n_real if last else min(n_real, pos + int((SEARCH_FACTOR * spoken.duration + SLACK) * RATE))
        span = speech_span(samples[pos:reach])
        if span is None:
            raise AlignError(f"{recording.path}: no speech after {pos / RATE:.2f} s for the words "
                             f"{part[:60]!r}: the transcript says more than the recording")
        # the last part ends where the speech does; another part's end is left open within the window
        a, b = pos + span[0], (pos + span[1] if last else reach)
        speech = [p for p, m in enumerate(spoken.phonemes) if m != PAUSE]
        first, final = speech[0], speech[-1]
        s0, s1 = float(spoken.starts[first]), float(spoken.ends[final])
        synth_f = mfcc(spoken.samples[int(s0 * RATE):int(s1 * RATE)])
        real_f = mfcc(samples[a:b])
        if last:
            i, j, cost, _ = _warp(synth_f, real_f, open_end=False, step_pattern=step_pattern)
        else:
            i, j, cost = _part_end(synth_f, real_f, samples[a:b], step_pattern)
        ratios.append((_mismatch_ratio(synth_f, real_f, cost), float(len(cost))))
        inner = np.array([spoken.starts[p] - s0 for p in range(first + 1, final + 1)] + [s1 - s0])
        carried = _carry(inner, i, j, len(synth_f)) + a / RATE
        real = np.concatenate([[a / RATE], carried[:-1]])
        # the next part is searched from the end of this one's warp (the start of the pause it ended at),
        # not from its carried last boundary, which may fall short of the last phone's fading tail
        speech_end = b / RATE if last else a / RATE + float(j[-1] + 1) * HOP
        part_spans.append((a / RATE, speech_end, part))
        offset = len(words)
        for p in range(first, final + 1):
            phones.append(spoken.phones[p])
            phonemes.append(spoken.phonemes[p])
            bounds.append(float(real[p - first]))
            word_of.append(spoken.word_of[p] + offset if spoken.word_of[p] >= 0 else -1)
        # the silence between two parts is one pause
        phones.append("")
        phonemes.append(PAUSE)
        bounds.append(speech_end)
        word_of.append(-1)
        words.extend(spoken.words)
        pos = min(n_real - 1, max(pos + 1, int(speech_end * RATE)))
        if progress is not None:
            progress(k + 1, len(parts))
    assert spoken is not None
    end = recording.duration
    if bounds[1] <= 0.0:  # speech from the first sample: no leading pause
        del phones[0], phonemes[0], bounds[0], word_of[0]
    if bounds[-1] >= end - MIN_PHONE:  # speech to the last sample: no trailing pause
        del phones[-1], phonemes[-1], bounds[-1], word_of[-1]
    bnd = _tidy(np.array([*bounds, end]), end)
    weight = sum(w for _, w in ratios)
    ratio = sum(r * w for r, w in ratios) / weight
    method = (f"alignment by synthesis: {spoken.engine} said the transcript, its MFCCs warped onto the recording's "
              f"(DTW){'' if len(parts) == 1 else f', in {len(parts)} parts'}")
    alignment = Alignment(tuple(phones), tuple(phonemes), bnd[:-1], bnd[1:], tuple(word_of), tuple(words), end,
                          method, spoken.phone_map, confidence=ratio, parts=part_spans)
    alignment.warnings.extend(_check(alignment, recording, ratio))
    return alignment


def _check(alignment: Alignment, recording: Recording, ratio: float) -> list[str]:
    """What makes this alignment doubtful, in words (empty if nothing)."""
    out: list[str] = []
    if ratio > MISMATCH_RATIO:
        out.append(f"{recording.path}: the recording matches the transcript poorly (warp distance ratio {ratio:.2f}, "
                   f"above {MISMATCH_RATIO:g}; a transcript the recording says gives about 0.8): is it the "
                   "transcript of this recording, in this language (--lang)? The phone times are likely wrong")
    # speech after the transcript's last phone: the transcript stops early
    if alignment.phonemes[-1] == PAUSE:
        start = float(alignment.starts[-1])
        tail = speech_frames(recording.samples[int(start * RATE):])
        if tail.sum() * HOP > LEFTOVER_SPEECH + 0.25 * (alignment.duration - start):
            out.append(f"{recording.path}: {tail.sum() * HOP:.1f} s of sound after the transcript's last word "
                       f"(from {start:.2f} s to the end, {alignment.duration:.2f} s): does the transcript stop "
                       "before the recording does?")
    return out
