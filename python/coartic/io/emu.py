"""EMU-webApp / emuR bundles (`<bundle>_bndl.json`): EMA sensor tracks in SSFF and the annotation.

A bundle holds base64 SSFF files (one per sensor: `<s>_posx, _posy, _posz`, orientation columns)
and an annotation whose SEGMENT levels carry the phone labels. An emuDB on disk keeps the same
bundle as a directory `<bundle>_bndl/`: the annotation `<bundle>_annot.json` and one SSFF file per
track, `<bundle>.<extension>`; reading the `_annot.json` reads the sensor tracks beside it. SSFF is the EMU/ASSP binary track
format: a text header (`Record_Freq`, `Start_Time`, `Column <name> <TYPE> <count>` lines, ended by
a line of dashes) and then the records, little-endian on IBM-PC machines. No maintained PyPI
package reads it, so the few lines below do.
"""

from __future__ import annotations

import base64
import binascii
import json
import re
from os import PathLike
from glob import escape as glob_escape
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.io.errors import DataError
from coartic.io.labels import Segments
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm
from coartic.textfile import TextDecodeError, read_text

_SSFF_TYPES = {"DOUBLE": "f8", "FLOAT": "f4", "LONG": "i4", "SHORT": "i2", "BYTE": "u1",
               "CHAR": "S1"}
_END = b"-----------------\n"
_POS = re.compile(r"^(?P<sensor>.+)_pos(?P<axis>[xyz])$")


def parse_ssff(data: bytes, where: str) -> tuple[dict[str, NDArray[Any]], float, float]:
    """Columns (name → records x count array), record rate and start time of one SSFF track."""
    end = data.find(_END)
    if not data.startswith(b"SSFF") or end < 0:
        raise DataError(f"{where}: not an SSFF track (no 'SSFF' header ended by dashes)")
    try:
        header = data[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise DataError(f"{where}: SSFF header is not ASCII text") from None
    order, rate, start = "<", None, 0.0
    columns: list[tuple[str, str, int]] = []
    for no, line in enumerate(header[1:], start=2):
        f = line.split()
        if not f:
            continue
        try:
            if f[0] == "Machine":
                order = "<" if len(f) > 1 and f[1] in ("IBM-PC", "PC") else ">"
            elif f[0] == "Record_Freq":
                rate = float(f[1])
            elif f[0] == "Start_Time":
                start = float(f[1])
            elif f[0] == "Column":
                name, typ, count = f[1], f[2], int(f[3])
                if typ not in _SSFF_TYPES or not 0 < count < 10_000:
                    raise ValueError(f"column type {typ} x {count}")
                columns.append((name, typ, count))
        except (IndexError, ValueError) as e:
            raise DataError(f"{where}: SSFF header line {no} {line!r} is malformed ({e})") from None
    if rate is None or not np.isfinite(rate) or rate <= 0:
        raise DataError(f"{where}: SSFF header has no positive Record_Freq")
    if not np.isfinite(start):
        raise DataError(f"{where}: SSFF Start_Time is not finite")
    if not columns:
        raise DataError(f"{where}: SSFF header declares no Column")
    dtype = np.dtype([(n, order + _SSFF_TYPES[t], (c,)) for n, t, c in columns])
    body = data[end + len(_END):]
    if len(body) % dtype.itemsize:
        raise DataError(f"{where}: SSFF data of {len(body)} bytes is not a whole number of "
                        f"{dtype.itemsize}-byte records (truncated?)")
    records = np.frombuffer(body, dtype=dtype)
    return {n: np.asarray(records[n]) for n, _, _ in columns}, float(rate), float(start)


def read_emu_bundle(
    path: str | PathLike[str], level: str | None = None, units: str | None = None
) -> tuple[Trial, Segments | None]:
    """The bundle's EMA sensors as a Trial (kind 'ema'), and the raw labels of a SEGMENT level.

    `level` names the annotation level (default: `Segment`, else the first SEGMENT level). The
    labels are not yet mapped: `load_trial` maps them through the label map.
    """
    p = Path(path)
    try:
        bundle = json.loads(read_text(p, "bundle"))
    except OSError as e:
        raise DataError(f"cannot read the bundle: {e.strerror or e}", path=p) from None
    except TextDecodeError as e:
        raise DataError(e.detail, path=p) from None
    except json.JSONDecodeError as e:
        raise DataError(f"not valid JSON: {e.msg}", path=p, line=e.lineno) from None
    except RecursionError:
        raise DataError("JSON nested too deeply to be an EMU bundle", path=p) from None
    except ValueError as e:  # e.g. an integer of more than 4300 digits
        raise DataError(f"not a usable JSON document: {e}", path=p) from None
    if isinstance(bundle, dict) and "ssffFiles" not in bundle and isinstance(bundle.get("levels"), list):
        # an emuDB bundle directory's annotation: its tracks are the SSFF files beside it
        trial = _sensor_trial(_track_files(p, bundle), p, units, "the bundle directory")
        return trial, _segments(bundle, level, p)
    if not isinstance(bundle, dict) or not isinstance(bundle.get("ssffFiles"), list):
        raise DataError("not an EMU bundle (no 'ssffFiles' list, nor an emuDB annotation's "
                        "'levels')", path=p)
    tracks: list[tuple[str, bytes]] = []
    for k, f in enumerate(bundle["ssffFiles"]):
        if not isinstance(f, dict) or not isinstance(f.get("data"), str):
            raise DataError(f"ssffFiles[{k}] has no base64 'data'", path=p)
        ext = str(f.get("fileExtension", k))
        try:
            tracks.append((ext, base64.b64decode(f["data"], validate=True)))
        except (binascii.Error, ValueError):
            raise DataError(f"track {ext!r}: data is not valid base64", path=p, item=ext) from None
    return _sensor_trial(tracks, p, units, "the bundle"), _segments(bundle.get("annotation"), level, p)


def _track_files(p: Path, annotation: dict[str, Any]) -> list[tuple[str, bytes]]:
    """The SSFF tracks `<bundle>.<ext>` beside an emuDB `<bundle>_annot.json` (other files, the
    audio and label files, skipped)."""
    stem = p.name.removesuffix("_annot.json") if p.name.endswith("_annot.json") else str(
        annotation.get("name") or p.stem)
    if not stem or "/" in stem or "\\" in stem:
        raise DataError(f"an emuDB annotation whose bundle name {stem!r} is not a file name", path=p)
    tracks: list[tuple[str, bytes]] = []
    for f in sorted(p.parent.glob(f"{glob_escape(stem)}.*")):
        if not f.is_file():
            continue
        try:
            with f.open("rb") as fh:
                if fh.read(4) != b"SSFF":
                    continue
            tracks.append((f.suffix[1:], f.read_bytes()))
        except OSError as e:
            raise DataError(f"cannot read the track: {e.strerror or e}", path=f) from None
    if not tracks:
        raise DataError(f"an emuDB annotation, but no SSFF track {stem}.<ext> beside it in "
                        f"{p.parent}", path=p)
    return tracks


def _sensor_trial(tracks: list[tuple[str, bytes]], p: Path, units: str | None, what: str) -> Trial:
    """The sensors of the tracks with `<s>_posx/_posy/_posz` columns, as one Trial."""
    sensors: dict[str, dict[str, NDArray[Any]]] = {}
    rate = start = None
    n_records = None
    for ext, raw in tracks:
        cols, r, s = parse_ssff(raw, f"{p}: track {ext!r}")
        pos = {n: c for n, c in cols.items() if _POS.match(n)}
        if not pos:
            continue  # formants, audio features...: not a sensor
        n = next(iter(pos.values())).shape[0]
        if rate is None:
            rate, start, n_records = r, s, n
        elif (r, s, n) != (rate, start, n_records):
            raise DataError(f"track {ext!r} has {n} records at {r:g} Hz from {s:g} s, the first "
                            f"sensor track {n_records} at {rate:g} Hz from {start:g} s", path=p,
                            item=ext)
        for name, c in pos.items():
            m = _POS.match(name)
            assert m is not None
            if c.dtype.kind not in "iuf":
                raise DataError(f"track {ext!r}: position column {name!r} holds {c.dtype} "
                                "(CHAR), not numbers", path=p, item=name)
            sensors.setdefault(m.group("sensor"), {})[m.group("axis")] = c[:, 0].astype(np.float64)
    if not sensors or rate is None or start is None:
        raise DataError(f"{what} has no SSFF track with <sensor>_posx/_posy/_posz columns", path=p)
    names = sorted(sensors, key=list(sensors).index)
    for s_name in names:
        lacking = [a for a in "xyz" if a not in sensors[s_name]]
        if lacking:
            raise DataError(f"sensor {s_name!r} has no column " +
                            ", ".join(f"{s_name}_pos{a}" for a in lacking), path=p, item=s_name)
    xyz = np.stack([np.stack([sensors[s][a] for a in "xyz"], axis=1) for s in names], axis=1)
    zero = np.all(xyz == 0.0, axis=(1, 2))
    xyz[zero] = np.nan
    xyz, note = to_mm(xyz, units or "mm", p, "sensor positions", names)
    notes = [note] if note else []
    if zero.any():
        notes.append(f"{int(zero.sum())} all-zero frames (no data) set to NaN")
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=rate,
                 units="mm", source=p, meta={"notes": notes}, start_time=start, kind="ema")


def _segments(annotation: Any, level: str | None, p: Path) -> Segments | None:
    if not isinstance(annotation, dict):
        if level is not None:
            raise DataError("the bundle has no annotation", path=p, item=level)
        return None
    levels = annotation.get("levels")
    sr = annotation.get("sampleRate")
    if not isinstance(levels, list) or not isinstance(sr, (int, float)) or sr <= 0:
        raise DataError("annotation without 'levels' or a positive 'sampleRate'", path=p)
    seg_levels = [lv for lv in levels if isinstance(lv, dict) and lv.get("type") == "SEGMENT"]
    names = [str(lv.get("name")) for lv in seg_levels]
    if level is not None:
        chosen = [lv for lv in seg_levels if lv.get("name") == level]
        if not chosen:
            raise DataError(f"no SEGMENT level {level!r}; the levels are {names}", path=p, item=level)
    else:
        chosen = [lv for lv in seg_levels if lv.get("name") == "Segment"] or seg_levels[:1]
        if not chosen:
            return None
    lv = chosen[0]
    labels: list[str] = []
    starts: list[float] = []
    ends: list[float] = []
    for i, item in enumerate(lv.get("items") or []):
        try:
            s, d = int(item["sampleStart"]), int(item["sampleDur"])
            lab = next((str(x["value"]) for x in item["labels"] if x.get("name") == lv["name"]),
                       str(item["labels"][0]["value"]) if item["labels"] else "")
        except (KeyError, IndexError, TypeError, ValueError, AttributeError) as e:
            raise DataError(f"level {lv.get('name')!r} item {i + 1} is malformed ({e!r})", path=p,
                            item=str(lv.get("name"))) from None
        labels.append(lab)
        starts.append(s / sr)
        ends.append((s + d) / sr)  # as EMU-webApp draws it, and as derived/*_Segment.tsv has it
    if not labels:
        raise DataError(f"level {lv.get('name')!r} has no items", path=p)
    return Segments(tuple(labels), np.array(starts), np.array(ends), p, (), str(lv.get("name")))


def _read(p: Path, req: ReadRequest) -> tuple[Trial, Segments | None]:
    return read_emu_bundle(p, level=req.level, units=req.units)


register(Reader("emu", "EMU bundle", (".json",), _read, axes=("+z", "-y"), sensors=True))
