"""Edinburgh Speech Tools (EST) track files as MOCHA-TIMIT and mngu0 distribute their EMA: a text
header, then the frames in binary or ASCII.

Header: `EST_File Track`, then `key value` lines (`DataType binary|ascii`, `ByteOrder 01`
(little-endian) or `10` (big-endian), `NumFrames`, `NumChannels`, `NumAuxChannels`,
`EqualSpace`, `BreaksPresent`, `CommentChar`, `Channel_<i> <name>`), ending with `EST_Header_End`.
Each frame is the time (s), a flag (1 = a frame, 0 = a break: no data) and the channels; binary
frames are 4-byte floats. MOCHA's channels are `<sensor>_x`, `<sensor>_y` for the sensors
ui li ul ll tt tb td v bn bt (unused slots are named `****`) in 1/100 mm: midsagittal data.
No maintained PyPI package reads EST tracks with errors naming the file and line, hence this
module.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from coartic.io.errors import DataError
from coartic.io.markers_csv import float_fields, midsagittal_note, planar_axis, rate_from_times, stack_axes
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm

MAGIC = b"EST_File Track"
END = "EST_Header_End"
# The EST header carries no unit. MOCHA-TIMIT's channels (`ul_x`) are in 1/100 mm; mngu0's
# (`T1_px`, AG500 positions with `_ph`/`_pt` angles beside them) in mm.
EST_UNIT_MM = 0.01
_CHANNEL = re.compile(r"^(?P<sensor>[A-Za-z0-9]+?)_(?P<p>p)?(?P<axis>[xyzXYZ])$")
MAX_HEADER_LINES = 10_000
FLOAT32_RATE_ERROR = 1e-6  # relative: a float32 time's rounding over a few thousand frames


def _header(raw: bytes, p: Path) -> tuple[dict[str, str], dict[int, str], int, int]:
    """(keys, channel index → name, the byte offset of the data, the line after the header)."""
    keys: dict[str, str] = {}
    channels: dict[int, str] = {}
    pos = 0
    for no in range(1, MAX_HEADER_LINES):
        nl = raw.find(b"\n", pos)
        if nl < 0:
            raise DataError(f"the header has no {END} line", path=p, line=no)
        try:
            line = raw[pos:nl].decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            raise DataError("the EST header holds non-ASCII bytes (binary data before "
                            f"{END}?)", path=p, line=no) from None
        pos = nl + 1
        if no == 1:
            if line.strip() != MAGIC.decode():
                raise DataError(f"not an EST track file: the first line is {line[:40]!r}, not "
                                f"{MAGIC.decode()!r}", path=p, line=1)
            continue
        s = line.strip()
        if s == END:
            return keys, channels, pos, no + 1
        if not s:
            continue
        key, _, value = s.partition(" ")
        m = re.fullmatch(r"Channel_(\d+)", key)
        if m:
            channels[int(m.group(1))] = value.strip()
        else:
            keys[key] = value.strip()
    raise DataError(f"no {END} line in the first {MAX_HEADER_LINES} lines", path=p)


def _plausible_times(t: np.ndarray) -> bool:
    """Frame times that can be a clock: finite, rising, within a day, in steps that vary little."""
    if t.size < 2 or not np.all(np.isfinite(t)) or np.max(np.abs(t)) > 86_400.0:
        return False
    d = np.diff(t)
    return bool(np.all(d > 0) and np.max(d) < 2.0 * np.min(d) + 1e-6)


def _int(keys: dict[str, str], key: str, p: Path, default: int | None = None) -> int:
    if key not in keys:
        if default is not None:
            return default
        raise DataError(f"the EST header has no {key} line", path=p, item=key)
    try:
        v = int(keys[key])
    except ValueError:
        raise DataError(f"{key} {keys[key]!r} is not an integer", path=p, item=key) from None
    if v < 0:
        raise DataError(f"{key} {v} is negative", path=p, item=key)
    return v


def read_est(path: str | Path, units: str | None = None) -> Trial:
    """Read an EST track of EMA sensors as a Trial (kind 'ema'), positions in mm.

    Sensor channels are `<sensor>_x/_y/_z` (MOCHA-TIMIT, 1/100 mm) or `<sensor>_px/_py/_pz`
    (mngu0, mm); other channels (angles, velum...) are ignored. Break frames and NaN samples are
    missing data. `units` overrides the unit.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise DataError(f"cannot read: {e.strerror or e}", path=p) from None
    keys, channels, offset, first_line = _header(raw, p)
    n_frames = _int(keys, "NumFrames", p)
    n_channels = _int(keys, "NumChannels", p)
    if _int(keys, "NumAuxChannels", p, default=0):
        raise DataError("auxiliary channels (NumAuxChannels > 0) are not read", path=p,
                        item="NumAuxChannels")
    for i in channels:
        if i >= n_channels:
            raise DataError(f"Channel_{i} names a channel beyond NumChannels {n_channels}",
                            path=p, item=f"Channel_{i}")
    kind = keys.get("DataType", "binary").lower()
    lines: list[int | None]
    width = 2 + n_channels  # time, break flag, channels
    if kind == "binary":
        order = keys.get("ByteOrder", "01")
        endian = {"01": "<", "10": ">", "littleendian": "<", "bigendian": ">"}.get(order.lower())
        if endian is None:
            raise DataError(f"ByteOrder {order!r}: expected 01 (little-endian) or 10 (big-endian)",
                            path=p, item="ByteOrder")
        body = raw[offset:]
        need = n_frames * width * 4
        if len(body) < need:
            raise DataError(f"truncated: NumFrames {n_frames} x ({n_channels} channels + time + "
                            f"flag) x 4 bytes = {need} bytes, the file holds {len(body)} after the "
                            "header", path=p)
        if len(body) > need:
            raise DataError(f"{len(body) - need} bytes after the {n_frames} frames the header "
                            "declares (NumFrames or NumChannels wrong?)", path=p)
        with np.errstate(invalid="ignore"):  # signalling-NaN bit patterns of a wrong byte order
            data = np.frombuffer(body, dtype=f"{endian}f4").reshape(n_frames, width).astype(np.float64)
        if not _plausible_times(data[:, 0]):
            other = "<" if endian == ">" else ">"
            with np.errstate(invalid="ignore"):
                swapped = np.frombuffer(body, dtype=f"{other}f4").reshape(n_frames, width).astype(np.float64)
            said = "little-endian" if endian == "<" else "big-endian"
            if _plausible_times(swapped[:, 0]):
                raise DataError(f"ByteOrder {order} says the frames are {said}, but their times read so are "
                                f"not a clock (first {data[0, 0]:.3g} s, then {data[1, 0]:.3g} s); read the other "
                                f"way they rise evenly from {swapped[0, 0]:.3g} s: the header's ByteOrder is "
                                f"wrong, set it to {'10' if other == '>' else '01'}", path=p, item="ByteOrder")
    elif kind == "ascii":
        data, lines = _ascii(raw[offset:], n_frames, width, p, first_line)
    else:
        raise DataError(f"DataType {kind!r}: expected binary or ascii", path=p, item="DataType")
    if n_frames < 2:
        raise DataError(f"{n_frames} frame(s): no frame rate", path=p)
    names: list[str] = []
    cols: dict[str, dict[str, int]] = {}
    mngu0 = False
    styles: dict[bool, list[str]] = {False: [], True: []}  # channels named as MOCHA (_x) and mngu0 (_px) do
    for i in sorted(channels):
        m = _CHANNEL.match(channels[i])
        if m is None:
            continue  # "****" (an unused slot), or not a position
        sensor, axis = m.group("sensor"), m.group("axis").lower()
        if sensor not in cols:
            cols[sensor] = {}
            names.append(sensor)
        if axis in cols[sensor]:
            raise DataError(f"channel {channels[i]!r} appears twice", path=p, item=channels[i])
        cols[sensor][axis] = 2 + i
        mngu0 = mngu0 or m.group("p") is not None
        styles[m.group("p") is not None].append(channels[i])
    if not names:
        raise DataError(f"no sensor channels named <sensor>_x, _y (the channels are "
                        f"{[channels[i] for i in sorted(channels)][:12]})", path=p)
    if styles[False] and styles[True] and units is None:
        # the name is the only sign of the unit (1/100 mm or mm): one odd name must not rescale the rest
        raise DataError(f"the channels mix MOCHA-TIMIT's names in 1/100 mm ({', '.join(styles[False][:4])}) and "
                        f"mngu0's in mm ({', '.join(styles[True][:4])}), so their unit cannot be told from them: "
                        "give the unit (coartic inspect --units mm, or units=... in Python), or rename the odd "
                        "channels", path=p, item=styles[True][0])
    planar = planar_axis(names, cols, p, "_")
    times = data[:, 0]
    if kind == "binary":
        lines = [None] * n_frames  # binary frames have no lines; the times name the place
    rate = rate_from_times(times, p, lines, "time")
    # binary times are 4-byte floats: 500 Hz reads as 499.99999; the rate is round to 0.001 Hz
    if abs(rate - round(rate, 3)) < FLOAT32_RATE_ERROR * rate:
        rate = round(rate, 3)
    xyz = stack_axes(data, names, cols, planar)
    breaks = data[:, 1] == 0.0
    xyz[breaks] = np.nan
    if units is None and mngu0:
        notes = ["positions read in mm (channels named <sensor>_px as mngu0 writes them)"]
    elif units is None:
        xyz = xyz * EST_UNIT_MM
        notes = ["positions read in 1/100 mm (channels named <sensor>_x as MOCHA-TIMIT writes "
                 "them) and converted to mm"]
    else:
        xyz, note = to_mm(xyz, units, p, "sensor positions", names)
        notes = [note] if note else []
    if breaks.any():
        notes.append(f"{int(breaks.sum())} break frames (no data) set to NaN")
    if planar is not None:
        notes.append(midsagittal_note(planar))
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=rate,
                 units="mm", source=p, meta={"notes": notes}, start_time=float(times[0]),
                 kind="ema", planar_axis=planar)


def _ascii(
    body: bytes, n_frames: int, width: int, p: Path, first_line: int
) -> tuple[np.ndarray, list[int | None]]:
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError as e:
        raise DataError(f"non-ASCII byte in the ASCII frames at offset {e.start}", path=p) from None
    rows = [(no, line.split()) for no, line in enumerate(text.splitlines(), start=first_line)
            if line.strip()]
    if len(rows) != n_frames:
        raise DataError(f"NumFrames says {n_frames} frames, the file holds {len(rows)}", path=p)
    out = np.empty((n_frames, width))
    for r, (no, fields) in enumerate(rows):
        if len(fields) != width:
            raise DataError(f"{len(fields)} fields where time, flag and {width - 2} channels "
                            f"make {width}", path=p, line=no)
        out[r] = float_fields(fields, p, no)
    return out, [no for no, _ in rows]


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    return read_est(p, units=req.units), None


# MOCHA's and mngu0's axes differ from lab to lab conventions: guessed from the sensors.
register(Reader("est", "MOCHA-TIMIT/mngu0 EST track", (".ema", ".est"), _read,
                sniff=lambda p, head: head.startswith(MAGIC), axes=None, sensors=True))
