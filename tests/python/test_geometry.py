"""Marker geometry from Python: the head frame and the channels of MODEL.md §6."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation  # type: ignore[import-untyped]

from coartic import _core

NAMES = ["NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN"]


def face_frames(rng: np.random.Generator, n: int) -> np.ndarray:
    """n frames of a face in its own head frame (x left, y up, z forward, mm) with moving lips."""
    base = np.array(
        [[0, 0, 100], [70, 0, 0], [-70, 0, 0], [0, -20, 95], [0, -30, 93], [25, -25, 85], [-25, -25, 85], [0, -60, 90]],
        dtype=float,
    )
    frames = np.repeat(base[None], n, axis=0)
    jaw = rng.uniform(0, 15, n)
    frames[:, 4, 1] -= jaw
    frames[:, 7, 1] -= jaw
    frames[:, 3, 1] += rng.uniform(-2, 2, n)
    frames[:, 3:5, 2] += rng.uniform(-3, 3, (n, 1))
    frames[:, 5, 0] += rng.uniform(-5, 5, n)
    return frames


def moved(frames: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each frame rigidly moved by its own random rotation and translation (head motion)."""
    rot = Rotation.from_rotvec(rng.normal(0, 0.3, (len(frames), 3)))
    shift = rng.uniform(-300, 300, (len(frames), 1, 3))
    return np.stack([rot[i].apply(frames[i]) for i in range(len(frames))]) + shift


def reference_channels(head: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """MODEL.md §6 written out on markers already in the head frame."""
    ul, ll = head[:, 3], head[:, 4]
    y0 = np.mean((ul[rest, 1] + ll[rest, 1]) / 2)
    return np.column_stack(
        [
            ul[:, 1] - y0,
            y0 - ll[:, 1],
            ul[:, 2],
            ll[:, 2],
            np.linalg.norm(head[:, 5] - head[:, 6], axis=1),
            np.linalg.norm(head[:, 0] - head[:, 7], axis=1),
            np.linalg.norm(ul - ll, axis=1),
        ]
    )


def test_names() -> None:
    assert _core.MARKER_NAMES == NAMES
    assert _core.CHANNEL_NAMES == ["ULO", "LLO", "ULP", "LLP", "LR", "JO", "LA"]


def test_channels_remove_head_motion() -> None:
    rng = np.random.default_rng(1)
    still = face_frames(rng, 50)
    rest = np.zeros(50, dtype=bool)
    rest[:10] = True
    want = reference_channels(still, rest)
    got = _core.marker_channels(moved(still, rng), rest)
    assert got.shape == (50, 7)
    np.testing.assert_allclose(got, want, atol=1e-9)
    np.testing.assert_allclose(_core.head_frame(moved(still, rng), 0, 1, 2), still, atol=1e-9)


def test_missing_markers_give_nan_only_where_needed() -> None:
    rng = np.random.default_rng(2)
    frames = moved(face_frames(rng, 6), rng)
    frames[1, 3] = np.nan  # UL
    frames[2, 0, 2] = np.nan  # NOSE z only
    frames[3, 5] = np.nan  # LC_L
    rest = np.ones(6, dtype=bool)
    got = _core.marker_channels(frames, rest)
    nan = np.isnan(got)
    assert not nan[[0, 4, 5]].any()
    assert nan[1].tolist() == [True, False, True, False, False, False, True]
    assert nan[2].tolist() == [True, True, True, True, False, True, False]
    assert nan[3].tolist() == [False, False, False, False, True, False, False]
    hf = _core.head_frame(frames, 0, 1, 2)
    assert np.isnan(hf[2]).all() and np.isnan(hf[1, 3]).all() and not np.isnan(hf[1, 4]).any()


def test_errors_name_the_argument() -> None:
    frames = face_frames(np.random.default_rng(3), 4)
    with pytest.raises(ValueError, match=r"rest selects 0 frame\(s\).*y_0"):
        _core.marker_channels(frames, np.zeros(4, dtype=bool))
    with pytest.raises(ValueError, match=r"'markers' has shape \(4, 7, 3\), expected \(\*, 8, 3\)"):
        _core.marker_channels(frames[:, :7], np.ones(4, dtype=bool))
    with pytest.raises(ValueError, match=r"'rest' has shape \(3,\), expected \(4,\)"):
        _core.marker_channels(frames, np.ones(3, dtype=bool))
    with pytest.raises(TypeError, match=r"'rest' must be a numpy.ndarray of dtype bool"):
        _core.marker_channels(frames, np.ones(4))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"ear_r = 9 is not a marker index \(there are 8 markers\)"):
        _core.head_frame(frames, 0, 1, 9)


def test_strided_markers_are_copied_not_misread() -> None:
    rng = np.random.default_rng(4)
    frames = moved(face_frames(rng, 10), rng)
    rest = np.ones(10, dtype=bool)
    want = _core.marker_channels(frames, rest)
    fortran = np.asfortranarray(frames)
    assert np.array_equal(_core.marker_channels(fortran, rest), want)
    doubled = np.repeat(frames, 2, axis=0)[::2]
    assert np.array_equal(_core.marker_channels(doubled, np.repeat(rest, 2)[::2]), want)
