"""A fitted table's speakers: how one speaker's trajectories follow from the table.

A fit with ``[model] speakers`` (docs/FITTING.md, "Several speakers in one fit") records in the
table's metadata, per channel, how each speaker it saw is predicted:

* ``"offset"`` / ``"offset_scale"``: speaker s is a_s + b_s·F, F the table's own trajectory (shared
  dynamics, the reference speaker's targets; the reference speaker has a = 0, b = 1);
* ``"targets"``: speaker s has its own target per phoneme, every other parameter shared; the
  table's targets are the mean over the speakers (the population), the speakers' own in metadata.

``speaker_mapping(table, name)`` reads that back (an unknown speaker is an error listing the known
ones; a table fitted without speakers refuses any name), and ``SpeakerMapping`` applies it:
``evaluation_table`` (the table with the speaker's targets) then ``apply`` (a + b·F). Score and the
animation runtime both go through it, so a speaker's prediction is computed one way.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.errors import CoarticError
from coartic.table import ParameterTable

F64 = NDArray[np.float64]
MODES = ("offset", "offset_scale", "targets")


class SpeakerError(CoarticError, ValueError):
    """A ``--speaker`` the table cannot map: the message names the table and the known speakers."""


@dataclass(frozen=True)
class SpeakerMapping:
    """One speaker of a table: (a, b) per channel and, in ``"targets"`` mode, own targets per channel."""

    name: str
    mode: str
    coefficients: dict[str, tuple[float, float]]  # channel -> (offset a mm, scale b)
    targets: dict[str, dict[str, float]] = field(default_factory=dict)  # channel -> phoneme -> target

    def evaluation_table(self, table: ParameterTable) -> ParameterTable:
        """The table to evaluate for this speaker: its own targets in ``"targets"`` mode, else the
        table itself (the mapping is then ``apply`` on the trajectories)."""
        if not self.targets:
            return table
        out = copy.deepcopy(table)
        for ch, per in self.targets.items():
            for ph, value in per.items():
                if ph in out.values and ch in out.values[ph]:
                    out.values[ph][ch]["target"] = float(value)
        out.source = f"{table.source} (speaker {self.name})"
        return out

    def apply(self, channel: str, values: F64) -> F64:
        """a + b·values for ``channel`` (values evaluated with ``evaluation_table``)."""
        if channel not in self.coefficients:
            raise SpeakerError(f"speaker {self.name!r} has no mapping on channel {channel} (the fit saw this speaker "
                               f"on {', '.join(self.coefficients) or 'no channel'})")
        a, b = self.coefficients[channel]
        return a + b * np.asarray(values, dtype=np.float64)


def table_speakers(table: ParameterTable) -> tuple[str, ...]:
    """The speakers a table knows (in the fit's order, reference first); () without speakers."""
    meta = (table.metadata or {}).get("speakers")
    if not isinstance(meta, dict):
        return ()
    names: dict[str, None] = {}
    for per in (meta.get("coefficients") or {}).values():
        for s in per:
            names.setdefault(str(s), None)
    return tuple(names)


def speaker_mapping(table: ParameterTable, name: str | None) -> SpeakerMapping | None:
    """The mapping of speaker ``name`` (None for no ``--speaker``: the table as it is)."""
    if name is None:
        return None
    meta: Any = (table.metadata or {}).get("speakers")
    if not isinstance(meta, dict) or meta.get("mode") not in MODES:
        raise SpeakerError(
            f"{table.source}: --speaker {name!r}, but the table was fitted without speakers ([model] speakers) or "
            "carries no metadata (a CSV table does not: use the table.json beside it); leave out --speaker")
    known = table_speakers(table)
    if name not in known:
        raise SpeakerError(f"{table.source}: no speaker {name!r}; the table knows {', '.join(known)} "
                           f"(fitted with [model] speakers = {meta['mode']!r})")
    coefs: dict[str, tuple[float, float]] = {}
    for ch, per in (meta.get("coefficients") or {}).items():
        if name in per:
            c = per[name]
            coefs[ch] = (float(c.get("offset_mm", 0.0)), float(c.get("scale", 1.0)))
    targets: dict[str, dict[str, float]] = {}
    for ch, per in (meta.get("targets") or {}).items():
        if name in per:
            targets[ch] = {str(p): float(v) for p, v in per[name].items()}
    return SpeakerMapping(name, str(meta["mode"]), coefs, targets)
