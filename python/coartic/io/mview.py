"""mview-style MATLAB EMA files (Haskins Laboratories; mview by Mark Tiede): a struct array with one
element per sensor (and usually one for the audio), each with the fields NAME, SRATE (Hz) and
SIGNAL (frames x coordinates, mm; columns x, y, z and then orientation, or x, z for midsagittal
data). Read with scipy.io.loadmat (MATLAB 5 format; v7.3 HDF5 files are refused with a message).

Elements whose SIGNAL has one column (audio) are not sensors and are skipped; every sensor must
share the first sensor's rate and length.

The Haskins IEEE rate database carries its forced alignment inside the file: the audio element has
the fields WORDS and PHONES, struct arrays of LABEL (ARPAbet, `sp` = pause) and OFFS ([start end]
in seconds). These are the file's own labels (`PHONES` unless the tier `WORDS` is asked for), used
when no label file is given, as an EMU bundle's are.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from coartic.io.errors import DataError
from coartic.io.labels import Segments
from coartic.io.markers_csv import midsagittal_note
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm

FIELDS = ("NAME", "SRATE", "SIGNAL")
# Columns of a sensor's SIGNAL: x, y, z, three of orientation and at most a couple more (RMS, status)
MAX_COORDINATES = 8
MAGIC = b"MATLAB 5.0 MAT-file"
# fields holding segment labels (struct arrays of LABEL and OFFS), the default first
LABEL_FIELDS = ("PHONES", "WORDS")


def read_mview(path: str | Path, units: str | None = None) -> Trial:
    """Read an mview struct-array .mat file as a Trial (kind 'ema'), positions in mm."""
    return read_mview_labelled(path, units=units)[0]


def read_mview_labelled(path: str | Path, units: str | None = None,
                        tier: str | None = None) -> tuple[Trial, Segments | None]:
    """The Trial of `read_mview` and the file's own segment labels: the `PHONES` field (or the
    field named by `tier`, e.g. `WORDS`) of the first element that has one; None when the file
    has no label field and no tier was asked for."""
    import scipy.io

    p = Path(path)
    try:
        head = p.read_bytes()[:128]
    except OSError as e:
        raise DataError(f"cannot read: {e.strerror or e}", path=p) from None
    if b"MATLAB 7.3" in head or head[:8] == b"\x89HDF\r\n\x1a\n":
        raise DataError("a MATLAB v7.3 (HDF5) file: scipy.io cannot read it; save it from MATLAB "
                        "with save(..., '-v7')", path=p)
    try:
        contents = scipy.io.loadmat(p, squeeze_me=False, struct_as_record=True)
    except MemoryError:
        raise
    except Exception as e:  # noqa: BLE001 - scipy's parser raises a dozen types on corrupt bytes
        # (MatReadError, struct.error, zlib.error, UnicodeDecodeError, ...): all mean "unreadable"
        raise DataError(f"not a readable MATLAB file ({type(e).__name__}: {e})", path=p) from None
    candidates = [(k, v) for k, v in contents.items()
                  if not k.startswith("__") and isinstance(v, np.ndarray) and v.dtype.names
                  and all(f in v.dtype.names for f in FIELDS)]
    if not candidates:
        found = {k: (list(v.dtype.names) if isinstance(v, np.ndarray) and v.dtype.names else
                     type(v).__name__) for k, v in contents.items() if not k.startswith("__")}
        raise DataError(f"no struct array with the fields {', '.join(FIELDS)} (mview format); the "
                        f"file holds {found}", path=p)
    var, structs = candidates[0]
    names: list[str] = []
    signals: list[np.ndarray] = []
    rates: list[float] = []
    transposed: list[str] = []
    for k, el in enumerate(structs.ravel()):
        name = _text(el["NAME"])
        if not name:
            raise DataError(f"element {k + 1} of {var!r} has an empty NAME", path=p, item=var)
        srate = _scalar(el["SRATE"], f"{name}: SRATE", p)
        sig = np.asarray(el["SIGNAL"])
        if sig.ndim != 2 or sig.dtype.kind not in "iuf":
            raise DataError(f"sensor {name!r}: SIGNAL is {sig.dtype} of shape {sig.shape}, not a "
                            "frames x coordinates matrix of numbers", path=p, item=name)
        if sig.shape[0] <= MAX_COORDINATES < sig.shape[1]:
            # coordinates x frames (saved transposed): a sensor has at most MAX_COORDINATES columns
            sig = sig.T
            transposed.append(name)
        if sig.shape[1] < 2:
            continue  # the audio, or another one-column signal: not a sensor
        if not (np.isfinite(srate) and srate > 0):
            raise DataError(f"sensor {name!r}: SRATE {srate:g} is not a frame rate (a positive number of "
                            "frames per second)", path=p, item=name)
        if name in names:
            raise DataError(f"sensor {name!r} appears twice in {var!r}", path=p, item=name)
        names.append(name)
        rates.append(srate)
        signals.append(sig.astype(np.float64))
    if not names:
        raise DataError(f"{var!r} holds no sensor (every SIGNAL has one column)", path=p, item=var)
    # every sensor shares one rate and length: the odd ones out are named, measured against the most
    # common (not the first, which may be the odd one)
    shapes = [(s.shape[0], r) for s, r in zip(signals, rates)]
    n, rate = max(set(shapes), key=shapes.count)
    odd = [f"{nm!r} ({m} frames at {r:g} Hz)" for nm, (m, r) in zip(names, shapes) if (m, r) != (n, rate)]
    if odd:
        raise DataError(f"sensor{'s' if len(odd) > 1 else ''} {', '.join(odd)} differ from the other "
                        f"{len(names) - len(odd)} ({n} frames at {rate:g} Hz): every sensor must share one rate "
                        "and length", path=p, item=odd[0].split("'")[1])
    if n < 2:
        raise DataError(f"{n} frame(s): no frame rate", path=p)
    dims = {s.shape[1] for s in signals}
    planar: int | None = None
    xyz = np.zeros((n, len(names), 3))
    if min(dims) >= 3:
        for j, s in enumerate(signals):
            xyz[:, j, :] = s[:, :3]
    elif dims == {2}:
        planar = 1  # x (anterior-posterior) and z (vertical): y, the lateral axis, is absent
        for j, s in enumerate(signals):
            xyz[:, j, 0] = s[:, 0]
            xyz[:, j, 2] = s[:, 1]
    else:
        short = next(nm for nm, s in zip(names, signals) if s.shape[1] == 2)
        raise DataError(f"sensor {short!r} has 2 coordinates where others have 3 or more",
                        path=p, item=short)
    xyz, note = to_mm(xyz, units or "mm", p, "sensor positions", names)
    notes = [f"mview struct {var!r}: {len(names)} sensors at {rate:g} Hz"] + ([note] if note else [])
    if transposed:
        notes.append(f"SIGNAL of {', '.join(transposed)} stored as coordinates x frames (transposed): read as "
                     "frames x coordinates")
    if planar is not None:
        notes.append(midsagittal_note(planar))
    segments = _embedded_segments(structs, var, tier, p)
    if segments is not None:
        notes.append(f"labels: the {len(segments)} {segments.tier} embedded in the file")
    trial = Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=float(rate),
                  units="mm", source=p, meta={"notes": notes}, kind="ema", planar_axis=planar)
    return trial, segments


def _embedded_segments(structs: np.ndarray, var: str, tier: str | None,
                       p: Path) -> Segments | None:
    fields = [f for f in (structs.dtype.names or ()) if f not in FIELDS]
    offered = [f for f in fields if f.upper() in LABEL_FIELDS]
    if tier is not None:
        wanted = [f for f in offered if f.upper() == tier.upper()]
        if not wanted:
            raise DataError(f"no label field {tier!r} in {var!r}; its label fields are "
                            f"{offered or 'none'} (of {fields or 'no fields'} beyond "
                            f"{', '.join(FIELDS)})", path=p, item=tier)
        field = wanted[0]
    else:
        default = next((f for want in LABEL_FIELDS for f in offered if f.upper() == want), None)
        if default is None:
            return None
        field = default
    holder = next((el for el in structs.ravel() if _entries(el[field]).size), None)
    if holder is None:
        if tier is not None:
            raise DataError(f"the label field {field!r} of {var!r} is empty in every element",
                            path=p, item=field)
        return None
    owner = _text(holder["NAME"])
    labels: list[str] = []
    starts: list[float] = []
    ends: list[float] = []
    for i, entry in enumerate(_entries(holder[field])):
        where = f"{field} entry {i + 1} of element {owner!r}"
        names = entry.dtype.names or ()
        if "LABEL" not in names or "OFFS" not in names:
            raise DataError(f"{where} has the fields {list(names)}, not LABEL and OFFS", path=p,
                            item=field)
        offs = np.asarray(entry["OFFS"], dtype=object).ravel()
        while offs.size == 1 and isinstance(offs[0], np.ndarray):
            offs = offs[0].ravel()
        try:
            s, e = (float(x) for x in offs)
        except (TypeError, ValueError):
            raise DataError(f"{where} ({_text(entry['LABEL'])!r}): OFFS is {offs.tolist()!r}, not "
                            "[start end] in seconds", path=p, item=field) from None
        labels.append(_text(entry["LABEL"]))
        starts.append(s)
        ends.append(e)
    return Segments(tuple(labels), np.array(starts), np.array(ends), p, (), field.upper())


def _entries(v: Any) -> np.ndarray:
    """A label field's entries (a struct array, possibly wrapped in object arrays by loadmat)."""
    a = np.asarray(v)
    while a.dtype == object and a.size == 1:
        a = np.asarray(a.ravel()[0])
    if a.dtype.names is None:
        return np.empty(0)
    return a.ravel()


def _text(v: Any) -> str:
    a = np.asarray(v).ravel()
    if a.size == 0:
        return ""
    x = a[0]
    if isinstance(x, np.ndarray):
        return _text(x)
    return str(x).strip()


def _scalar(v: Any, what: str, p: Path) -> float:
    a = np.asarray(v, dtype=object).ravel()
    while a.size == 1 and isinstance(a[0], np.ndarray):
        a = a[0].ravel()
    try:
        if a.size != 1:
            raise ValueError
        return float(a[0])
    except (TypeError, ValueError):
        raise DataError(f"{what} is not one number", path=p) from None


def _read(p: Path, req: ReadRequest) -> tuple[Trial, Segments | None]:
    return read_mview_labelled(p, units=req.units, tier=req.level)


register(Reader("mview", "mview MATLAB .mat EMA", (".mat",), _read,
                sniff=lambda p, head: head.startswith(MAGIC), axes=None, sensors=True))
