"""A fitted table's emotions: the table an emotion at an intensity speaks with.

A fit with ``[model] emotions = "targets"`` (docs/EMOTIONS.md) records in ``metadata.emotions``, per
channel, each emotion's deviations d = T(p|e) − T(p|neutral) from the table's (neutral) targets.
``emotion_table(table, "joy", 0.6)`` is the table with every target T + 0.6·d: the model is linear
in the targets and the emotions share the dynamics, so intensity s gives F_neutral + s·(F_e − F_neutral)
exactly. Where a phoneme makes a contact (k_R = 1 on ULO or LLO: the closure of /p b m/, the
lower lip on the teeth for /f v/) its target there is kept neutral at every intensity: the
contact is phonological, and Magno Caldognetto et al. (2003, 2004) found lip opening keeping the
phonological contrasts under every emotion.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.errors import CoarticError
from coartic.model import Utterance, evaluate_corpus
from coartic.table import ParameterTable

F64 = NDArray[np.float64]

CONTACT_CHANNELS = ("ULO", "LLO")
CONTACT_K_R = 1.0 - 1e-6  # k_R counts as 1 from here (a fitted table holds 0.9999996)
MAX_INTENSITY = 1.5  # past the recorded expression, extrapolation: refused beyond this


class EmotionError(CoarticError, ValueError):
    """An ``--emotion`` the table cannot speak, or an intensity out of range: the message names the
    table and the known emotions."""


def table_emotions(table: ParameterTable) -> tuple[str, ...]:
    """The emotions a table knows, the neutral one first; () for a table fitted without emotions."""
    meta: Any = (table.metadata or {}).get("emotions")
    if not isinstance(meta, dict) or not isinstance(meta.get("channels"), dict):
        return ()
    names: dict[str, None] = {str(meta.get("neutral", "neutral")): None}
    for per in meta["channels"].values():
        for e in (per.get("deviations") or {}):
            names.setdefault(str(e), None)
    return tuple(names)


def emotion_table(table: ParameterTable, emotion: str | None, intensity: float = 1.0,
                  keep_contacts: bool = True) -> ParameterTable:
    """The table speaking ``emotion`` at ``intensity`` (0 = neutral, 1 = as recorded); ``None`` or the
    neutral emotion: the table itself. ``keep_contacts`` False: every fitted target as fitted, the
    contacts too (what scoring a fit compares with the data)."""
    if emotion is None:
        return table
    if not (isinstance(intensity, (int, float)) and math.isfinite(intensity) and 0.0 <= intensity <= MAX_INTENSITY):
        raise EmotionError(f"--intensity {intensity!r}: expected a number from 0 (neutral) to {MAX_INTENSITY:g} "
                           "(1 is the emotion as recorded)")
    known = table_emotions(table)
    if not known:
        raise EmotionError(f"{table.source}: --emotion {emotion!r}, but the table was fitted without emotions "
                           "([model] emotions = \"targets\", docs/EMOTIONS.md) or carries no metadata (a CSV "
                           "table does not: use the table.json beside it); leave out --emotion")
    if emotion not in known:
        raise EmotionError(f"{table.source}: no emotion {emotion!r}; the table knows {', '.join(known)}")
    if emotion == known[0]:
        return table
    out = copy.deepcopy(table)
    for ch, per in table.metadata["emotions"]["channels"].items():
        for ph, d in (per.get("deviations") or {}).get(emotion, {}).items():
            row = out.values.get(ph, {}).get(ch)
            if row is None:
                continue
            if keep_contacts and ch in CONTACT_CHANNELS and row["k_r"] >= CONTACT_K_R:
                continue  # the contact is phonological: kept at every intensity
            row["target"] = float(row["target"] + intensity * float(d))
    out.source = f"{table.source} ({emotion} at {intensity:g})"
    return out


def evaluate_by_emotion(table: ParameterTable, channel: str, utterances: Sequence[Utterance]) -> list[F64]:
    """One channel over many utterances, each with its own emotion's fitted targets (the manifest
    column the table was fitted with; an utterance without one, or with an emotion the table does
    not know, is predicted neutral): the held-out prediction of a table fitted with emotions."""
    known = table_emotions(table)
    if not known:
        return evaluate_corpus(table, channel, utterances)
    column = str(table.metadata["emotions"].get("column", "emotion"))
    groups: dict[str, list[int]] = {}
    for i, u in enumerate(utterances):
        e = str(u.meta.get(column, known[0]))
        groups.setdefault(e if e in known else known[0], []).append(i)
    out: list[F64 | None] = [None] * len(utterances)
    for e, idx in groups.items():
        values = evaluate_corpus(emotion_table(table, e, 1.0, keep_contacts=False), channel,
                                 [utterances[i] for i in idx])
        for i, v in zip(idx, values):
            out[i] = v
    return [v for v in out if v is not None]
