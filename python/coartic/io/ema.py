"""EMA sensor tables (Carstens AG50x, NDI Wave exports): `<sensor>_posx, _posy, _posz` columns
(orientation columns `_orix..` are ignored), and the channels EMA sensors can give.

EMA positions are already head-corrected by the system (reference sensors), so there is no head
frame to build: the channels are read along the role map's vertical and anterior axes. How each
channel is made is documented in docs/DATA.md.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from os import PathLike
from pathlib import Path

import numpy as np

from coartic.io.errors import DataError
from coartic.io.markers_csv import (
    first_line,
    axis_columns,
    midsagittal_note,
    parse_numbers,
    planar_axis,
    rate_from_times,
    read_table,
    stack_axes,
    time_column,
)
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.roles import ema_sensor_names
from coartic.io.trial import Trial
from coartic.io.units import to_mm

_POS = re.compile(r"^(?P<sensor>.+)_pos(?P<axis>[xyzXYZ])$")
_PLAIN = re.compile(r"^(?P<sensor>.+)_(?P<axis>[xyzXYZ])$")
def looks_like_ema(header: Sequence[str]) -> bool:
    """`<sensor>_posx` columns, or `<name>_x` columns whose names are EMA sensors (UL, LL and a
    jaw or tongue sensor) with no face head marker (NOSE, EAR_L, EAR_R, CHIN): EMA labs write
    both, and the face-marker reading would then ask for NOSE and CHIN."""
    if any(_POS.match(h) for h in header):
        return True
    return ema_sensor_names([m.group("sensor") for h in header if (m := _PLAIN.match(h))])


def read_ema_csv(path: str | PathLike[str], units: str | None = None) -> Trial:
    """Read an EMA sensor table as a Trial (kind 'ema', no labels), positions in mm.

    Columns `<sensor>_posx, _posy, _posz` (orientation columns are ignored), or `<sensor>_x, _y,
    _z`; midsagittal tables give the same two axes for every sensor. Frames where every sensor is
    exactly 0 are 'no data' on Carstens systems and become NaN.
    """
    p = Path(path)
    header, rows, lines, file_unit = read_table(p)
    tcol, scale = time_column(header, p)
    pattern = _POS if any(_POS.match(h) for h in header) else _PLAIN
    names, cols = axis_columns(header, pattern, p, skip=tcol)
    if not names:
        raise DataError(f"no EMA sensor columns named <sensor>_posx, _posy, _posz; the columns "
                        f"are {header[:8]}...", path=p)
    sep = "_pos" if pattern is _POS else "_"
    planar = planar_axis(names, cols, p, sep)
    if not rows:
        raise DataError("a header but no data rows", path=p)
    data = parse_numbers(rows, lines, header, p)
    times = data[:, tcol] * scale
    rate = rate_from_times(times, p, lines, header[tcol])
    xyz = stack_axes(data, names, cols, planar)
    kept = [k for k in range(3) if k != planar]
    zero = np.all(xyz[:, :, kept] == 0.0, axis=(1, 2))
    xyz[zero] = np.nan
    if planar is not None:
        xyz[zero, :, planar] = np.nan
    xyz, note = to_mm(xyz, units or file_unit or "mm", p, "sensor positions", names)
    notes = [note] if note else []
    if zero.any():
        notes.append(f"{int(zero.sum())} all-zero frames (no data) set to NaN")
    if planar is not None:
        notes.append(midsagittal_note(planar))
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=rate,
                 units="mm", source=p, meta={"notes": notes}, start_time=float(times[0]),
                 kind="ema", planar_axis=planar)


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    return read_ema_csv(p, units=req.units), None


def _sniff(p: Path, head: bytes) -> bool:
    return looks_like_ema(re.split(r"[,;\t\s]+", first_line(head).strip()))


register(Reader("ema-csv", "EMA CSV/TSV", (".csv", ".tsv", ".txt"), _read, sniff=_sniff,
                axes=("+z", "-y"), sensors=True, default=False))
