"""Which marker or sensor plays which role, and (for EMA) which axis points where.

Roles are the marker names of MODEL.md §6: NOSE, EAR_L, EAR_R, UL, LL, LC_L, LC_R, CHIN, plus JAW
(an EMA jaw sensor, used for JO when there is no CHIN marker) and LC (a single EMA lip-corner
sensor). Axes are written as a sign and a letter, e.g. "+z" (the coordinate that increases
upwards) or "-y" (forwards is decreasing y).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.io.errors import DataError, parse_json
from coartic.textfile import TextDecodeError, read_text

MARKER_ROLES = ("NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN")
EMA_ROLES = ("UL", "LL", "JAW", "LC", "LC_L", "LC_R", "TT", "TB")
# TT: tongue tip; TB: tongue body (the dorsum sensor behind the tip): the tongue channels' sensors.
ROLES = (*MARKER_ROLES, "JAW", "LC", "TT", "TB")
# Usual sensor names on EMA systems (Carstens AG50x, NDI Wave), lower case.
EMA_SENSOR_GUESSES: dict[str, tuple[str, ...]] = {
    "UL": ("ul", "upper_lip", "upperlip", "ulip"),
    "LL": ("ll", "lower_lip", "lowerlip", "llip"),
    # li: lower incisor (MOCHA); mi: mandible incisor pellet (X-ray Microbeam)
    "JAW": ("jw", "jaw", "li", "ji", "lower_incisor", "lowerincisor", "mand", "mi"),
    # ml: "mouth left", the lip-corner sensor of the Haskins IEEE rate database
    "LC": ("lc", "lip_corner", "lipcorner", "corner", "ml", "mouth_left"),
    # t1: the X-ray Microbeam pellet nearest the tip
    "TT": ("tt", "t_tip", "tongue_tip", "tonguetip", "ttip", "tip", "t1"),
    # German EMU data: tt, tm (mid), tb (back); MOCHA: tt, tb (body), td (dorsum); Haskins: tt,
    # tb, tr (rear); X-ray Microbeam: t1..t4, t3 on the dorsum. A dorsum sensor stands in for TB
    # only when there is no body sensor.
    "TB": ("tb", "t_back", "tongue_body", "tonguebody", "tongue_back", "tback", "tbody", "t3",
           "td", "tdor"),
}
_AXES = ("x", "y", "z")
AXIS_KEYS = ("vertical", "anterior")
# The key of the table metadata that holds the role map (and axes) a table was fitted with.
ROLE_RECORD_KEY = "role_map"


def _axis(spec: str, what: str, source: str) -> tuple[int, float]:
    s = spec.strip().lower()
    sign = -1.0 if s.startswith("-") else 1.0
    letter = s.lstrip("+-")
    if letter not in _AXES:
        raise DataError(f"{source}: axis {what} = {spec!r}; write a sign and x, y or z (e.g. '-y')",
                        item=what)
    return _AXES.index(letter), sign


@dataclass(frozen=True)
class RoleMap:
    """Role → marker/sensor name in the file; for EMA also the up, forward and lateral axes."""

    roles: Mapping[str, str] = field(default_factory=dict)
    vertical: str = "+z"
    anterior: str = "-y"
    source: str = "<dict>"
    axes_given: bool = False  # the map says the axes (else the format's own, or a guess, apply)

    def __post_init__(self) -> None:
        for r in self.roles:
            if r not in ROLES:
                raise DataError(f"{self.source}: unknown role {r!r}; roles are {list(ROLES)}", item=r)
        v, a = _axis(self.vertical, "vertical", self.source), _axis(self.anterior, "anterior",
                                                                     self.source)
        if v[0] == a[0]:
            raise DataError(f"{self.source}: vertical {self.vertical!r} and anterior "
                            f"{self.anterior!r} are the same axis")
        by_marker: dict[str, str] = {}
        for r, name in self.roles.items():
            other = by_marker.get(name.lower())
            if other is not None:
                # e.g. LL given the UL sensor: LA would be 0 and the lower lip a copy of the upper
                raise DataError(f"{self.source}: roles {other} and {r} both name marker {name!r}; "
                                "each role needs its own marker", item=r)
            by_marker[name.lower()] = r

    @property
    def vertical_axis(self) -> tuple[int, float]:
        return _axis(self.vertical, "vertical", self.source)

    @property
    def anterior_axis(self) -> tuple[int, float]:
        return _axis(self.anterior, "anterior", self.source)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "<dict>") -> RoleMap:
        roles: dict[str, str] = {}
        axes = d.get("axes", {})
        if not isinstance(axes, Mapping):
            raise DataError(f"{source}: 'axes' must be an object like "
                            '{"vertical": "+z", "anterior": "-y"}')
        unknown = sorted(set(axes) - set(AXIS_KEYS))
        if unknown:
            raise DataError(f"{source}: unknown axis {unknown[0]!r} in 'axes'; give {list(AXIS_KEYS)} "
                            "(the lateral axis is the third)", item=str(unknown[0]))
        for k, v in d.items():
            if k == "axes":
                continue
            if not isinstance(v, str):
                raise DataError(f"{source}: role {k!r} must name a marker, found {v!r}", item=k)
            if k.upper() in roles:
                raise DataError(f"{source}: role {k.upper()!r} is given twice", item=k)
            roles[k.upper()] = v
        return cls(roles, str(axes.get("vertical", "+z")), str(axes.get("anterior", "-y")), source,
                   "axes" in d)

    def to_record(self) -> dict[str, Any]:
        """What a fitted table stores (metadata["role_map"]): the roles and axes the fit read its
        recordings with, so that scoring reads new recordings of the same system alike."""
        rec: dict[str, Any] = {"source": self.source, "roles": dict(self.roles)}
        if self.axes_given:  # else the format's axes (or the guess from the sensors) apply again
            rec["axes"] = {"vertical": self.vertical, "anterior": self.anterior}
        return rec

    @classmethod
    def recorded(cls, table: Any) -> RoleMap | None:
        """The role map ``table`` (a ParameterTable) was fitted with, or None if it records none; a
        malformed record is the table's TableError."""
        rec = table.metadata.get(ROLE_RECORD_KEY)
        if rec is None:
            return None
        from coartic.table import TableError

        where = f"{table.source}: metadata.{ROLE_RECORD_KEY}"
        if not isinstance(rec, Mapping) or not isinstance(rec.get("roles", {}), Mapping):
            raise TableError(f"{where} must be an object with 'roles' and 'axes', found {str(rec)[:80]!r}")
        try:
            axes = {"axes": rec["axes"]} if "axes" in rec else {}
            return cls.from_dict({**rec.get("roles", {}), **axes},
                                 f"the role map recorded in {table.source} ({rec.get('source', 'no source')})")
        except DataError as e:
            raise TableError(f"{where}: {e}") from None

    @classmethod
    def from_file(cls, path: str | PathLike[str]) -> RoleMap:
        p = Path(path)
        try:
            text = read_text(p, "role map")
        except OSError as e:
            raise DataError(f"cannot read the role map: {e.strerror or e}", path=p) from None
        except TextDecodeError as e:
            raise DataError(e.detail, path=p) from None
        d = parse_json(text, p)
        if not isinstance(d, dict):
            raise DataError('a role map is a JSON object {"UL": "<marker>", ...}', path=p)
        return cls.from_dict(d, str(p))

    def find(self, role: str, names: Sequence[str], path: str | PathLike[str] | None = None) -> int | None:
        """Index of the marker playing `role` (its own name, case-insensitively, by default).

        Markers whose names differ only in case (`ul` and `UL`) make the match ambiguous: a
        DataError naming both, unless the role map names one of them exactly."""
        wanted = self.roles.get(role, role)
        hits = [i for i, n in enumerate(names) if n.lower() == wanted.lower()]
        if len(hits) > 1:
            if role in self.roles and wanted in names:
                return list(names).index(wanted)
            raise DataError(f"markers {[names[i] for i in hits]} differ only in case: which is "
                            f"{role}? (name it exactly in a role map)", path=path, item=role)
        return hits[0] if hits else None

    def resolve(
        self, roles: Sequence[str], names: Sequence[str], path: str | PathLike[str] | None = None
    ) -> dict[str, int | None]:
        """Marker index of each role (None when absent); two roles on one marker is a DataError."""
        idx = {r: self.find(r, names, path) for r in roles}
        seen: dict[int, str] = {}
        for r, k in idx.items():
            if k is None:
                continue
            if k in seen:
                raise DataError(f"roles {seen[k]} and {r} are both marker {names[k]!r}"
                                + (f" (role map {self.source})" if self.roles else "")
                                + "; each role needs its own marker", path=path, item=r)
            seen[k] = r
        return idx


def resolve_role_map(spec: RoleMap | Mapping[str, Any] | str | PathLike[str] | None) -> RoleMap:
    if spec is None:
        return RoleMap(source="default role map")
    if isinstance(spec, RoleMap):
        return spec
    if isinstance(spec, Mapping):
        return RoleMap.from_dict(spec, "the role map given")
    return RoleMap.from_file(spec)


def guess_ema_roles(names: Sequence[str], base: RoleMap) -> RoleMap:
    """`base` with UL, LL, JAW, LC filled in from usual sensor names where it does not say."""
    roles = dict(base.roles)
    lower = {n.lower(): n for n in names}
    for role, guesses in EMA_SENSOR_GUESSES.items():
        if role in roles:
            continue
        hit = next((lower[g] for g in guesses if g in lower), None)
        if hit is not None:
            roles[role] = hit
    return RoleMap(roles, base.vertical, base.anterior, base.source, base.axes_given)


# Names only a face marker set has, and names only an EMA lab gives (jaw, incisor, tongue sensors).
_FACE_ONLY = frozenset({"nose", "ear_l", "ear_r", "chin"})
_EMA_ONLY = frozenset({"jaw", "jw", "li", "mi", "tt", "tb", "td", "tr", "tm", "t1", "t2", "t3",
                       "t4", "t_tip", "t_mid", "t_back"})


def ema_sensor_names(names: Sequence[str]) -> bool:
    """Names as EMA labs give their sensors: UL, LL and a jaw or tongue sensor, and no face head
    marker (NOSE, EAR_L, EAR_R, CHIN). Read as face markers, such a file would ask for NOSE/CHIN."""
    lower = {n.lower() for n in names}
    return not lower & _FACE_ONLY and {"ul", "ll"} <= lower and bool(lower & _EMA_ONLY)


# Sensors that sit behind the lips on the midline, in the order they define "forwards".
_BEHIND_THE_LIPS = ("TT", "JAW", "TB")


def guess_axes(
    markers: NDArray[np.float64], names: Sequence[str], roles: RoleMap, planar_axis: int | None,
    path: str | PathLike[str] | None = None,
) -> tuple[str, str, str]:
    """(vertical, anterior, why) from the sensors: up is the axis along which UL and LL lie
    farthest apart, signed so that UL is above LL; forwards is, of the remaining axes (the one
    other axis of midsagittal data), the one along which the lips lie farthest in front of the
    tongue tip (else the jaw sensor, else the tongue body), signed so that the lips are in front.
    Without UL and LL, or with no frame holding them, a DataError says to give the axes."""
    axes = [k for k in range(3) if k != planar_axis]
    idx = roles.resolve(("UL", "LL", *_BEHIND_THE_LIPS), names, path)
    ul_k, ll_k = idx["UL"], idx["LL"]
    hint = ' (give them in a role map: {"axes": {"vertical": "+y", "anterior": "-x"}})'
    if ul_k is None or ll_k is None:
        raise DataError("the axes of this format differ between labs and are guessed from the UL "
                        f"and LL sensors, which were not found among {list(names)}" + hint,
                        path=path, item="UL/LL")
    ul, ll = markers[:, ul_k, :], markers[:, ll_k, :]
    ok = np.isfinite(ul).all(axis=1) & np.isfinite(ll).all(axis=1)
    if not ok.any():
        raise DataError("no frame holds both UL and LL, so the axes cannot be guessed" + hint,
                        path=path, item="UL/LL")
    sep = np.median(ul[ok] - ll[ok], axis=0)
    v = max(axes, key=lambda k: abs(float(sep[k])))
    vertical = ("+" if sep[v] >= 0 else "-") + "xyz"[v]
    why = f"UL {abs(float(sep[v])):.1f} mm above LL"
    rest = [k for k in axes if k != v]
    lips = 0.5 * (ul + ll)
    for role in _BEHIND_THE_LIPS:
        k = idx[role]
        if k is None:
            continue
        s = markers[:, k, :]
        both = ok & np.isfinite(s).all(axis=1)
        if not both.any():
            continue
        front = np.median(lips[both] - s[both], axis=0)
        a = max(rest, key=lambda j: abs(float(front[j])))
        anterior = ("+" if front[a] >= 0 else "-") + "xyz"[a]
        return vertical, anterior, f"{why}; the lips {abs(float(front[a])):.1f} mm in front of {role}"
    if len(rest) == 1:
        return vertical, "+" + "xyz"[rest[0]], (f"{why}; no sensor behind the lips (TT, JAW, TB) "
                                                "to tell forwards from backwards: + assumed")
    raise DataError("the axes of this format differ between labs and are guessed from the "
                    "sensors, but no sensor behind the lips (TT, JAW, TB) tells forwards from "
                    "sideways" + hint, path=path)
