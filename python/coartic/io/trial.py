"""The Trial: one recording (markers or EMA sensors) with its labels, and its channels.

`load_trial` (coartic.io.load) is the one entry point that makes one: it picks the reader from
the extension and the content, reads and maps the labels, and checks that they fit the data. The
readers build Trials, so this module sits below the reader registry and load_trial above it.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

import warnings

# Left and right markers further apart than this in a two-axis marker file show a frontal, not a
# side, view: a side view projects them onto one another, a frontal one keeps their whole distance
# (lip corners ~50 mm, ears ~140 mm). Half of it: a side view would need the head turned 30 degrees.
PLANAR_PAIR_MM = {("LC_L", "LC_R"): 25.0, ("EAR_L", "EAR_R"): 70.0}

from coartic.io.errors import DataError, DataWarning
from coartic.io.ema_geometry import ema_channels, planar_reason
from coartic.io.gaps import DEFAULT_MAX_GAP, Gap, fill_gaps, resample
from coartic.io.labelmap import LabelMap
from coartic.io.labels import Segments
from coartic.io.roles import MARKER_ROLES, RoleMap

from coartic.table import ALL_CHANNELS, PAUSE, TONGUE_CHANNELS

# The channels a marker (face) set gives; the tongue channels need EMA sensors.
MARKER_CHANNELS = ("ULO", "LLO", "ULP", "LLP", "LR", "JO", "LA")
HEAD_ROLES = ("NOSE", "EAR_L", "EAR_R")
# Markers each channel needs (MODEL.md §6): heights and protrusions are read in the head frame
# (and y_0 needs UL and LL); the distances LR, JO, LA need no head frame.
CHANNEL_ROLES: dict[str, tuple[str, ...]] = {
    "ULO": (*HEAD_ROLES, "UL", "LL"), "LLO": (*HEAD_ROLES, "UL", "LL"),
    "ULP": (*HEAD_ROLES, "UL"), "LLP": (*HEAD_ROLES, "LL"),
    "LR": ("LC_L", "LC_R"), "JO": ("NOSE", "CHIN"), "LA": ("UL", "LL"),
}
# Midsagittal (2-D) face markers: the head frame needs the ears, which lie off the midline, and
# the lip width the lateral axis; the distances JO and LA are still computed.
PLANAR_MARKER_REFUSED = ("ULO", "LLO", "ULP", "LLP", "LR")
DEFAULT_REST_FRAMES = 20
DISTANCE_CHANNELS = ("LR", "JO", "LA")  # |a - b| of two markers: no head frame, no y_0
# Beyond these a value is not a face: a unit mistake or a broken file (DataWarning). Positions: a
# capture volume is a few metres across; channels (mm): a lip opening of 1.3 m is 1300 mm.
PLAUSIBLE_POSITION_MM = 10_000.0
PLAUSIBLE_CHANNEL_MM: dict[str, float] = {
    "ULO": 100.0, "LLO": 100.0, "LA": 150.0, "LR": 150.0, "JO": 300.0, "ULP": 500.0, "LLP": 500.0,
    # a tongue sensor moves a few centimetres from its rest position
    "TTH": 100.0, "TTA": 100.0, "TBH": 100.0, "TBA": 100.0,
}


@dataclass(frozen=True)
class Channels(Mapping[str, NDArray[np.float64]]):
    """Channel name → samples (mm), with a `valid` mask per channel (False: weight 0 in fits)."""

    arrays: dict[str, NDArray[np.float64]]
    valid: dict[str, NDArray[np.bool_]]
    times: NDArray[np.float64]
    rate: float
    gaps: tuple[Gap, ...] = ()
    unavailable: dict[str, str] = field(default_factory=dict)

    def __getitem__(self, key: str) -> NDArray[np.float64]:
        if key not in self.arrays:
            why = self.unavailable.get(key)
            raise KeyError(f"channel {key!r} is not available" + (f": {why}" if why else
                           f"; the channels are {list(self.arrays)}"))
        return self.arrays[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.arrays)

    def __len__(self) -> int:
        return len(self.arrays)

    def weights(self, channel: str) -> NDArray[np.float64]:
        """1.0 where the channel was measured, 0.0 where it is missing (for the SSE weights)."""
        return self.valid[channel].astype(np.float64)


def _clip_final_pause(segments: Segments, label_map: LabelMap, end: float, data: Path | None) -> Segments:
    """The labels with a final pause that runs past the data's `end` clipped to it, and pauses
    that start after it left out, with a warning: labels made on the audio, which runs on after the
    sensors stop (MOCHA-TIMIT: `sil` 1.67-2.2 s against 1.932 s of EMA), describe no articulation
    there. A speech label past the data stays an error."""
    tol = 1e-6
    k = len(segments)
    while k > 1 and segments.starts[k - 1] >= end - tol and label_map.map_label(segments.labels[k - 1]) == PAUSE:
        k -= 1
    last = k - 1
    if k == len(segments) and not segments.ends[last] > end + tol:
        return segments
    if label_map.map_label(segments.labels[last]) != PAUSE or not segments.starts[last] < end - tol:
        return segments  # a speech label past the data: refused by the caller, naming it
    dropped = len(segments) - k
    src = f" of {data}" if data is not None else ""
    warnings.warn(f"{segments.source}: the final pause {segments.labels[last]!r} "
                  f"({segments.starts[last]:g}-{segments.ends[last]:g} s) runs past the end of the data{src} "
                  f"({end:g} s; labels made on the longer audio): clipped to {end:g} s"
                  + (f", and the {dropped} pause label(s) after the data left out" if dropped else ""),
                  DataWarning, stacklevel=3)
    return segments.clipped(end, k)


# A speech label this long, and this many times the recording's median speech label, is no phone:
# phones in connected speech last 30-300 ms and utterance-final lengthening about doubles them, so
# past half a second an automatic aligner has most likely run the last (or first) phone into the
# rest the labels do not mark. The ratio keeps slow and sustained speech, whose labels are all long,
# quiet. A warning only: the model fits what the labels say.
LONG_SEGMENT_S = 0.5
LONG_SEGMENT_RATIO = 5.0


def _warn_long_segments(raw: Segments, mapped: Segments) -> None:
    """Warn (DataWarning) of each speech label far longer than a phone lasts (``LONG_SEGMENT_S``)."""
    durations = mapped.ends - mapped.starts
    speech = np.array([lab != PAUSE for lab in mapped.labels])
    if speech.sum() < 2:
        return
    median = float(np.median(durations[speech]))
    for i in np.flatnonzero(speech & (durations > LONG_SEGMENT_S) & (durations > LONG_SEGMENT_RATIO * median)):
        where = f"{raw.source if raw.source is not None else 'labels'}" + (
            f", line {raw.lines[i]}" if raw.lines[i] is not None else "")
        warnings.warn(f"{where}: the label {raw.labels[i]!r} ({raw.starts[i]:g}-{raw.ends[i]:g} s, "
                      f"segment {i + 1}) lasts {durations[i]:.2f} s, {durations[i] / median:.0f} times the "
                      f"recording's median speech label ({1000 * median:.0f} ms): longer than a phone lasts. If "
                      f"the speaker was silent or at rest for part of it, label that part as a pause; the model "
                      f"fits it as /{mapped.labels[i]}/ throughout", DataWarning, stacklevel=3)


@dataclass(frozen=True)
class Trial:
    """One recording: positions (frames x markers x 3, mm, NaN where missing) and labels."""

    markers: NDArray[np.float64]
    marker_names: tuple[str, ...]
    rate: float
    units: str = "mm"
    segments: Segments | None = None
    source: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    start_time: float = 0.0
    kind: Literal["markers", "ema"] = "markers"
    roles: RoleMap = field(default_factory=RoleMap)
    # midsagittal (2-D) data: the index of the axis the file lacks (stored as 0), else None
    planar_axis: int | None = None

    def __post_init__(self) -> None:
        m = self.markers
        if m.ndim != 3 or m.shape[2] != 3 or m.shape[1] != len(self.marker_names):
            raise DataError(f"markers must be frames x {len(self.marker_names)} x 3, got "
                            f"{m.shape}", path=self.source)

    @property
    def n_frames(self) -> int:
        return int(self.markers.shape[0])

    @property
    def times(self) -> NDArray[np.float64]:
        return self.start_time + np.arange(self.n_frames) / self.rate

    @property
    def duration(self) -> float:
        return self.n_frames / self.rate

    @property
    def valid(self) -> NDArray[np.bool_]:
        """frames x markers: True where the marker was measured."""
        valid: NDArray[np.bool_] = np.all(np.isfinite(self.markers), axis=2)
        return valid

    def marker(self, name: str) -> NDArray[np.float64]:
        """frames x 3 of one marker, by its name in the file or by its role."""
        k = self.roles.find(name, self.marker_names, self.source)
        if k is None:
            raise DataError(f"no marker {name!r}; the markers are {list(self.marker_names)}",
                            path=self.source, item=name)
        return self.markers[:, k, :]

    def with_labels(self, segments: Segments, label_map: LabelMap | None = None) -> Trial:
        """This trial with `segments` (mapped through `label_map`), checked against the data."""
        lm = label_map if label_map is not None else LabelMap.model()
        end = self.start_time + self.duration
        tol = 1e-6
        last = len(segments) - 1
        if last >= 0 and end + tol < segments.ends[last] <= end + 1.0 / self.rate + tol \
                and segments.starts[last] < end:
            # a last label a few ms past the data (audio and sensors stop apart): clipped
            warnings.warn(f"{segments.source}: the last label {segments.labels[last]!r} ends at "
                          f"{segments.ends[last]:g} s, within one frame after the data of "
                          f"{self.source} end ({end:g} s): clipped to {end:g} s", DataWarning,
                          stacklevel=2)
            segments = segments.clipped(end)
        segments = _clip_final_pause(segments, lm, end, self.source)
        for i, (lab, s, e) in enumerate(zip(segments.labels, segments.starts, segments.ends)):
            if e > end + tol or s < self.start_time - 1.0 / self.rate - tol:
                src = f" of {self.source}" if self.source else ""
                raise DataError(f"label {lab!r} ({s:g}-{e:g} s) lies beyond the data{src} "
                                f"({self.start_time:g}-{end:g} s)", path=segments.source,
                                line=segments.lines[i], item=lab)
        mapped = lm.apply(segments)
        _warn_long_segments(segments, mapped)
        meta = dict(self.meta)
        meta["raw_labels"] = segments.labels
        meta["label_map"] = lm.source
        return replace(self, segments=mapped, meta=meta)

    def rest_frames(self, n_frames: int = DEFAULT_REST_FRAMES) -> NDArray[np.bool_]:
        """The frames that define y_0: the first half of the first pause label, else the first
        `n_frames` frames.

        Only the first half: late in an acoustic pause the lips already move towards the first
        vowel, and averaging over the whole pause shifts y_0 (by up to 0.19 mm in the synthetic
        session, by 0 with its first half)."""
        mask = np.zeros(self.n_frames, dtype=bool)
        if self.segments is not None and PAUSE in self.segments.labels:
            i = self.segments.labels.index(PAUSE)
            t = self.times
            start = self.segments.starts[i]
            midpoint = 0.5 * (start + self.segments.ends[i])
            pause: NDArray[np.bool_] = (t >= start) & (t <= midpoint)
            if pause.any():
                return pause
        mask[: max(1, n_frames)] = True
        return mask

    def fill_gaps(self, max_gap: float = DEFAULT_MAX_GAP) -> tuple[Trial, list[Gap]]:
        """This trial with gaps up to `max_gap` s interpolated, and every gap found."""
        filled, gaps = fill_gaps(self.markers, self.marker_names, self.rate, self.start_time,
                                 max_gap)
        return replace(self, markers=filled), gaps

    def resample(self, rate: float) -> Trial:
        """This trial on a new frame rate, never interpolating across a gap."""
        if rate == self.rate:
            return self
        out = resample(self.markers, self.rate, rate, self.start_time)
        meta = dict(self.meta)
        meta["notes"] = [*meta.get("notes", []), f"resampled from {self.rate:g} Hz to {rate:g} Hz"]
        return replace(self, markers=out, rate=float(rate), meta=meta)

    def channels(
        self,
        channels: Sequence[str] | None = None,
        *,
        max_gap: float = DEFAULT_MAX_GAP,
        rest_frames: int = DEFAULT_REST_FRAMES,
    ) -> Channels:
        """Articulatory channels (MODEL.md §6) with short gaps filled and long ones masked.

        `channels=None` gives every channel the data allow (the others are listed in
        `.unavailable`); naming a channel whose markers are missing is an error.
        """
        wanted = tuple(ALL_CHANNELS if channels is None else channels)
        for c in wanted:
            if c not in ALL_CHANNELS:
                raise DataError(f"unknown channel {c!r}; channels are {list(ALL_CHANNELS)}", item=c)
        filled, gaps = self.fill_gaps(max_gap)
        rest = self.rest_frames(rest_frames)
        if self.kind == "ema":
            values, why = ema_channels(filled.markers, self.marker_names, self.roles, rest,
                                       self.source, planar_axis=self.planar_axis)
        else:
            values, why = filled._marker_channels(wanted, channels is not None, rest)
        if channels is not None:
            for c in wanted:
                if c not in values:
                    raise DataError(f"channel {c} cannot be computed: {why.get(c, 'no data')}",
                                    path=self.source, item=c)
        values = {c: np.ascontiguousarray(values[c], dtype=np.float64) for c in wanted if c in values}
        valid = {c: np.isfinite(v) for c, v in values.items()}
        for c, v in values.items():
            big = np.abs(v[valid[c]]) > PLAUSIBLE_CHANNEL_MM[c]
            if big.any():
                worst = float(np.max(np.abs(v[valid[c]])))
                warnings.warn(f"{self.source}: channel {c} reaches {worst:.6g} mm (beyond "
                              f"{PLAUSIBLE_CHANNEL_MM[c]:g} mm in {int(big.sum())} frames): not a face's "
                              "motion; check the units and the role map", DataWarning, stacklevel=2)
        return Channels(values, valid, self.times, self.rate, tuple(gaps),
                        {c: w for c, w in why.items() if c in wanted})

    def _marker_channels(
        self, wanted: Sequence[str], strict: bool, rest: NDArray[np.bool_]
    ) -> tuple[dict[str, NDArray[np.float64]], dict[str, str]]:
        idx = self.roles.resolve(MARKER_ROLES, self.marker_names, self.source)
        tongue = [c for c in wanted if c in TONGUE_CHANNELS]
        if strict and tongue:
            raise DataError(f"channel {tongue[0]} cannot be computed: tongue channels come from EMA "
                            f"tongue sensors (roles TT, TB), and this file was read as face markers "
                            f"{list(self.marker_names)}", path=self.source, item=tongue[0])
        flat = planar_reason(self.planar_axis) if self.planar_axis is not None else None
        if flat is not None:
            self._refuse_frontal_plane(idx)
            three_d = [c for c in wanted if c in PLANAR_MARKER_REFUSED]
            if strict and three_d:
                raise DataError(f"channel {three_d[0]} cannot be computed: {flat}",
                                path=self.source, item=three_d[0])
        needed: set[str] = set()
        for c in wanted:
            if c in TONGUE_CHANNELS or (flat is not None and c in PLANAR_MARKER_REFUSED):
                continue
            if strict or all(idx[r] is not None for r in CHANNEL_ROLES[c]):
                needed.update(CHANNEL_ROLES[c])
        lacking = [r for r in MARKER_ROLES if r in needed and idx[r] is None]
        if lacking or not needed:
            lacking = lacking or [r for r in MARKER_ROLES if idx[r] is None]
            named = {r: self.roles.roles[r] for r in lacking if r in self.roles.roles}
            raise DataError(
                f"required marker(s) {lacking} missing" +
                (f" (role map names {named})" if named else "") +
                f"; the file has {list(self.marker_names)}; pass role_map={{'NOSE': '<name>', ...}}"
                " to say which marker is which", path=self.source, item=lacking[0])
        why: dict[str, str] = {c: "tongue channels come from EMA tongue sensors (roles TT, TB), "
                               "not from a face marker set" for c in TONGUE_CHANNELS}
        for c in MARKER_CHANNELS:
            absent = [r for r in CHANNEL_ROLES[c] if idx[r] is None]
            if absent:
                why[c] = f"no marker for role(s) {absent}"
        if flat is not None:
            values = {}
            why.update({c: flat for c in PLANAR_MARKER_REFUSED})
        elif all(idx[r] is not None for r in (*HEAD_ROLES, "UL", "LL")):
            values = self._head_frame_channels(idx, wanted, strict, rest, why)
        else:
            values = {}
        # Distances need neither the head frame nor y_0: computed from the markers themselves
        # when the core could not run (no head markers, or no frame with all of them).
        for c in DISTANCE_CHANNELS:
            if c not in values and c not in why:
                a, b = (self.markers[:, idx[r], :] for r in CHANNEL_ROLES[c] if idx[r] is not None)
                values[c] = np.linalg.norm(a - b, axis=1)
        return values, why

    def _refuse_frontal_plane(self, idx: Mapping[str, int | None]) -> None:
        """Two-axis markers are read as a side view (front-back and up). Seen from the front
        instead (x ear to ear), a left and right marker lie far apart in the plane, where a side
        view puts them on one another: refused, since every distance would be the wrong one."""
        for (left, right), limit in PLANAR_PAIR_MM.items():
            a, b = idx[left], idx[right]
            if a is None or b is None:
                continue
            apart = self.markers[:, a, :] - self.markers[:, b, :]
            d = float(np.nanmedian(np.linalg.norm(apart, axis=1))) if np.isfinite(apart).all(axis=1).any() else 0.0
            if d > limit:
                kept = " and ".join(ax for k, ax in enumerate("xyz") if k != self.planar_axis)
                raise DataError(
                    f"{left} ({self.marker_names[a]}) and {right} ({self.marker_names[b]}) are {d:.0f} mm apart "
                    f"in the file's {kept} plane: the markers were seen from the front (one axis ear to ear), "
                    f"but markers with two axes are read as a side view (front-back and up), where these two lie "
                    f"within {limit:g} mm of each other. Give the markers' three axes, or a side view",
                    path=self.source, item=left)

    def _head_frame_channels(
        self, idx: Mapping[str, int | None], wanted: Sequence[str], strict: bool,
        rest: NDArray[np.bool_], why: dict[str, str],
    ) -> dict[str, NDArray[np.float64]]:
        """Every channel the markers allow, through the Rust core (MODEL.md §6); {} when no frame
        has UL, LL and the head markers (then only the distances can be made)."""
        from coartic import _core

        f = self.n_frames
        stack = np.full((f, len(MARKER_ROLES), 3), np.nan)
        for j, r in enumerate(MARKER_ROLES):
            k = idx[r]
            if k is not None:
                stack[:, j, :] = self.markers[:, k, :]
        # The core needs y_0, i.e. a rest frame with UL, LL and the head frame; without one, ULO
        # and LLO are undefined but the other channels are not.
        lips = np.ones(f, dtype=bool)
        for j in (0, 1, 2, 3, 4):
            lips &= np.isfinite(stack[:, j]).all(axis=1)
        core_rest = rest
        if not (lips & rest).any():
            t = self.times[rest]
            reason = (f"UL, LL and the head markers are never all present in the rest frames "
                      f"({t[0]:.3f}-{t[-1]:.3f} s): y_0 is undefined")
            if strict and {"ULO", "LLO"} & set(wanted):
                raise DataError(reason + ", and so are ULO and LLO", path=self.source,
                                item="UL/LL")
            why["ULO"] = why["LLO"] = reason
            core_rest = lips
        if not core_rest.any():
            reason = "no frame has UL, LL, NOSE, EAR_L and EAR_R all present: no head frame"
            head = [c for c in ("ULO", "LLO", "ULP", "LLP") if c in wanted]
            if strict and head:
                raise DataError(f"{reason}, so {', '.join(head)} cannot be computed",
                                path=self.source, item="UL/LL")
            for c in ("ULO", "LLO", "ULP", "LLP"):
                why.setdefault(c, reason)
            return {}
        try:
            cols = np.asarray(_core.marker_channels(np.ascontiguousarray(stack), core_rest))
        except ValueError as e:
            raise DataError(f"marker geometry: {e}", path=self.source) from None
        return {c: cols[:, j] for j, c in enumerate(MARKER_CHANNELS) if c not in why}


def common_rate(trials: Sequence[Trial], rate: float | None = None) -> list[Trial]:
    """The trials on one frame rate: `rate`, or else the lowest among them (no invented samples)."""
    if not trials:
        return []
    target = rate if rate is not None else min(t.rate for t in trials)
    return [t.resample(target) for t in trials]
