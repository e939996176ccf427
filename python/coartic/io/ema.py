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
from numpy.typing import NDArray

from coartic.io.errors import DataError
from coartic.io.markers_csv import TIME_COLUMNS, parse_numbers, rate_from_times, read_table
from coartic.io.roles import RoleMap
from coartic.io.trial import Trial
from coartic.io.units import to_mm

_POS = re.compile(r"^(?P<sensor>.+)_pos(?P<axis>[xyzXYZ])$")


def looks_like_ema(header: Sequence[str]) -> bool:
    return any(_POS.match(h) for h in header)


def read_ema_csv(path: str | PathLike[str], units: str | None = None) -> Trial:
    """Read an EMA sensor table as a Trial (kind 'ema', no labels), positions in mm.

    Frames where every sensor is exactly 0 are 'no data' on Carstens systems and become NaN.
    """
    p = Path(path)
    header, rows, lines, file_unit = read_table(p)
    tcol = next((i for i, h in enumerate(header) if h.lower() in TIME_COLUMNS), None)
    if tcol is None:
        raise DataError(f"no time column (one of {sorted(TIME_COLUMNS)}); the columns are "
                        f"{header[:8]}...", path=p, line=1)
    cols: dict[str, dict[str, int]] = {}
    names: list[str] = []
    for i, h in enumerate(header):
        m = _POS.match(h)
        if m is None:
            continue
        s, a = m.group("sensor"), m.group("axis").lower()
        if s not in cols:
            cols[s] = {}
            names.append(s)
        cols[s][a] = i
    if not names:
        raise DataError(f"no EMA sensor columns named <sensor>_posx, _posy, _posz; the columns "
                        f"are {header[:8]}...", path=p)
    for s in names:
        lacking = [a for a in "xyz" if a not in cols[s]]
        if lacking:
            raise DataError(f"sensor {s!r} has no column " + ", ".join(f"{s}_pos{a}" for a in lacking),
                            path=p, item=s)
    if not rows:
        raise DataError("a header but no data rows", path=p)
    data = parse_numbers(rows, lines, header, p)
    times = data[:, tcol] * TIME_COLUMNS[header[tcol].lower()]
    rate = rate_from_times(times, p, lines, header[tcol])
    xyz = np.stack([data[:, [cols[s]["x"], cols[s]["y"], cols[s]["z"]]] for s in names], axis=1)
    zero = np.all(xyz == 0.0, axis=(1, 2))
    xyz[zero] = np.nan
    xyz, note = to_mm(xyz, units or file_unit or "mm", p, "sensor positions")
    notes = [note] if note else []
    if zero.any():
        notes.append(f"{int(zero.sum())} all-zero frames (no data) set to NaN")
    return Trial(markers=np.ascontiguousarray(xyz), marker_names=tuple(names), rate=rate,
                 units="mm", source=p, meta={"notes": notes}, start_time=float(times[0]),
                 kind="ema")


def ema_channels(
    markers: NDArray[np.float64], names: Sequence[str], roles: RoleMap, rest: NDArray[np.bool_],
    source: Path | None,
) -> tuple[dict[str, NDArray[np.float64]], dict[str, str]]:
    """Channels from EMA sensors, and for each channel that cannot be made, why not."""
    vi, vs = roles.vertical_axis
    ai, asg = roles.anterior_axis
    li = 3 - vi - ai

    def sensor(role: str) -> NDArray[np.float64] | None:
        k = roles.find(role, names)
        return None if k is None else markers[:, k, :]

    ul, ll, jaw = sensor("UL"), sensor("LL"), sensor("JAW")
    out: dict[str, NDArray[np.float64]] = {}
    why: dict[str, str] = {}
    if ul is None or ll is None:
        raise DataError(f"EMA channels need the UL and LL roles; the sensors are {list(names)} "
                        "and the role map names " + (str(dict(roles.roles)) or "none") +
                        " (pass role_map={'UL': ..., 'LL': ...})", path=source, item="UL/LL")
    mid = 0.5 * (ul[:, vi] + ll[:, vi]) * vs
    rest_mid = mid[rest & np.isfinite(mid)]
    if rest_mid.size == 0:
        raise DataError("no valid UL/LL samples in the rest frames: y_0 is undefined", path=source)
    y0 = float(rest_mid.mean())
    out["ULO"] = vs * ul[:, vi] - y0
    out["LLO"] = y0 - vs * ll[:, vi]
    out["ULP"] = asg * ul[:, ai]
    out["LLP"] = asg * ll[:, ai]
    lcl, lcr, lc = sensor("LC_L"), sensor("LC_R"), sensor("LC")
    if lcl is not None and lcr is not None:
        out["LR"] = np.linalg.norm(lcl - lcr, axis=1)
    elif lc is not None:
        out["LR"] = 2.0 * np.abs(lc[:, li] - 0.5 * (ul[:, li] + ll[:, li]))
    else:
        why["LR"] = "no lip-corner sensor (role LC, or LC_L and LC_R)"
    nose = sensor("NOSE")
    if jaw is None:
        why["JO"] = "no jaw sensor (role JAW)"
    elif nose is not None:
        out["JO"] = np.linalg.norm(nose - jaw, axis=1)
    else:
        out["JO"] = -vs * jaw[:, vi]
    out["LA"] = np.linalg.norm(ul - ll, axis=1)
    return out, why

