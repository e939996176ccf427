"""Missing samples: find the gaps, fill the short ones, leave the long ones NaN and say so.

A gap is a run of frames in which a marker is missing (any coordinate NaN). Its length is the
number of missing frames / rate. Gaps up to `max_gap` seconds that have valid samples on both
sides are filled by a cubic spline through the marker's valid samples (scipy CubicSpline); longer
gaps and gaps at the start or end of a recording are left NaN and reported, so that fits give those
samples weight 0. Resampling never bridges a gap that was left open.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from coartic.io.errors import DataError

DEFAULT_MAX_GAP = 0.050  # s: a blink-length occlusion; longer and the lips may have moved a lot


@dataclass(frozen=True)
class Gap:
    """One run of missing samples of one marker (times of the first and last missing frame)."""

    marker: str
    start: float
    end: float
    frames: int
    filled: bool
    reason: str  # "filled", "too long", "at the start", "at the end", "no valid samples"

    def __str__(self) -> str:
        state = "filled" if self.filled else f"left missing ({self.reason})"
        return (f"{self.marker}: {self.start:.3f}-{self.end:.3f} s ({self.frames} frames) {state}")


def runs(missing: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of a 1-D mask."""
    m = np.concatenate(([False], np.asarray(missing, dtype=bool), [False]))
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def fill_gaps(
    markers: NDArray[np.float64],
    names: Sequence[str],
    rate: float,
    start_time: float = 0.0,
    max_gap: float = DEFAULT_MAX_GAP,
) -> tuple[NDArray[np.float64], list[Gap]]:
    """Markers (F, M, 3) with the short gaps filled, and every gap found."""
    if not max_gap >= 0:
        raise DataError(f"max_gap must be a duration >= 0 s, got {max_gap}", item="max_gap")
    out = np.array(markers, dtype=np.float64, copy=True)
    n = out.shape[0]
    gaps: list[Gap] = []
    frame_index = np.arange(n, dtype=np.float64)
    for j, name in enumerate(names):
        missing = ~np.all(np.isfinite(out[:, j, :]), axis=1)
        if not missing.any():
            continue
        out[missing, j, :] = np.nan  # a half-missing marker is a missing marker
        valid = ~missing
        spline: CubicSpline | None = None
        if valid.sum() >= 2:
            spline = CubicSpline(frame_index[valid], out[valid, j, :], axis=0)
        for a, b in runs(missing):
            length = (b - a) / rate
            if a == 0 and b == n:
                reason = "no valid samples"
            elif a == 0:
                reason = "at the start"
            elif b == n:
                reason = "at the end"
            elif length > max_gap + 1e-9:
                reason = "too long"
            else:
                reason = "filled"
            filled = reason == "filled" and spline is not None
            if filled:
                assert spline is not None
                out[a:b, j, :] = spline(frame_index[a:b])
            gaps.append(Gap(name, start_time + a / rate, start_time + (b - 1) / rate, b - a,
                            filled, reason))
    return out, gaps


def resample(
    markers: NDArray[np.float64], rate: float, new_rate: float, start_time: float = 0.0
) -> NDArray[np.float64]:
    """Markers (F, M, 3) on the grid start_time + k / new_rate, piece by piece over the runs of
    valid samples: a cubic spline within each run (after an anti-alias low-pass when the rate goes
    down), NaN wherever the new grid falls in or beyond a gap.
    """
    if not (rate > 0 and new_rate > 0):
        raise DataError(f"rates must be positive, got {rate} and {new_rate}")
    n = markers.shape[0]
    duration = (n - 1) / rate
    n_new = int(np.floor(duration * new_rate + 1e-9)) + 1
    t_old = np.arange(n) / rate
    t_new = np.arange(n_new) / new_rate
    out = np.full((n_new, *markers.shape[1:]), np.nan)
    # imported here, not with the module: every reader of recordings imports this one, and scipy.signal
    # (with scipy.stats) costs a fresh process about 0.5 CPU-s where nothing is resampled
    from scipy.signal import butter, sosfiltfilt

    sos = butter(4, 0.8 * (new_rate / 2) / (rate / 2), output="sos") if new_rate < rate else None
    for j in range(markers.shape[1]):
        ok = np.all(np.isfinite(markers[:, j, :]), axis=1)
        for a, b in runs(ok):
            seg = markers[a:b, j, :]
            if sos is not None and b - a > 27:  # sosfiltfilt needs a few filter lengths of data
                seg = sosfiltfilt(sos, seg, axis=0)
            inside = (t_new >= t_old[a] - 1e-9) & (t_new <= t_old[b - 1] + 1e-9)
            if not inside.any():
                continue
            if b - a == 1:
                out[inside, j, :] = seg[0]
            else:
                out[inside, j, :] = CubicSpline(t_old[a:b], seg, axis=0)(t_new[inside])
    return out
