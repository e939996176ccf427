"""Pauses as people label them: one pause label, three postures.

Label files use one pause label for very different postures (issue 25): the open-lipped breath
before a sentence, the closed lips after it, and, in a fast token, a 20 ms "pause" that is the
silent closure of a /p/. One pause target cannot fit them all. ``pause_postures`` gives each
its own row of the table:

- a pause before the first speech segment of an utterance stays ``#`` (``PAUSE``): the posture at
  rest before speaking, which the runtime takes as the neutral face and the readers as the rest
  frames of y_0;
- a pause after the last speech segment becomes ``#end`` (``FINAL_PAUSE``): its own target and θ,
  its α (where free) the initial pause's (``EDGE_TIED``);
- a pause between speech segments becomes ``#mid`` (``MEDIAL_PAUSE``): weak, its dominance
  magnitude α starts (and, where α is not free, stays) at ``MEDIAL_ALPHA``, so that its neighbours
  dominate it;
- a medial pause shorter than ``SHORT_PAUSE_S`` before a stop (the stop's silent closure) or
  between two segments of one phoneme (one articulation split in two) is no pause: it joins its
  neighbours (one segment of the stop, or of the phoneme, from the first's start to the last's end).

Every change is named (``PauseChange``) for the fit report. A fit with ``[model] pauses =
"postures"`` (the default) records ``POSTURES_RECORD`` in its table's metadata under
``RECORD_KEY``; whoever evaluates that table on labels (``coartic.model.trajectories``, ``coartic
score``, the runtime) applies the same rules (on utterances: ``coartic.model.utterances_for_table``
and ``utterances_with_postures``, beside the utterance type; this module works on labels and sits
below the model), and a table that records none (older tables, the
shipped Italian table) keeps one pause phoneme ``#``. The rules touch only ``#`` labels, so
applying them twice changes nothing.
"""

from __future__ import annotations

from collections.abc import Container, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.table import PAUSE

FINAL_PAUSE = "#end"
MEDIAL_PAUSE = "#mid"
PAUSE_PHONEMES = (PAUSE, FINAL_PAUSE, MEDIAL_PAUSE)
# The model's pause modes ([model] pauses): "postures" (this module's rules) or "one" (every pause
# is '#', as before issue 25).
PAUSE_MODES = ("postures", "one")
# A labelled pause this short next to a stop cannot be a pause of its own: stop closures last
# 50-100 ms at normal rates, and a silent interval under 100 ms is the closure (or an aligner's
# split of one segment), not a breath or a boundary.
SHORT_PAUSE_S = 0.1
# The medial pause's dominance magnitude relative to the speech segments' (α = 1 where α is not
# free): a tenth, so that a neighbour 50 ms away dominates it at any θ up to ln(10)/0.05 = 46 /s.
# No recording we have has a medial pause (the German EMA has none, the synthetic session's
# utterances are # V C V #), so it is not estimated; where α is free it starts here.
MEDIAL_ALPHA = 0.1
# The parameters the two edge pauses share (one value, the initial pause's row carries it, where
# both are free; coartic.estimation.parameters): a posture is a target, so each edge has its own
# target, but one dominance magnitude α. With an α of its own each edge pause bends its transition
# to the training rate's timing: on the synthetic session (one true rest posture, whose 75 ms target
# lag the fitted model lacks) the initial pause took α 15.9 and the final 0.46, the in-sample RMSE
# fell 0.80 -> 0.28 mm and the held-out speech RMSE at the fast rate rose 0.75 -> 0.99 mm (LLO),
# all of it in the first vowel (docs/REAL_DATA.md, "Why the synthetic figures moved").
EDGE_TIED = ("alpha",)
# The model phonemes whose segment is, or starts with, a silent oral closure (stops, affricates).
STOPS = frozenset({"p", "b", "t", "d", "k", "g", "ts", "dz", "tS", "dZ"})
# The pause row that stands in for one a table lacks: the edges for each other, the medial pause
# for the pause at rest before speaking.
STAND_INS: Mapping[str, tuple[str, ...]] = {PAUSE: (FINAL_PAUSE, MEDIAL_PAUSE), FINAL_PAUSE: (PAUSE, MEDIAL_PAUSE),
                                            MEDIAL_PAUSE: (PAUSE, FINAL_PAUSE)}
RECORD_KEY = "pauses"
POSTURES_RECORD: Mapping[str, Any] = {"mode": "postures", "short_pause_s": SHORT_PAUSE_S,
                                      "medial_alpha": MEDIAL_ALPHA}


def is_pause(label: str) -> bool:
    """A pause phoneme of any posture."""
    return label in PAUSE_PHONEMES


def speech_samples(labels: Sequence[str], segments: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Which samples lie inside a segment that is no pause, given each sample's segment index
    (``Utterance.sample_segments``: -1 outside every segment, which is not speech either)."""
    pause = np.array([is_pause(lab) for lab in labels] + [True])
    return ~pause[segments]


@dataclass(frozen=True)
class PauseChange:
    """One pause given another row, or joined to its neighbours."""

    index: int  # the pause's segment (counted from 0) in the labels as given
    start: float
    end: float
    became: str  # FINAL_PAUSE, MEDIAL_PAUSE, or the phoneme it joined
    why: str

    def text(self) -> str:
        return (f"the pause at {self.start:.3f}-{self.end:.3f} s (segment {self.index + 1}, "
                f"{1000 * (self.end - self.start):.0f} ms) {self.why}")


def pause_postures(labels: Sequence[str], starts: Sequence[float] | NDArray[np.float64],
                   ends: Sequence[float] | NDArray[np.float64], short: float = SHORT_PAUSE_S,
                   available: Container[str] | None = None
                   ) -> tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64], list[PauseChange]]:
    """The segments with their pauses given their posture (module docstring) and the changes made.
    Segments joined to a neighbour disappear into it, so the result may have fewer segments.
    ``available``: the phonemes a table has; a pause whose row it lacks (its training data had
    none: a table fitted on the first halves of utterances has no final pause) takes the nearest
    pause row it has (``STAND_INS``)."""
    labs = list(labels)
    s = np.asarray(starts, dtype=np.float64).copy()
    e = np.asarray(ends, dtype=np.float64).copy()
    speech = [i for i, lab in enumerate(labs) if not is_pause(lab)]
    if not speech:
        return tuple(labs), s, e, []
    first, last = speech[0], speech[-1]
    changes: list[PauseChange] = []
    joined: set[int] = set()  # pauses joined to a neighbour (dropped below)
    for i, lab in enumerate(labs):
        if lab != PAUSE or i < first:
            continue
        dur = float(e[i] - s[i])
        if i > last:
            labs[i] = FINAL_PAUSE
            changes.append(PauseChange(i, float(s[i]), float(e[i]), FINAL_PAUSE,
                                       f"ends the utterance: fitted as {FINAL_PAUSE!r}, its own target"))
            continue
        before, after = labs[i - 1], labs[i + 1]
        touching = abs(float(s[i]) - float(e[i - 1])) < 1e-6 and abs(float(s[i + 1]) - float(e[i])) < 1e-6
        if dur < short and touching and before == after and not is_pause(before):
            labs[i] = before
            joined.add(i)
            changes.append(PauseChange(i, float(s[i]), float(e[i]), before,
                                       f"lies between two segments of /{before}/ (shorter than {short * 1000:.0f} ms): "
                                       f"one /{before}/ with them"))
        elif dur < short and touching and after in STOPS:
            labs[i] = after
            joined.add(i)
            changes.append(PauseChange(i, float(s[i]), float(e[i]), after,
                                       f"is the silent closure of the /{after}/ after it (shorter than "
                                       f"{short * 1000:.0f} ms): part of that /{after}/"))
        else:
            labs[i] = MEDIAL_PAUSE
            changes.append(PauseChange(i, float(s[i]), float(e[i]), MEDIAL_PAUSE,
                                       f"lies inside the utterance: fitted as {MEDIAL_PAUSE!r}, weak (α {MEDIAL_ALPHA:g}: "
                                       "its neighbours dominate it)"))
    if available is not None:
        for i, lab in enumerate(labs):
            if is_pause(lab) and lab not in available:
                labs[i] = next((p for p in STAND_INS[lab] if p in available), lab)
    if joined:
        # one segment per run of the same phoneme that a joined pause connects
        out_l: list[str] = []
        out_s: list[float] = []
        out_e: list[float] = []
        for i, lab in enumerate(labs):
            if out_l and (i in joined or i - 1 in joined) and out_l[-1] == lab:
                out_e[-1] = float(e[i])
                continue
            out_l.append(lab)
            out_s.append(float(s[i]))
            out_e.append(float(e[i]))
        return tuple(out_l), np.array(out_s), np.array(out_e), changes
    return tuple(labs), s, e, changes


def recorded(metadata: Mapping[str, Any]) -> bool:
    """Whether a table's metadata says it was fitted with pause postures (``RECORD_KEY``)."""
    rec = metadata.get(RECORD_KEY)
    return isinstance(rec, Mapping) and rec.get("mode") == "postures"


def recorded_short(metadata: Mapping[str, Any]) -> float:
    """The short-pause threshold a table was fitted with (``SHORT_PAUSE_S`` if it records none)."""
    rec = metadata.get(RECORD_KEY)
    value = rec.get("short_pause_s") if isinstance(rec, Mapping) else None
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else SHORT_PAUSE_S
