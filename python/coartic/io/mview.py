"""mview-style MATLAB EMA files (Haskins Laboratories; mview by Mark Tiede): a struct array with one
element per sensor (and usually one for the audio), each with the fields NAME, SRATE (Hz) and
SIGNAL (frames x coordinates, mm; columns x, y, z and then orientation, or x, z for midsagittal
data). Read with scipy.io.loadmat (MATLAB 5 format; v7.3 HDF5 files are refused with a message).

Elements whose SIGNAL has one column (audio) are not sensors and are skipped; every sensor must
share the first sensor's rate and length.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from coartic.io.errors import DataError
from coartic.io.markers_csv import midsagittal_note
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm

FIELDS = ("NAME", "SRATE", "SIGNAL")
MAGIC = b"MATLAB 5.0 MAT-file"


def read_mview(path: str | Path, units: str | None = None) -> Trial:
    """Read an mview struct-array .mat file as a Trial (kind 'ema'), positions in mm."""
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
    rate: float | None = None
    for k, el in enumerate(structs.ravel()):
        name = _text(el["NAME"])
        if not name:
            raise DataError(f"element {k + 1} of {var!r} has an empty NAME", path=p, item=var)
        srate = _scalar(el["SRATE"], f"{name}: SRATE", p)
        sig = np.asarray(el["SIGNAL"])
        if sig.ndim != 2 or sig.dtype.kind not in "iuf":
            raise DataError(f"sensor {name!r}: SIGNAL is {sig.dtype} of shape {sig.shape}, not a "
                            "frames x coordinates matrix of numbers", path=p, item=name)
        if sig.shape[1] < 2:
            continue  # the audio, or another one-column signal: not a sensor
        if rate is None:
            rate = srate
        elif srate != rate or sig.shape[0] != signals[0].shape[0]:
            raise DataError(f"sensor {name!r} has {sig.shape[0]} frames at {srate:g} Hz, the "
                            f"first sensor {names[0]!r} {signals[0].shape[0]} at {rate:g} Hz",
                            path=p, item=name)
        if name in names:
            raise DataError(f"sensor {name!r} appears twice in {var!r}", path=p, item=name)
        names.append(name)
        signals.append(sig.astype(np.float64))
    if not names or rate is None:
        raise DataError(f"{var!r} holds no sensor (every SIGNAL has one column)", path=p, item=var)
    if rate <= 0 or not np.isfinite(rate):
        raise DataError(f"SRATE {rate:g} is not a frame rate", path=p, item=names[0])
    n = signals[0].shape[0]
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
    if planar is not None:
        notes.append(midsagittal_note(planar))
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=float(rate),
                 units="mm", source=p, meta={"notes": notes}, kind="ema", planar_axis=planar)


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


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    return read_mview(p, units=req.units), None


register(Reader("mview", "mview MATLAB .mat EMA", (".mat",), _read,
                sniff=lambda p, head: head.startswith(MAGIC), axes=None, sensors=True))
