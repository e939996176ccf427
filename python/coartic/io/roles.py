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

from coartic.io.errors import DataError, parse_json

MARKER_ROLES = ("NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN")
EMA_ROLES = ("UL", "LL", "JAW", "LC", "LC_L", "LC_R", "TT", "TB")
# TT: tongue tip; TB: tongue body (the dorsum sensor behind the tip): the tongue channels' sensors.
ROLES = (*MARKER_ROLES, "JAW", "LC", "TT", "TB")
# Usual sensor names on EMA systems (Carstens AG50x, NDI Wave), lower case.
EMA_SENSOR_GUESSES: dict[str, tuple[str, ...]] = {
    "UL": ("ul", "upper_lip", "upperlip", "ulip"),
    "LL": ("ll", "lower_lip", "lowerlip", "llip"),
    "JAW": ("jw", "jaw", "li", "ji", "lower_incisor", "lowerincisor", "mand"),
    "LC": ("lc", "lip_corner", "lipcorner", "corner"),
    "TT": ("tt", "t_tip", "tongue_tip", "tonguetip", "ttip", "tip"),
    # German EMU data: tt, tm (mid), tb (back); MOCHA: tt, tb (body), td (dorsum)
    "TB": ("tb", "t_back", "tongue_body", "tonguebody", "tongue_back", "tback", "tbody", "tdor"),
}
_AXES = ("x", "y", "z")
AXIS_KEYS = ("vertical", "anterior")


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
        return cls(roles, str(axes.get("vertical", "+z")), str(axes.get("anterior", "-y")), source)

    @classmethod
    def from_file(cls, path: str | PathLike[str]) -> RoleMap:
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise DataError(f"cannot read the role map: {e}", path=p) from None
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
    return RoleMap(roles, base.vertical, base.anterior, base.source)
