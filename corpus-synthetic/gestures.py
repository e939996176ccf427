"""The second, harder flavour of the session: channels from critically damped gestures.

CORPUS.md asks for trajectories that the coarticulation model did not make, so that fits are also
tried on data where the model can only approximate. Here each channel is a critically damped
second-order system (a task-dynamics style gesture, as in Saltzman & Munhall 1989) driven by the
phoneme targets of the ground-truth table in turn:

    x'' = ω² (u − x) − 2 ω x'

u is the target of the phoneme whose gesture is active, and the gesture of each segment is active
from ``lead`` before its acoustic start to ``lead`` before its end (articulation precedes the
sound). The stiffness ω grows with the phoneme's dominance α in the table (ω = ω0 + ω1 α,
capped), so strongly specified gestures (bilabial closure, rounding) are fast and weak ones hardly
move the channel in their short segment. No library integrates a system whose stiffness and input
switch at arbitrary instants exactly, so the closed form of each constant piece is used:
with a = x0 − u and b = v0 + ω a,  x(t) = u + (a + b t) e^{−ωt},  v(t) = (b − ω (a + b t)) e^{−ωt}.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from coartic.table import CHANNELS, ParameterTable

F64 = npt.NDArray[np.float64]


def stiffness(table: ParameterTable, phoneme: str, channel: str, settings: dict[str, Any]) -> float:
    if phoneme == "#":
        return float(settings["pause_omega"])  # the return to rest is unhurried
    alpha = table.values[phoneme][channel]["alpha"]
    return float(min(settings["omega0"] + settings["omega1"] * alpha, settings["omega_max"]))


def gesture_channel(
    targets: Sequence[float], omegas: Sequence[float], onsets: F64, times: F64, x0: float
) -> F64:
    """x(times) of the damped system, starting at rest at x0, switching at ``onsets``.

    Segment i drives the system with target ``targets[i]`` and stiffness ``omegas[i]`` from
    ``onsets[i]`` to ``onsets[i+1]`` (the last one for ever); before ``onsets[0]`` it rests at x0.
    """
    out = np.full(times.shape, x0, dtype=np.float64)
    x, v, t0 = x0, 0.0, float(onsets[0])
    bounds = list(onsets[1:]) + [np.inf]
    for u, w, t1 in zip(targets, omegas, bounds):
        sel = (times >= t0) & (times < t1)
        a = x - u
        b = v + w * a
        dt = times[sel] - t0
        out[sel] = u + (a + b * dt) * np.exp(-w * dt)
        if np.isfinite(t1):
            d = t1 - t0
            e = np.exp(-w * d)
            x, v = u + (a + b * d) * e, (b - w * (a + b * d)) * e
            t0 = float(t1)
    return out


def gesture_trajectories(
    table: ParameterTable,
    labels: Sequence[str],
    starts: F64,
    ends: F64,
    times: F64,
    settings: dict[str, Any],
) -> dict[str, F64]:
    """Every channel of one utterance from critically damped gestures towards the table's targets."""
    onsets = np.maximum(np.asarray(starts, dtype=np.float64) - settings["lead"], times[0])
    onsets[0] = times[0]
    out = {}
    for ch in CHANNELS:
        targets = [table.values[p][ch]["target"] for p in labels]
        omegas = [stiffness(table, p, ch, settings) for p in labels]
        out[ch] = gesture_channel(targets, omegas, onsets, times, targets[0])
    return out
