"""C3D marker files (ELITE/BTS, Vicon, Optotrak, Qualisys) through ezc3d, or the pure-Python `c3d`
package when ezc3d is missing or fails.

Occluded samples (a negative residual, which is how C3D flags them) become NaN. ezc3d reads a
truncated file without complaint and returns fewer frames, so the frame count is checked against
POINT:FRAMES / the header.

ezc3d trusts the parameter section: one corrupted byte (a parameter's number of dimensions set to
255) makes it read far past its buffers and crash the interpreter. So the section is walked here
first, with bounds checked, and anything ezc3d could not read safely is a DataError.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import warnings
from os import PathLike
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from coartic.io.errors import DataError
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm

Backend = Literal["auto", "ezc3d", "c3d"]

BLOCK = 512  # C3D is organised in 512-byte blocks
MAX_PARAM_DIMS = 7  # the C3D format allows at most 7 dimensions per parameter
_ELEMENT_BYTES = {-1: 1, 1: 1, 2: 2, 4: 4}  # parameter data types: char, byte, int16, float
_PROCESSORS = {84: "<", 85: "<", 86: ">"}  # Intel, DEC (little-endian integers), MIPS


def read_c3d(
    path: str | PathLike[str], backend: Backend = "auto", units: str | None = None,
    allow_truncated: bool = False,
) -> Trial:
    """Read the POINT data of a C3D file as a Trial (no labels) in mm.

    `units` overrides POINT:UNITS when the file's own field is wrong or empty. A file that holds
    fewer frames than its header declares is an error unless `allow_truncated`, which reads the
    frames that are there and says so in `meta["notes"]`.
    """
    p = Path(path)
    if not p.is_file():
        raise DataError("no such C3D file", path=p)
    with p.open("rb") as f:
        # the header and the largest parameter section there can be (255 blocks after block 255)
        head = f.read(2 * 256 * BLOCK)
    # Byte 2 of every C3D header is 0x50; checking it first keeps non-C3D files (and most
    # garbage) away from the C++ parser.
    if len(head) < 2 or head[1] != 0x50:
        raise DataError("not a C3D file (byte 2 of the header is not 0x50)", path=p)
    check_parameter_section(p, head)
    use_ezc3d = backend in ("auto", "ezc3d")
    if use_ezc3d:
        try:
            import ezc3d  # noqa: F401
        except ImportError:
            if backend == "ezc3d":
                raise DataError("ezc3d is not installed (pip install ezc3d)", path=p) from None
            use_ezc3d = False
    trial = _read_ezc3d(p, units) if use_ezc3d else _read_pyc3d(p, units)
    declared = _declared_frames(p)
    if declared is not None and trial.n_frames < declared:
        # A writer pads the last block with zero bytes; in a truncated file the readers take the
        # whole frames of padding as frames at (0, 0, 0) with residual 0, i.e. valid.
        held = _frames_before_padding(p)
        padding = 0
        if held is not None and held < trial.n_frames:
            if held == 0:
                raise DataError("no frames of POINT data (only the zero bytes that pad the last "
                                "block)", path=p)
            padding = trial.n_frames - held
            trial = dataclasses.replace(trial, markers=trial.markers[:held].copy())
        msg = (f"truncated C3D: the header declares {declared} frames of POINT data, the file "
               f"holds {trial.n_frames}")
        if not allow_truncated:
            raise DataError(msg + "; --allow-truncated (allow_truncated=True in Python) reads those", path=p)
        trial.meta["notes"].append(msg + "; read those" + (
            f" ({padding} all-zero frames of block padding after them left out)" if padding else ""))
    return trial


def check_parameter_section(p: Path, raw: bytes) -> None:
    """Walk the parameter section in `raw` (the file's first bytes) as a C3D reader does, and
    raise a DataError naming the group:parameter whose entry cannot be read within bounds."""
    first = raw[0]
    if first < 2:
        raise DataError(f"header: the parameter section starts at block {first} (must be 2 or later)",
                        path=p, item="header")
    start = (first - 1) * BLOCK
    if len(raw) < start + 4:
        raise DataError("the file ends before its parameter section", path=p)
    n_blocks, processor = raw[start + 2], raw[start + 3]
    if processor not in _PROCESSORS:
        raise DataError(f"parameter section: processor type {processor} is none of 84 (Intel), 85 "
                        "(DEC), 86 (MIPS)", path=p)
    end = start + BLOCK * n_blocks
    if n_blocks == 0 or end > len(raw):
        raise DataError(f"parameter section: {n_blocks} blocks from block {first} run past the end "
                        "of the file", path=p)
    order = _PROCESSORS[processor]
    groups: dict[int, str] = {}
    pos = start + 4
    while pos + 2 <= end:
        n_chars, gid = struct.unpack("bb", raw[pos:pos + 2])
        if n_chars == 0 or gid == 0:
            break  # the end of the parameter list
        name_end = pos + 2 + abs(n_chars)
        if name_end + 2 > end:
            raise DataError(f"parameter section: the entry at byte {pos} runs past the section",
                            path=p)
        name = raw[pos + 2:name_end].decode("latin-1")
        what = (f"parameter {groups.get(gid, f'group {gid}')}:{name}" if gid > 0 else f"group {name}")
        if not name.isprintable():
            raise DataError(f"parameter section: the name of the entry at byte {pos} is not text "
                            f"({name!r})", path=p)
        (offset,) = struct.unpack(order + "h", raw[name_end:name_end + 2])
        nxt = end if offset == 0 else name_end + offset
        if offset != 0 and not name_end + 2 <= nxt <= end:
            raise DataError(f"{what}: its offset to the next entry ({offset}) points outside the "
                            "parameter section", path=p, item=name)
        if gid < 0:
            groups[-gid] = name
        else:
            q = name_end + 2
            if q + 2 > nxt:
                raise DataError(f"{what}: the entry ends before its data type", path=p, item=name)
            (dtype,) = struct.unpack("b", raw[q:q + 1])
            n_dims = raw[q + 1]
            if dtype not in _ELEMENT_BYTES:
                raise DataError(f"{what}: data type {dtype} is none of -1 (char), 1 (byte), 2 "
                                "(int16), 4 (float)", path=p, item=name)
            if n_dims > MAX_PARAM_DIMS:
                raise DataError(f"{what}: {n_dims} dimensions (C3D allows at most "
                                f"{MAX_PARAM_DIMS}): a corrupt parameter section", path=p, item=name)
            dims = list(raw[q + 2:q + 2 + n_dims])
            size = math.prod(dims) * _ELEMENT_BYTES[dtype]
            if q + 2 + n_dims + size > nxt:
                raise DataError(f"{what}: dimensions {dims} of {_ELEMENT_BYTES[dtype]}-byte values "
                                f"need {size} bytes, more than its entry holds: a corrupt parameter "
                                "section", path=p, item=name)
        if offset == 0:
            break
        pos = nxt


def _frames_before_padding(p: Path) -> int | None:
    """Whole frames of a truncated file that end before its trailing zero bytes (the padding of
    the last block); None when the layout cannot be read."""
    try:
        import c3d

        with p.open("rb") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = c3d.Reader(f)
            data_start = (int(r.header.data_block) - 1) * BLOCK
            size = 4 if float(r.point_scale) < 0 else 2
            frame_bytes = size * (4 * int(r.point_used)
                                  + int(r.analog_used) * int(r.header.analog_per_frame))
    except Exception:  # an unreadable header was already reported by the reader that succeeded
        return None
    if frame_bytes <= 0:
        return None
    last = _last_nonzero_byte(p)
    if last < data_start:
        return 0
    return -(-(last + 1 - data_start) // frame_bytes)  # frames that hold a non-zero byte


def _last_nonzero_byte(p: Path) -> int:
    """Offset of the file's last non-zero byte (-1 if none), reading backwards in blocks."""
    with p.open("rb") as f:
        pos = f.seek(0, 2)
        while pos > 0:
            step = min(pos, 64 * BLOCK)
            pos -= step
            f.seek(pos)
            chunk = f.read(step).rstrip(b"\0")
            if chunk:
                return pos + len(chunk) - 1
    return -1


def _finish(
    p: Path, xyz: NDArray[np.float64], names: list[str], rate: float, unit: str,
    units: str | None, backend: str, first_frame: int,
) -> Trial:
    if not np.isfinite(rate) or rate <= 0:
        raise DataError(f"POINT:RATE is {rate!r}, not a positive frame rate", path=p, item="POINT:RATE")
    if xyz.shape[0] == 0:
        raise DataError("no frames of POINT data", path=p)
    if len(names) != xyz.shape[1]:
        raise DataError(f"POINT:LABELS has {len(names)} names for {xyz.shape[1]} markers", path=p,
                        item="POINT:LABELS")
    notes: list[str] = []
    unnamed = [i for i, n in enumerate(names) if not n]
    if unnamed:
        # some systems leave markers unlabelled; a stable name keeps them addressable
        names = [n or f"Marker_{i + 1}" for i, n in enumerate(names)]
        notes.append(f"{len(unnamed)} unlabelled marker(s) named Marker_<index>")
    seen: dict[str, int] = {}
    for i, n in enumerate(names):
        if n in seen:
            raise DataError(f"marker name {n!r} appears twice in POINT:LABELS (markers "
                            f"{seen[n] + 1} and {i + 1})", path=p, item=n)
        seen[n] = i
    given = units if units is not None else unit
    if not given.strip():
        raise DataError("POINT:UNITS is empty; say what they are with --units mm (or cm, m; units='mm' in Python)",
                        path=p, item="POINT:UNITS")
    xyz, note = to_mm(xyz, given, p, "marker positions", names)
    if note:
        notes.append(note)
    meta: dict[str, Any] = {"backend": backend, "first_frame": first_frame, "notes": notes}
    return Trial(markers=np.ascontiguousarray(xyz, dtype=np.float64), marker_names=tuple(names),
                 rate=float(rate), units="mm", source=p, meta=meta, start_time=0.0)


def _point_units(value: Any) -> str:
    # POINT:UNITS is one string, but some writers (e.g. Optotrak) repeat it once per marker.
    items = [str(v).strip() for v in (value if isinstance(value, (list, tuple)) else [value])]
    items = [v for v in items if v]
    if not items:
        return ""
    if len(set(items)) > 1:
        return "mixed: " + ", ".join(sorted(set(items)))
    return items[0]


def _read_ezc3d(p: Path, units: str | None) -> Trial:
    import ezc3d

    try:
        c = ezc3d.c3d(str(p))
    except Exception as e:  # ezc3d raises RuntimeError/OSError/IndexError on corrupt files
        raise DataError(f"corrupt or truncated C3D ({e})", path=p) from None
    try:
        point = c["parameters"]["POINT"]
        pts = np.asarray(c["data"]["points"], dtype=np.float64)  # (4, M, F)
        meta_points = c["data"]["meta_points"] if "meta_points" in c["data"] else {}
        resid = np.asarray(meta_points.get("residuals", np.zeros((1, 0, 0))),
                           dtype=np.float64)  # (1, M, F); ezc3d already NaNs most invalid samples
        labels = [str(s).strip() for s in point["LABELS"]["value"]]
        rate = float(np.asarray(point["RATE"]["value"]).ravel()[0])
        unit = _point_units(point["UNITS"]["value"]) if "UNITS" in point else "mm"
        first = int(c["header"]["points"]["first_frame"])
        scale = float(np.asarray(point["SCALE"]["value"]).ravel()[0]) if "SCALE" in point else -1.0
    except (KeyError, IndexError, TypeError, ValueError) as e:
        raise DataError(f"C3D without usable POINT parameters ({type(e).__name__}: {e})",
                        path=p) from None
    _check_scale(scale, p)
    if pts.ndim != 3 or pts.shape[0] < 3:
        raise DataError(f"C3D POINT data of unexpected shape {pts.shape}", path=p)
    labels = labels[: pts.shape[1]]
    xyz = np.transpose(pts[:3], (2, 1, 0)).copy()  # (F, M, 3)
    if resid.ndim == 3 and resid.shape[1:] == pts.shape[1:]:
        invalid = np.transpose(resid[0], (1, 0)) < 0
    else:
        invalid = np.zeros(xyz.shape[:2], dtype=bool)
    xyz[invalid] = np.nan
    return _finish(p, xyz, labels, rate, unit, units, "ezc3d", first)


def _read_pyc3d(p: Path, units: str | None) -> Trial:
    try:
        import c3d
    except ImportError:
        raise DataError("neither ezc3d nor the c3d package is installed", path=p) from None
    try:
        with p.open("rb") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the EOF warning; the frame count is checked after
            r = c3d.Reader(f)
            labels = [str(s).strip() for s in r.point_labels]
            rate = float(r.point_rate)
            upar = r.get("POINT:UNITS")
            unit = _point_units(list(upar.string_array)) if upar is not None else "mm"
            first = int(r.first_frame)
            scale = float(r.point_scale)
            frames = [np.array(pts, dtype=np.float64) for _, pts, _ in r.read_frames()]
    except Exception as e:  # the c3d package raises many kinds on corrupt input
        raise DataError(f"corrupt or truncated C3D ({type(e).__name__}: {e})", path=p) from None
    _check_scale(scale, p)
    if not frames:
        raise DataError("no frames of POINT data", path=p)
    arr = np.stack(frames)  # (F, M, 5): x y z residual cameras
    xyz = arr[:, :, :3].copy()
    xyz[arr[:, :, 3] < 0] = np.nan
    return _finish(p, xyz, labels[: xyz.shape[1]], rate, unit, units, "c3d", first)


def _check_scale(scale: float, p: Path) -> None:
    """POINT:SCALE multiplies integer positions (its sign says integer or float data): 0 would read
    every marker at the origin, which then fails far from the cause."""
    if scale == 0.0 or not math.isfinite(scale):
        raise DataError(f"POINT:SCALE is {0.0 if scale == 0 else scale:g}: every position would read as that times its "
                        "stored value; "
                        "C3D needs a non-zero scale (negative for float data, e.g. -1; the length of one integer "
                        "unit otherwise): fix POINT:SCALE in the file (e.g. with ezc3d)", path=p, item="POINT:SCALE")


def _declared_frames(p: Path) -> int | None:
    """Frames the file says it holds: POINT:FRAMES, or the header's first..last frame when that
    16-bit field has wrapped. ezc3d rewrites both to what it read, so the header is read with the
    `c3d` package; None when it cannot tell.
    """
    try:
        import c3d

        with p.open("rb") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = c3d.Reader(f)
            par = r.get("POINT:FRAMES")
            n = int(par.int16_value) if par is not None else 0
            if n <= 0:
                n = int(r.last_frame) - int(r.first_frame) + 1
    except Exception:  # an unreadable header was already reported by the reader that succeeded
        return None
    return n if n > 0 else None


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    return read_c3d(p, units=req.units, allow_truncated=req.allow_truncated), None


# Byte 2 of every C3D header is 0x50: how a C3D file without its extension is recognised.
register(Reader("c3d", "C3D", (".c3d",), _read,
                sniff=lambda p, head: len(head) >= 2 and head[1] == 0x50
                and p.suffix.lower() not in (".csv", ".tsv", ".txt")))
