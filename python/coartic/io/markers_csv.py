"""Marker tables as CSV/TSV: a time column and `<MARKER>_x, <MARKER>_y, <MARKER>_z` columns.

The delimiter is sniffed (comma, tab, semicolon or whitespace); empty cells and `nan` are missing
samples. The time column (`time_s`, `time`, `t`, or `time_ms` in milliseconds) must be evenly
spaced: the frame rate is read from it. A leading comment line `# units: cm` gives the unit
(default mm).
"""

from __future__ import annotations

import csv
import re
from collections.abc import Sequence
from os import PathLike
from pathlib import Path

import numpy as np

from coartic.io.errors import DataError
from coartic.textfile import TextDecodeError, read_text
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm

TIME_COLUMNS = {"time_s": 1.0, "time": 1.0, "t": 1.0, "times": 1.0, "time_ms": 1e-3}
_AXIS = re.compile(r"^(?P<marker>.+)_(?P<axis>[xyzXYZ])$")
_UNITS = re.compile(r"^#\s*units?\s*[:=]\s*(?P<unit>\S+)", re.IGNORECASE)
# Frame times may jitter by this fraction of a frame (rounded timestamps) before it is an error.
RATE_JITTER = 0.05


def read_table(path: Path) -> tuple[list[str], list[list[str]], list[int], str | None]:
    """Header, data rows, their line numbers and a `# units:` value, delimiter sniffed."""
    try:
        text = read_text(path, "marker table")
    except OSError as e:
        raise DataError(f"cannot read the table: {e.strerror or e}", path=path) from None
    except TextDecodeError as e:
        raise DataError(e.detail, path=path) from None
    if "\x00" in text:
        raise DataError("contains NUL bytes: not a text table", path=path)
    unit = None
    lines = text.splitlines()
    body: list[tuple[int, str]] = []
    for no, line in enumerate(lines, start=1):
        if line.startswith("#"):
            m = _UNITS.match(line)
            if m:
                unit = m.group("unit")
            continue
        if line.strip():
            body.append((no, line))
    if not body:
        raise DataError("empty table: no header line", path=path)
    first = body[0][1]
    delim: str | None
    try:
        delim = csv.Sniffer().sniff(first, delimiters=",\t;").delimiter
    except csv.Error:
        delim = None  # whitespace
    rows: list[list[str]] = []
    numbers: list[int] = []
    for no, line in body:
        if delim is None:
            fields = line.split()
        else:
            try:
                fields = next(csv.reader([line], delimiter=delim))
            except csv.Error as e:
                raise DataError(f"unreadable row: {e}", path=path, line=no) from None
        rows.append([f.strip() for f in fields])
        numbers.append(no)
    return rows[0], rows[1:], numbers[1:], unit


def float_fields(fields: Sequence[str], path: Path, line: int) -> list[float]:
    """One row of numbers (a whitespace-separated text format's frame), or a DataError naming the
    first field that is not a number, its file and line."""
    values = []
    for f in fields:
        try:
            values.append(float(f))
        except ValueError:
            raise DataError(f"{f!r} is not a number", path=path, line=line, item=f) from None
    return values


def parse_numbers(
    rows: list[list[str]], lines: list[int], header: list[str], path: Path
) -> np.ndarray:
    """The rows as a float matrix; empty cells and nan are NaN, anything else non-numeric an error."""
    if all(len(row) == len(header) for row in rows):
        # fast path: NumPy parses the whole table; the cell-by-cell loop below only runs to
        # find and name a bad cell
        cells = np.array(rows, dtype=object)
        cells[np.isin(cells, ("", "nan", "NaN", "NA", "na", "null"))] = "nan"
        try:
            fast = cells.astype(np.float64)
        except (ValueError, OverflowError):
            pass
        else:
            literal_nan = np.isin(cells, ("nan",))
            if np.all(np.isfinite(fast) | literal_nan):
                return fast
    out = np.full((len(rows), len(header)), np.nan)
    for r, (row, no) in enumerate(zip(rows, lines)):
        if len(row) != len(header):
            raise DataError(f"{len(row)} fields where the header has {len(header)}", path=path,
                            line=no)
        for c, cell in enumerate(row):
            if cell == "" or cell.lower() in ("nan", "na", "null"):
                continue
            try:
                v = float(cell)
            except ValueError:
                raise DataError(f"column {header[c]!r}: {cell!r} is not a number", path=path,
                                line=no, item=header[c]) from None
            if not np.isfinite(v):
                raise DataError(f"column {header[c]!r}: {cell!r} is not finite", path=path,
                                line=no, item=header[c])
            out[r, c] = v
    return out


def time_column(header: list[str], path: Path) -> tuple[int, float]:
    """Index of the one time column and its factor to seconds; two time columns are an error (which
    one holds the sample times cannot be guessed: `time` in ms beside `time_s`, say)."""
    found = [i for i, h in enumerate(header) if h.lower() in TIME_COLUMNS]
    if not found:
        raise DataError(f"no time column (one of {sorted(TIME_COLUMNS)}); the columns are "
                        f"{header[:12]}{'...' if len(header) > 12 else ''}", path=path, line=1)
    if len(found) > 1:
        names = [header[i] for i in found]
        raise DataError(f"{len(found)} time columns {names}: keep one (or rename the others)",
                        path=path, line=1, item=names[1])
    return found[0], TIME_COLUMNS[header[found[0]].lower()]


def rate_from_times(times: np.ndarray, path: Path, lines: Sequence[int | None], column: str) -> float:
    if times.size < 2:
        raise DataError("fewer than two frames: no frame rate", path=path)
    if not np.all(np.isfinite(times)):
        bad = int(np.flatnonzero(~np.isfinite(times))[0])
        raise DataError(f"time column {column!r} is empty", path=path, line=lines[bad], item=column)
    steps = np.diff(times)
    step = float(np.median(steps))
    if step <= 0:
        raise DataError(f"time column {column!r} does not increase", path=path, item=column)
    off = np.abs(steps - step) > RATE_JITTER * step
    if off.any():
        k = int(np.flatnonzero(off)[0])
        raise DataError(f"time column {column!r} is not evenly spaced: {times[k]:g} s to "
                        f"{times[k + 1]:g} s where the usual step is {step:g} s (missing frames "
                        "should be rows with empty cells)", path=path, line=lines[k + 1], item=column)
    # Timestamps written with few decimals give rates like 199.99999999; the true rate is round.
    rate = 1.0 / float((times[-1] - times[0]) / (times.size - 1))
    return round(rate, 6) if abs(rate - round(rate, 6)) < 1e-6 * rate else rate


def read_markers_csv(path: str | PathLike[str], units: str | None = None) -> Trial:
    """Read a marker table as a Trial (no labels), positions in mm."""
    p = Path(path)
    header, rows, lines, file_unit = read_table(p)
    tcol, scale = time_column(header, p)
    names, cols = axis_columns(header, _AXIS, p, skip=tcol)
    if not names:
        raise DataError(f"no marker columns named <MARKER>_x, _y, _z; the columns are {header}",
                        path=p)
    planar = planar_axis(names, cols, p, "_")
    if not rows:
        raise DataError("a header but no data rows", path=p)
    data = parse_numbers(rows, lines, header, p)
    times = data[:, tcol] * scale
    rate = rate_from_times(times, p, lines, header[tcol])
    xyz = stack_axes(data, names, cols, planar)
    unit = units or file_unit or "mm"
    xyz, note = to_mm(xyz, unit, p, "marker positions", names)
    meta = {"notes": [note] if note else []}
    if planar is not None:
        meta["notes"].append(midsagittal_note(planar))
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=rate,
                 units="mm", source=p, meta=meta, start_time=float(times[0]), planar_axis=planar)


def axis_columns(
    header: list[str], pattern: re.Pattern[str], p: Path, skip: int | None = None
) -> tuple[list[str], dict[str, dict[str, int]]]:
    """The markers (in column order) and, for each, its axis → column index, from the columns
    `pattern` matches (groups `marker` or `sensor`, and `axis`); a column given twice is an error."""
    names: list[str] = []
    cols: dict[str, dict[str, int]] = {}
    for i, h in enumerate(header):
        m = pattern.match(h)
        if i == skip or m is None:
            continue
        groups = m.groupdict()
        marker, axis = groups.get("marker") or groups["sensor"], m.group("axis").lower()
        if marker not in cols:
            cols[marker] = {}
            names.append(marker)
        if axis in cols[marker]:
            raise DataError(f"column {h!r} appears twice", path=p, item=h)
        cols[marker][axis] = i
    return names, cols


def planar_axis(names: list[str], cols: dict[str, dict[str, int]], p: Path, sep: str) -> int | None:
    """None when every marker has x, y and z; the missing axis when every marker has the same two
    (midsagittal data); else a DataError naming the marker that lacks a column."""
    if all(len(cols[n]) == 3 for n in names):
        return None
    have = {frozenset(cols[n]) for n in names}
    if len(have) == 1 and len(next(iter(have))) == 2:
        return next(k for k, a in enumerate("xyz") if a not in cols[names[0]])
    for n in names:
        lacking = [a for a in "xyz" if a not in cols[n]]
        if lacking:
            raise DataError(f"marker {n!r} has no column " + ", ".join(f"{n}{sep}{a}" for a in lacking)
                            + " (midsagittal data gives the same two axes for every marker)",
                            path=p, item=n)
    raise AssertionError("unreachable")


def stack_axes(data: np.ndarray, names: list[str], cols: dict[str, dict[str, int]],
               planar: int | None) -> np.ndarray:
    """frames x markers x 3 from the table's columns; the missing axis of midsagittal data is 0."""
    xyz = np.zeros((data.shape[0], len(names), 3))
    for j, n in enumerate(names):
        for k, a in enumerate("xyz"):
            if k != planar:
                xyz[:, j, k] = data[:, cols[n][a]]
    return xyz


def midsagittal_note(planar: int) -> str:
    kept = " and ".join(a for k, a in enumerate("xyz") if k != planar)
    return (f"midsagittal data ({kept} only): channels that need the lateral axis are not "
            "computed")


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    return read_markers_csv(p, units=req.units), None


def first_line(head: bytes) -> str:
    lines = head.decode("utf-8", errors="replace").lstrip("\ufeff").splitlines()
    return next((line for line in lines if line.strip() and not line.startswith("#")), "")


register(Reader("markers-csv", "marker CSV/TSV", (".csv", ".tsv", ".txt"), _read,
                sniff=lambda p, head: "_x" in first_line(head).lower(), priority=90))
