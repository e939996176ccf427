"""X-ray Microbeam (University of Wisconsin XRMB database) pellet files, `.txy`.

One frame per line, whitespace-separated: the time in microseconds, then x and y of the pellets
UL LL T1 T2 T3 T4 MI MM (upper and lower lip, four tongue pellets from the tip backwards,
mandible at the incisors and at the molars), in micrometres; 1000000 marks a pellet the tracker
lost. The data are midsagittal (x, y): the lateral axis is absent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coartic.io.errors import DataError
from coartic.io.markers_csv import float_fields, midsagittal_note, rate_from_times
from coartic.io.registry import Reader, ReadRequest, register
from coartic.io.trial import Trial
from coartic.io.units import to_mm

PELLETS = ("UL", "LL", "T1", "T2", "T3", "T4", "MI", "MM")
MISSING = 1_000_000.0
UM_TO_MM = 1e-3
US_TO_S = 1e-6


def read_txy(path: str | Path, units: str | None = None) -> Trial:
    """Read an XRMB `.txy` file as a midsagittal Trial (kind 'ema'), positions in mm.

    `units` overrides the micrometres of the format (for a file converted to mm, say)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(f"cannot read as ASCII text: {e}", path=p) from None
    width = 1 + 2 * len(PELLETS)
    rows: list[list[float]] = []
    lines: list[int | None] = []
    for no, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = s.split()
        if len(fields) != width:
            raise DataError(f"{len(fields)} fields where the time and x, y of the pellets "
                            f"{' '.join(PELLETS)} make {width}", path=p, line=no)
        rows.append(float_fields(fields, p, no))
        lines.append(no)
    if not rows:
        raise DataError("no frames", path=p)
    data = np.array(rows)
    if not np.isfinite(data).all():
        r = int(np.flatnonzero(~np.isfinite(data).all(axis=1))[0])
        raise DataError("a value is not finite", path=p, line=lines[r])
    times = data[:, 0] * US_TO_S
    rate = rate_from_times(times, p, lines, "time (us)")
    xy = data[:, 1:].reshape(len(rows), len(PELLETS), 2)
    lost = (xy == MISSING).any(axis=2)
    xyz = np.zeros((len(rows), len(PELLETS), 3))
    xyz[:, :, 0] = xy[:, :, 0]
    xyz[:, :, 1] = xy[:, :, 1]
    xyz[lost] = np.nan
    if units is None:
        xyz = xyz * UM_TO_MM
        notes = ["positions read in micrometres (XRMB) and converted to mm"]
    else:
        xyz, note = to_mm(xyz, units, p, "pellet positions", PELLETS)
        notes = [note] if note else []
    if lost.any():
        per = {PELLETS[j]: int(lost[:, j].sum()) for j in range(len(PELLETS)) if lost[:, j].any()}
        notes.append("pellet samples marked lost (1000000) set to NaN: "
                     + ", ".join(f"{k} {v}" for k, v in per.items()))
    notes.append(midsagittal_note(2))
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=PELLETS, rate=rate, units="mm",
                 source=p, meta={"notes": notes}, start_time=float(times[0]), kind="ema",
                 planar_axis=2)


def _read(p: Path, req: ReadRequest) -> tuple[Trial, None]:
    return read_txy(p, units=req.units), None


register(Reader("xrmb", "X-ray Microbeam .txy", (".txy",), _read, axes=None, sensors=True))
