"""The model's per-channel settings, each written once: name, default, allowed values, meaning.

A fit spec's ``[model]`` keys, a table's ``channels`` entries, ``[choose]`` grids and the report
read defaults and ranges from here, and the Rust core checks the same ranges (ModelOptions::
validate and validate_params; tests/python/test_table.py probes both and checks they agree).
The per-phoneme parameters' domains are ``coartic.table.MODEL_DOMAIN``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

INF = math.inf


@dataclass(frozen=True)
class Setting:
    """One channel setting: its default, what it may be (an interval of numbers, a choice of
    words, or true/false) and what it means in MODEL.md terms."""

    name: str
    default: Any
    meaning: str
    low: float = -INF
    high: float = INF
    open_lower: bool = False  # low itself excluded
    choices: tuple[str, ...] = ()
    flag: bool = False  # true or false

    @property
    def allowed(self) -> str:
        """What the setting may be, as the errors say it."""
        if self.flag:
            return "true or false"
        if self.choices:
            return "one of " + ", ".join(self.choices)
        return (("(" if self.open_lower or self.low == -INF else "[") + f"{self.low:g}, {self.high:g}"
                + (")" if self.high == INF else "]"))

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is not a value of this setting (words to follow ``name = value``), or None."""
        if self.flag:
            return None if isinstance(value, bool) else "is not true or false"
        if self.choices:
            return None if value in self.choices else f"is not {self.allowed}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return "is not a number"
        if not math.isfinite(value):
            return "is not finite"
        if (value <= self.low if self.open_lower else value < self.low) or value > self.high:
            return f"is outside {self.allowed}"
        return None


# Dominance time scale (MODEL.md §2.1): "centre" is the model of §2, "plateau" the rate-aware one.
DOMINANCES: tuple[str, ...] = ("centre", "plateau")

CHANNEL_SETTINGS: Mapping[str, Setting] = {s.name: s for s in (
    Setting("beta", 1.0, "β, how steeply the resistance ρ(u) = exp(−βu/(1−u)) falls towards its extent "
            "(MODEL.md §3.1)", 0.0),
    Setting("edge_extent", 1.0, "Λ, the extent (s) beyond the first and last target (MODEL.md §3.1)",
            0.0, open_lower=True),
    Setting("apex_fraction", 0.5, "a, where in its segment a phoneme's target time t_i lies (MODEL.md §1)",
            0.0, 1.0),
    Setting("dominance", "centre", "the dominance's time scale: from the target time (centre), or flat "
            "over h·d around it (plateau, rate-aware; docs/MODEL.md §2.1)", choices=DOMINANCES),
    Setting("plateau_fraction", 0.5, "h, the half-width of the plateau dominance's flat top in segment "
            "durations (docs/MODEL.md §2.1)", 0.0, 1.0),
    Setting("handover", False, "the forward side of a dominance takes θ_fw, c_fw from the next "
            "phoneme (rate-aware; docs/MODEL.md §2.1)", flag=True),
)}
# The rate-aware options: written to a table only when they differ from their defaults, so a
# table of the centre model reads and writes as before they existed.
RATE_SETTINGS: tuple[str, ...] = ("dominance", "plateau_fraction", "handover")


def default(name: str) -> Any:
    """The default of channel setting ``name``."""
    return CHANNEL_SETTINGS[name].default
