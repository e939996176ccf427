"""Articulatory channels from EMA sensor positions (MODEL.md §6, docs/DATA.md): which role gives
which channel, the sanity checks on the axes, and why a channel cannot be made.

The geometry lives apart from the EMA readers so that ``Trial.channels`` (io/trial.py) can use it
while the readers, which build Trials, import trial.py: neither imports the other's caller.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from coartic.io.errors import DataError, DataWarning
from coartic.io.roles import RoleMap

EMA_ROLES_USED = ("UL", "LL", "JAW", "LC", "LC_L", "LC_R", "NOSE", "TT", "TB")
# channel -> (role, coordinate): height along the vertical, advancement along the anterior axis
TONGUE_SENSORS: dict[str, tuple[str, str]] = {
    "TTH": ("TT", "vertical"), "TTA": ("TT", "anterior"),
    "TBH": ("TB", "vertical"), "TBA": ("TB", "anterior"),
}
_TONGUE_NAMES = {"TT": "tongue-tip", "TB": "tongue-body"}
# The lips' motion along the axis taken as lateral may exceed their motion along the anterior axis
# by this factor before the axes are called implausible (German EMA, right axes: 0.7).
LATERAL_MOTION_RATIO = 2.0
# A sensor whose median lateral coordinate is within this (mm) of the lips' is on the midline (German
# EMA: ul, ll, jw, tt, tm, tb within 3.4 mm of one another); a jaw sensor farther out is a lateral one.
MIDLINE_MM = 5.0


def planar_reason(planar_axis: int) -> str:
    """Why a channel that needs the third axis is not computed from midsagittal data."""
    kept = " and ".join(a for k, a in enumerate("xyz") if k != planar_axis)
    return (f"it needs the third (lateral) axis, and this file is midsagittal ({kept} only)")


def ema_channels(
    markers: NDArray[np.float64], names: Sequence[str], roles: RoleMap, rest: NDArray[np.bool_],
    source: Path | None, *, planar_axis: int | None = None,
) -> tuple[dict[str, NDArray[np.float64]], dict[str, str]]:
    """Channels from EMA sensors, and for each channel that cannot be made, why not."""
    vi, vs = roles.vertical_axis
    ai, asg = roles.anterior_axis
    li = 3 - vi - ai

    idx = roles.resolve(EMA_ROLES_USED, names, source)

    def sensor(role: str) -> NDArray[np.float64] | None:
        k = idx[role]
        return None if k is None else markers[:, k, :]

    ul, ll, jaw = sensor("UL"), sensor("LL"), sensor("JAW")
    out: dict[str, NDArray[np.float64]] = {}
    why: dict[str, str] = {}
    if ul is None or ll is None:
        raise DataError(f"EMA channels need the UL and LL roles; the sensors are {list(names)} "
                        "and the role map names " + (str(dict(roles.roles)) or "none") +
                        " (pass role_map={'UL': ..., 'LL': ...})", path=source, item="UL/LL")
    ll_k, jaw_k = idx["LL"], idx["JAW"]
    lips_jaw = {idx["UL"], ll_k, jaw_k}
    check_axes(ul, ll, sensor("JAW"), roles, source,
               names=(names[ll_k], names[jaw_k]) if ll_k is not None and jaw_k is not None else None,
               others={names[k]: markers[:, k, :] for k in range(len(names)) if k not in lips_jaw},
               assigned=frozenset(names[k] for k in idx.values() if k is not None))
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
    if planar_axis is not None:
        why["LR"] = planar_reason(planar_axis)
    elif lcl is not None and lcr is not None:
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
    for channel, (role, along) in TONGUE_SENSORS.items():
        s = sensor(role)
        if s is None:
            why[channel] = f"no {_TONGUE_NAMES[role]} sensor (role {role})"
            continue
        k, sign = (vi, vs) if along == "vertical" else (ai, asg)
        coord = sign * s[:, k]
        # relative to the sensor's rest position, as ULO/LLO are to y_0: sensor placement differs
        # between sessions, the motion does not
        at_rest = coord[rest & np.isfinite(coord)]
        if at_rest.size == 0:
            why[channel] = f"no valid {role} sample in the rest frames: its rest position is undefined"
            continue
        out[channel] = coord - float(at_rest.mean())
    return out, why



def check_axes(
    ul: NDArray[np.float64], ll: NDArray[np.float64], jaw: NDArray[np.float64] | None, roles: RoleMap,
    source: Path | None, names: tuple[str, str] | None = None,
    others: dict[str, NDArray[np.float64]] | None = None, assigned: frozenset[str] = frozenset(),
) -> None:
    """Warn (DataWarning) when the role map's axes do not fit the sensors' geometry.

    Three things hold on every speaker: the upper lip is above the lower lip, mostly along the
    vertical; the lips sit in front of the lower incisors (the jaw sensor), more along the anterior
    axis than sideways; and midline sensors move less sideways than forwards. Wrong axes give
    wrong channels without an error, e.g. ULP and LLP read along the lateral axis. A lower-lip
    sensor behind the jaw sensor while the upper lip is in front of both is named as a swapped
    pair of sensors (`names`: the LL and JAW sensors' names), not as an axis problem; so is a jaw
    sensor off the midline where the lips and the file's other sensors (`others`, by name; those in
    `assigned` play a role already) are on it: a lateral jaw sensor taken for the midline one, with
    the midline candidates for the role map's JAW.
    """
    vi, vs = roles.vertical_axis
    ai, asg = roles.anterior_axis
    li = 3 - vi - ai
    ok = np.isfinite(ul).all(axis=1) & np.isfinite(ll).all(axis=1)
    ok_jaw = ok & np.isfinite(jaw).all(axis=1) if jaw is not None else ok
    if ok.sum() < 2:
        return
    where = f"{source}: " if source is not None else ""
    axes = f"(axes: vertical {roles.vertical!r}, anterior {roles.anterior!r}, from {roles.source})"
    sep = np.median(ul[ok] - ll[ok], axis=0)
    problems: list[str] = []
    if int(np.argmax(np.abs(sep))) != vi:
        k = int(np.argmax(np.abs(sep)))
        problems.append(f"UL and LL are {abs(sep[k]):.1f} mm apart along {'xyz'[k]} but "
                        f"{abs(sep[vi]):.1f} mm along the vertical axis {'xyz'[vi]}")
    elif sep[vi] * vs < 0:
        problems.append(f"the UL sensor is {abs(sep[vi]):.1f} mm below LL along {roles.vertical!r} "
                        "(the vertical sign, or UL/LL swapped?)")
    if jaw is not None and ok_jaw.sum() >= 2:
        front = np.median(ll[ok_jaw] - jaw[ok_jaw], axis=0)
        ul_front = np.median(ul[ok_jaw] - ll[ok_jaw], axis=0)
        if (not problems and abs(front[ai]) >= abs(front[li]) and front[ai] * asg < 0
                and ul_front[ai] * asg > 0
                and abs(ul_front[ai]) > abs(front[ai]) / 2):
            # The LL sensor is the farthest back of the three while UL is in front of it: the
            # lips are where the axes say, and the LL and JAW sensors trade places (e.g. speaker
            # F01 of the Haskins rate database), not an axis sign.
            ll_name, jaw_name = names if names is not None else ("<LL sensor>", "<JAW sensor>")
            warnings.warn(
                f"{where}the LL and JAW sensors look swapped {axes}: the sensor taken as LL "
                f"({ll_name!r}) is {abs(front[ai]):.1f} mm behind the one taken as JAW "
                f"({jaw_name!r}) and {abs(ul_front[ai]):.1f} mm behind UL along "
                f"{roles.anterior!r}, where a lower lip sits in front of the lower incisors. If the "
                f"sensors were swapped when recorded, give the role map "
                f'{{"LL": "{jaw_name}", "JAW": "{ll_name}"}}', DataWarning, stacklevel=3)
            return
        if not problems and abs(front[li]) > abs(front[ai]) and lateral_jaw(ul, ll, jaw, np.asarray(ok_jaw, dtype=bool), roles, where, axes,
                                                                          names, others or {}, assigned):
            return
        if abs(front[li]) > abs(front[ai]):
            problems.append(f"LL is {abs(front[li]):.1f} mm from the jaw sensor along {'xyz'[li]} "
                            f"(taken as lateral) and {abs(front[ai]):.1f} mm along the anterior axis "
                            f"{'xyz'[ai]}: the lips sit in front of the incisors, so "
                            f"{'xyz'[li]} looks anterior")
        elif front[ai] * asg < 0:
            problems.append(f"LL is {abs(front[ai]):.1f} mm behind the jaw sensor along "
                            f"{roles.anterior!r} (the anterior sign?)")
    else:
        lat = float(ul[ok, li].std() + ll[ok, li].std())
        ant = float(ul[ok, ai].std() + ll[ok, ai].std())
        if lat > LATERAL_MOTION_RATIO * ant:
            problems.append(f"the lips move {lat / max(ant, 1e-12):.1f} times more along "
                            f"{'xyz'[li]} (taken as lateral) than along the anterior axis {'xyz'[ai]}")
    if problems:
        warnings.warn(f"{where}the EMA axes look wrong {axes}: " + "; ".join(problems)
                      + ". Give the axes in the role map, e.g. "
                      '{"axes": {"vertical": "+z", "anterior": "+x"}}', DataWarning, stacklevel=3)


def lateral_jaw(ul: NDArray[np.float64], ll: NDArray[np.float64], jaw: NDArray[np.float64], ok: NDArray[np.bool_],
                roles: RoleMap, where: str, axes: str, names: tuple[str, str] | None,
                others: dict[str, NDArray[np.float64]], assigned: frozenset[str]) -> bool:
    """Warn and return True when the sensor taken as JAW is off the midline while the lips and most
    other sensors are on it (within ``MIDLINE_MM`` along the lateral axis): a lateral jaw sensor
    (e.g. Haskins' JAWL) in the place of the midline one, not wrong axes. The warning names the
    midline sensors below and behind the lower lip that play no role, for the role map's JAW."""
    vi, vs = roles.vertical_axis
    ai, asg = roles.anterior_axis
    li = 3 - vi - ai
    mid = float(np.median(0.5 * (ul[ok, li] + ll[ok, li])))
    jaw_off = float(np.median(jaw[ok, li])) - mid
    if abs(jaw_off) <= MIDLINE_MM:
        return False
    at: dict[str, NDArray[np.float64]] = {}
    for nm, s in others.items():
        good = np.isfinite(s).all(axis=1)
        if good.sum() >= 2:
            at[nm] = np.median(s[good], axis=0)
    midline = [nm for nm, p in at.items() if abs(float(p[li]) - mid) <= MIDLINE_MM]
    if not midline or 2 * len(midline) <= len(at):  # the other sensors do not show a midline: not this
        return False
    ll_at = np.median(ll[ok], axis=0)
    below_behind = [nm for nm in midline if nm not in assigned
                    and (at[nm][vi] - ll_at[vi]) * vs < 0 and (at[nm][ai] - ll_at[ai]) * asg < 0]
    jaw_name = names[1] if names is not None else "<JAW sensor>"
    fix = (f'{{"JAW": "{below_behind[0]}"}}' + (f" (midline sensors below and behind the lower lip that play no role: "
                                                 f"{', '.join(below_behind)})" if len(below_behind) > 1 else "")
           if below_behind else '{"JAW": "<the lower-incisor sensor>"}')
    warnings.warn(
        f"{where}the sensor taken as JAW ({jaw_name!r}) is {abs(jaw_off):.1f} mm to the side of the lips' midline "
        f"along {'xyz'[li]} (the lateral axis), where UL, LL and {len(midline)} of the file's {len(at)} other "
        f"sensors ({', '.join(midline)}) lie within {MIDLINE_MM:g} mm of it: it looks like a lateral jaw sensor "
        f"taken for the midline one on the lower incisors that JO is measured from; the axes {axes} fit the "
        f"other sensors. Give the midline jaw sensor in the role map, e.g. {fix}", DataWarning, stacklevel=4)
    return True
