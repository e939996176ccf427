"""Lengths in millimetres: what the model's targets are in (MODEL.md §1)."""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike

import numpy as np
from numpy.typing import NDArray

from coartic.io.errors import DataError

_TO_MM = {"mm": 1.0, "millimeter": 1.0, "millimetre": 1.0, "millimeters": 1.0,
          "millimetres": 1.0, "cm": 10.0, "m": 1000.0, "meter": 1000.0, "metre": 1000.0,
          "meters": 1000.0, "metres": 1000.0}


def to_mm(
    values: NDArray[np.float64], unit: str, path: str | PathLike[str] | None, what: str = "data",
    names: Sequence[str] | None = None,
) -> tuple[NDArray[np.float64], str | None]:
    """`values` in mm and a note saying what was converted (None when already in mm).

    `names` (one per marker of a frames x markers x 3 array) names the marker of an overflow."""
    key = unit.strip().lower()
    if key not in _TO_MM:
        raise DataError(f"{what} are in unit {unit!r}; coartic reads mm, cm or m only "
                        "(--units mm, units='mm' in Python, if the file's unit field is wrong)", path=path, item=unit)
    factor = _TO_MM[key]
    if factor == 1.0:
        return values, None
    with np.errstate(over="ignore"):
        out = values * factor
    # a finite value that overflows is a broken file, not a missing sample: NaN would hide it as a gap
    over = np.isinf(out) & np.isfinite(values)
    if over.any():
        k = np.unravel_index(int(np.flatnonzero(over)[0]), values.shape)
        at = (f"frame {int(k[0])}, marker {names[int(k[1])]!r}, {'xyz'[int(k[2])]}"
              if names is not None and values.ndim == 3 else f"index {tuple(int(i) for i in k)}")
        raise DataError(f"{what}: {float(values[k]):g} {unit.strip()} ({at}) overflows when "
                        f"converted to mm (x{factor:g}): not a length",
                        path=path, item=names[int(k[1])] if names is not None and values.ndim == 3 else unit)
    return out, f"{what} converted from {unit.strip()} to mm (x{factor:g})"
