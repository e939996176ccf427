"""A fitted table's emotions: the table an emotion at an intensity speaks with.

A fit with ``[model] emotions = "targets"`` (docs/EMOTIONS.md) records in ``metadata.emotions``, per
channel, each emotion's deviations d = T(p|e) − T(p|neutral) from the table's (neutral) targets.
``emotion_table(table, "joy", 0.6)`` is the table with every target T + 0.6·d: the model is linear
in the targets, so where the emotions share the dynamics (``[model] emotions = "targets"``) intensity s
gives F_neutral + s·(F_e − F_neutral) exactly; a table fitted with ``"targets+dynamics"`` also has
each emotion's log deviations of α, θ_bw, θ_fw, applied as v·exp(s·δ). Where a phoneme makes a contact (k_R = 1 on ULO or LLO: the closure of /p b m/, the
lower lip on the teeth for /f v/) its target there is kept neutral at every intensity: the
contact is phonological, and Magno Caldognetto et al. (2003, 2004) found lip opening keeping the
phonological contrasts under every emotion.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
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


# the manifest column holding a trial's known intensity (0 neutral, 1 as recorded); a trial without
# it (no such column, or an empty cell) counts as 1
INTENSITY_COLUMN = "intensity"


def trial_intensity(u: Utterance) -> float:
    """The intensity an utterance's emotion was recorded at (manifest column ``intensity``; missing or
    empty: 1): its deviation from neutral is scaled by it, in the fit and in held-out scoring. A value
    that is not a number from 0 to ``MAX_INTENSITY`` is refused, naming the utterance."""
    raw = str(u.meta.get(INTENSITY_COLUMN, "") or "").strip()
    if not raw:
        return 1.0
    try:
        s = float(raw)
    except ValueError:
        s = math.nan
    if not (math.isfinite(s) and 0.0 <= s <= MAX_INTENSITY):
        raise EmotionError(f"utterance {u.name!r} ({u.meta.get('file', '')}): manifest column "
                           f"{INTENSITY_COLUMN!r} = {raw!r}: expected a number from 0 (neutral) to "
                           f"{MAX_INTENSITY:g} (1 as recorded), or an empty cell (counts as 1)")
    return s


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
        # [model] emotions = "targets+dynamics": the emotion's own rates, log deviations scaled likewise
        for q, dyn in (per.get("dynamics") or {}).items():
            for ph, d in (dyn.get("deviations") or {}).get(emotion, {}).items():
                row = out.values.get(ph, {}).get(ch)
                if row is not None:
                    row[q] = float(row[q] * math.exp(intensity * float(d)))
    out.source = f"{table.source} ({emotion} at {intensity:g})"
    # what the runtime shows outside the mouth (coartic.runtime.expression); the targets carry the rest
    out.metadata = {**(out.metadata or {}), "expression": {"emotion": emotion, "intensity": float(intensity)}}
    return out


def evaluate_by_emotion(table: ParameterTable, channel: str, utterances: Sequence[Utterance]) -> list[F64]:
    """One channel over many utterances, each with its own emotion's fitted targets (the manifest
    column the table was fitted with; an utterance without one, or with an emotion the table does
    not know, is predicted neutral) at its intensity (``trial_intensity``): the held-out prediction
    of a table fitted with emotions."""
    known = table_emotions(table)
    if not known:
        return evaluate_corpus(table, channel, utterances)
    column = str(table.metadata["emotions"].get("column", "emotion"))
    groups: dict[tuple[str, float], list[int]] = {}
    for i, u in enumerate(utterances):
        e = str(u.meta.get(column, known[0]))
        e = e if e in known else known[0]
        groups.setdefault((e, 1.0 if e == known[0] else trial_intensity(u)), []).append(i)
    out: list[F64 | None] = [None] * len(utterances)
    for (e, s), idx in groups.items():
        values = evaluate_corpus(emotion_table(table, e, s, keep_contacts=False), channel,
                                 [utterances[i] for i in idx])
        for i, v in zip(idx, values):
            out[i] = v
    return [v for v in out if v is not None]


# ----------------------------------------------------------------------------- emotion over time

# An emotion's onset and offset: a raised-cosine ramp of this length centred on each span boundary
# (an expression takes a few hundred ms to come and go; a step would jump the lips between frames).
RAMP_S = 0.2


@dataclass(frozen=True)
class EmotionSpan:
    """One span of a markup: ``emotion`` at ``intensity`` from ``start`` to ``end`` (s)."""

    start: float
    end: float
    emotion: str
    intensity: float = 1.0


def read_emotion_spans(path: str | Path) -> list[EmotionSpan]:
    """A TSV of spans, one per line: ``start end emotion [intensity]`` (s, s, name, 0-1.5; tabs or
    spaces; ``#`` starts a comment). Errors name the file, the line and the field."""
    from coartic.textfile import read_text

    path = Path(path)
    spans: list[EmotionSpan] = []
    for n, line in enumerate(read_text(path, "emotion spans").splitlines(), start=1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) not in (3, 4):
            raise EmotionError(f"{path}, line {n}: expected 'start end emotion [intensity]', got {len(fields)} fields")
        try:
            start, end = float(fields[0]), float(fields[1])
            intensity = float(fields[3]) if len(fields) == 4 else 1.0
        except ValueError:
            raise EmotionError(f"{path}, line {n}: start, end and intensity must be numbers: {line.strip()!r}") from None
        if not (math.isfinite(start) and math.isfinite(end) and 0.0 <= start < end):
            raise EmotionError(f"{path}, line {n}: a span needs 0 <= start < end, got {start:g} to {end:g}")
        if not (math.isfinite(intensity) and 0.0 <= intensity <= MAX_INTENSITY):
            raise EmotionError(f"{path}, line {n}: intensity {fields[3]!r} is not within 0-{MAX_INTENSITY:g}")
        if spans and start < spans[-1].end:
            raise EmotionError(f"{path}, line {n}: the span starting at {start:g} s overlaps the one before "
                               f"(ending at {spans[-1].end:g} s): spans are in time order, one emotion at a time")
        spans.append(EmotionSpan(start, end, fields[2], intensity))
    if not spans:
        raise EmotionError(f"{path}: no span (lines 'start end emotion [intensity]')")
    return spans


def with_emotion_spans(table: ParameterTable, spans: Sequence[EmotionSpan], where: str = "") -> ParameterTable:
    """The table speaking the spans' emotions over time: its targets are the neutral ones, and
    ``metadata.expression.spans`` tells ``runtime.animate`` to add each emotion's deviation trajectory
    weighted by its ramped intensity (``span_weights``), and the expression outside the mouth to follow."""
    known = table_emotions(table)
    for s in spans:
        if not known:
            emotion_table(table, s.emotion)  # the error for a table without emotions
        if s.emotion not in known:
            raise EmotionError(f"{where or table.source}: no emotion {s.emotion!r} (span {s.start:g}-{s.end:g} s); "
                               f"the table knows {', '.join(known)}")
    out = copy.deepcopy(table)
    out.metadata["expression"] = {"spans": [[s.start, s.end, s.emotion, s.intensity] for s in spans]}
    return out


def span_weights(spans: Sequence[Sequence[Any]], times: F64, ramp: float = RAMP_S) -> dict[str, F64]:
    """emotion -> its intensity at ``times``: within a span its intensity, ramped in and out by a
    raised cosine of ``ramp`` seconds centred on the span's boundaries."""
    out: dict[str, F64] = {}
    t = np.asarray(times, dtype=np.float64)
    for start, end, emotion, intensity in spans:
        def edge(x: F64) -> F64:  # 0 before, 1 after, raised cosine over the ramp
            u = np.clip(x / ramp + 0.5, 0.0, 1.0)
            return np.asarray(0.5 - 0.5 * np.cos(np.pi * u), dtype=np.float64)
        w = float(intensity) * edge(t - float(start)) * edge(float(end) - t)
        out[str(emotion)] = out.get(str(emotion), np.zeros_like(t)) + w
    return out


def expression_weights(table: ParameterTable | None, times: F64) -> dict[str, F64]:
    """emotion -> intensity per time of the expression a table speaks with (``emotion_table``: one
    emotion throughout; ``with_emotion_spans``: the spans'); {} for none."""
    meta: Any = (table.metadata or {}).get("expression") if table is not None else None
    if not isinstance(meta, dict):
        return {}
    if "spans" in meta:
        return span_weights(meta["spans"], times)
    return {str(meta["emotion"]): np.full(np.shape(times), float(meta["intensity"]))}
