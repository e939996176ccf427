"""Carstens AG50x articulograph position files, `.pos`, as the systems write them.

Layout (Carstens' documentation of the AG500 and AG501 data files): little-endian 32-bit floats,
frame after frame; each frame holds every channel (sensor) in turn, each channel seven values:
x, y, z (mm), φ, θ (degrees: the sensor's orientation), the RMS error of the position solution,
and an extra value. AG501 files open with a text header,

    AG50xDATA_V002\\n
    00000070\\n                  the header's length in bytes, eight decimal digits
    NumberOfChannels=16\\n
    SamplingFrequencyHz=250\\n
    (padding up to that length)

while AG500 files have none: 12 channels at 200 Hz. The amplitude files (`.amp`, the raw
transmitter amplitudes the positions are solved from) carry the same header; a headerless `.pos`
whose sweep has an `.amp` beside it (`0001.amp` in the same folder, or in `../amps/` as Carstens'
session folders keep them) takes its channel count and rate from that header.

The files do not name their sensors: a lab keeps which channel is which in its own notes. Names
come from a sensor file beside the recording, `<stem>.sensors` or `sensors.txt` in its folder or
the session folder above it: one sensor a line, `<channel number> <name>` (or names alone, in
channel order); `#` starts a comment. Named sensors are matched to roles by the same name guessing
as the other EMA readers (`ul`, `ll`, `jaw`, `tt`, ...). Without a sensor file the channels are
`ch1` ... `chN` and a role map names the roles (`{"UL": "ch3", "LL": "ch4", "JAW": "ch7"}`).

Positions the system could not solve are written as NaN (AG501) or as an all-zero position: both
become NaN. The axes depend on how the session was head-corrected, so they are guessed from the
sensors' geometry (as for X-ray Microbeam and mview files) unless the role map gives them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coartic.io.errors import DataError
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm
from coartic.textfile import TextDecodeError, read_text

MAGIC = b"AG50xDATA_V"
FIELDS = ("x", "y", "z", "phi", "theta", "rms", "extra")
AG500_CHANNELS = 12
AG500_RATE_HZ = 200.0
FLOAT_BYTES = 4
# the longest header coartic reads: Carstens' own is 70 bytes
MAX_HEADER_BYTES = 65536
SENSOR_FILES = ("sensors.txt",)


@dataclass(frozen=True)
class PosHeader:
    version: str  # "V002"; "" for a headerless AG500 file
    size: int  # bytes before the first frame
    channels: int
    rate: float
    source: str  # what the channel count and rate were read from, for the notes


def parse_header(data: bytes, path: Path) -> PosHeader | None:
    """The AG50x text header at the start of `data`, or None when the file has none (AG500)."""
    if not data.startswith(MAGIC):
        return None
    first, _, rest = data.partition(b"\n")
    version = first[len(MAGIC) - 1:].decode("ascii", "replace")
    size_field, _, _ = rest.partition(b"\n")
    if not re.fullmatch(rb"\d{1,8}", size_field.strip()):
        raise DataError(f"Carstens header: the second line must be the header's length in bytes "
                        f"(eight digits, e.g. 00000070), found {size_field[:20]!r}", path=path, line=2)
    size = int(size_field)
    if not len(first) + len(size_field) + 2 <= size <= min(len(data), MAX_HEADER_BYTES):
        raise DataError(f"Carstens header: length {size} bytes does not fit a file of {len(data)} "
                        f"bytes whose header lines take {len(first) + len(size_field) + 2}",
                        path=path, line=2)
    fields: dict[str, str] = {}
    for no, raw in enumerate(data[:size].split(b"\n")[2:], start=3):
        line = raw.strip(b"\x00\x1a\r\t ")
        if not line:
            continue
        key, eq, value = line.decode("ascii", "replace").partition("=")
        if not eq:
            raise DataError(f"Carstens header: {line[:40]!r} is not KEY=VALUE", path=path, line=no)
        fields[key.strip()] = value.strip()
    channels = _header_number(fields, "NumberOfChannels", path)
    rate = _header_number(fields, "SamplingFrequencyHz", path)
    if channels != int(channels) or not 1 <= channels <= 1024:
        raise DataError(f"Carstens header: NumberOfChannels={fields['NumberOfChannels']} is not a "
                        "channel count (1 to 1024)", path=path, item="NumberOfChannels")
    if not 0.0 < rate <= 1e6:
        raise DataError(f"Carstens header: SamplingFrequencyHz={fields['SamplingFrequencyHz']} is "
                        "not a sampling rate (above 0, at most 1 MHz)", path=path,
                        item="SamplingFrequencyHz")
    return PosHeader(version, size, int(channels), rate, f"its {version} header")


def _header_number(fields: dict[str, str], key: str, path: Path) -> float:
    if key not in fields:
        raise DataError(f"Carstens header: no {key}= line (the header has {sorted(fields)})",
                        path=path, item=key)
    try:
        value = float(fields[key])
    except ValueError:
        raise DataError(f"Carstens header: {key}={fields[key]!r} is not a number", path=path,
                        item=key) from None
    if not np.isfinite(value):
        raise DataError(f"Carstens header: {key}={fields[key]} is not finite", path=path, item=key)
    return value


def _amp_beside(p: Path) -> Path | None:
    for amp in (p.with_suffix(".amp"), p.parent.parent / "amps" / (p.stem + ".amp")):
        if amp.is_file():
            return amp
    return None


def _layout(p: Path, data: bytes) -> tuple[PosHeader, list[str]]:
    header = parse_header(data, p)
    if header is not None:
        return header, []
    amp = _amp_beside(p)
    if amp is not None:
        with amp.open("rb") as f:
            amp_header = parse_header(f.read(MAX_HEADER_BYTES), amp)
        if amp_header is not None:
            return (PosHeader("", 0, amp_header.channels, amp_header.rate,
                              f"the header of {amp.name}"),
                    [f"no header (AG500 layout): {amp_header.channels} channels at "
                     f"{amp_header.rate:g} Hz, from the header of {amp}"])
    return (PosHeader("", 0, AG500_CHANNELS, AG500_RATE_HZ, "the AG500 layout"),
            [f"no header: read as an AG500 file ({AG500_CHANNELS} channels at {AG500_RATE_HZ:g} "
             "Hz); an AG501 file always has one"])


def sensor_names(p: Path, channels: int) -> tuple[tuple[str, ...], Path | None]:
    """The channels' names from the sensor file beside `p`, else ch1 ... chN."""
    for cand in (p.with_suffix(".sensors"), *(d / name for d in (p.parent, p.parent.parent)
                                              for name in SENSOR_FILES)):
        if cand.is_file():
            return _read_sensor_file(cand, channels), cand
    return tuple(f"ch{k}" for k in range(1, channels + 1)), None


def _read_sensor_file(path: Path, channels: int) -> tuple[str, ...]:
    try:
        text = read_text(path, "sensor names")
    except OSError as e:
        raise DataError(f"cannot read the sensor names: {e.strerror or e}", path=path) from None
    except TextDecodeError as e:
        raise DataError(e.detail, path=path) from None
    names: dict[int, str] = {}
    in_order: list[tuple[int, str]] = []
    for no, line in enumerate(text.splitlines(), start=1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) == 2 and fields[0].isdigit():
            k = int(fields[0])
            if not 1 <= k <= channels:
                raise DataError(f"channel {k} is not one of the recording's channels 1 to "
                                f"{channels}", path=path, line=no, item=fields[1])
            if k in names:
                raise DataError(f"channel {k} is named twice ({names[k]!r} and {fields[1]!r})",
                                path=path, line=no, item=fields[1])
            names[k] = fields[1]
        elif len(fields) == 1:
            in_order.append((no, fields[0]))
        else:
            raise DataError(f"{line.strip()!r}: write '<channel number> <name>' or a name alone",
                            path=path, line=no)
    if names and in_order:
        raise DataError("mixes numbered lines ('3 TT') with bare names: use one form", path=path,
                        line=in_order[0][0])
    if in_order:
        if len(in_order) > channels:
            raise DataError(f"{len(in_order)} names for {channels} channels", path=path,
                            line=in_order[channels][0])
        names = {k: name for k, (_, name) in enumerate(in_order, start=1)}
    full = tuple(names.get(k, f"ch{k}") for k in range(1, channels + 1))
    lower = [n.lower() for n in full]
    dup = next((n for n in full if lower.count(n.lower()) > 1), None)
    if dup is not None:
        raise DataError(f"sensor name {dup!r} is given to two channels", path=path, item=dup)
    return full


def read_pos(path: str | Path, units: str | None = None, allow_truncated: bool = False) -> Trial:
    """Read a Carstens AG500/AG501 `.pos` file as a Trial (kind 'ema'), positions in mm.

    `allow_truncated` reads the whole frames of a file cut short (an interrupted copy) instead of
    refusing it; the notes say how many bytes were left out."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise DataError(f"cannot read: {e.strerror or e}", path=p) from None
    header, notes = _layout(p, data)
    frame_bytes = header.channels * len(FIELDS) * FLOAT_BYTES
    body = len(data) - header.size
    n_frames, extra = divmod(body, frame_bytes)
    if extra:
        what = (f"{body} bytes of frames are not whole frames of {header.channels} channels x "
                f"{len(FIELDS)} values x {FLOAT_BYTES} bytes = {frame_bytes} bytes "
                f"({n_frames} frames and {extra} bytes; layout from {header.source})")
        if not allow_truncated:
            raise DataError(f"{what}: the file is cut short or not a Carstens position file "
                            "(`--allow-truncated` reads its whole frames)", path=p)
        notes.append(f"truncated: {extra} bytes after the last whole frame left out")
    if n_frames == 0:
        raise DataError(f"no frames (layout from {header.source})", path=p)
    values = np.frombuffer(data, dtype="<f4", count=n_frames * header.channels * len(FIELDS),
                           offset=header.size).reshape(n_frames, header.channels, len(FIELDS))
    xyz = values[:, :, :3].astype(np.float64)
    unsolved = ~np.isfinite(xyz).all(axis=2) | (xyz == 0.0).all(axis=2)
    xyz[unsolved] = np.nan
    names, names_file = sensor_names(p, header.channels)
    xyz, note = to_mm(xyz, units or "mm", p, "sensor positions", names)
    if note:
        notes.append(note)
    if names_file is not None:
        notes.append(f"sensor names from {names_file}")
    else:
        notes.append(f"the file does not name its channels: ch1 ... ch{header.channels}; write "
                     f"their names in {p.with_suffix('.sensors').name} or sensors.txt beside it "
                     "('<channel> <name>' a line), or give a role map")
    never = [names[k] for k in range(header.channels) if unsolved[:, k].all()]
    some = {names[k]: int(unsolved[:, k].sum()) for k in range(header.channels)
            if unsolved[:, k].any() and not unsolved[:, k].all()}
    if never:
        notes.append(f"channels with no position in any frame (not connected): {', '.join(never)}")
    if some:
        notes.append("positions not solved (NaN or all zero) set to NaN: "
                     + ", ".join(f"{k} {v}" for k, v in some.items()))
    meta: dict[str, object] = {"notes": notes, "carstens": {
        "version": header.version or "AG500 (no header)", "channels": header.channels,
        "layout_from": header.source}}
    if names_file is None:
        meta["roles_hint"] = (
            "Carstens .pos files do not name their channels: write the names in "
            f"{p.with_suffix('.sensors')} ('<channel number> <name>' a line, e.g. '3 UL') or give "
            'a role map naming channels, e.g. {"UL": "ch3", "LL": "ch4", "JAW": "ch7"}')
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=names, rate=header.rate,
                 units="mm", source=p, meta=meta, kind="ema")


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    if p.suffix.lower() == ".amp":
        raise DataError("a Carstens amplitude file: coartic reads the positions solved from it; "
                        f"give the .pos file of the same sweep ({p.stem}.pos, in the session's "
                        "pos/ folder)", path=p)
    return read_pos(p, units=req.units, allow_truncated=req.allow_truncated), None


def _sniff(p: Path, head: bytes) -> bool:
    return head.startswith(MAGIC)


register(Reader("carstens-pos", "Carstens AG50x .pos", (".pos", ".amp"), _read, sniff=_sniff,
                axes=None, sensors=True))
