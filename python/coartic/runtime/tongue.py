"""The tongue's trajectories for an animation: from the table's tongue channels (TTH TTA TBH TBA,
docs/DATA.md) where it has them, else from the shipped Italian table's (fitted on the EMA tongue of
the synthetic session's Italian flavour), both through the model itself (coartic.runtime.animate),
so the tongue coarticulates like the lips. A phoneme the shipped table lacks (a label of a table of
one's own) takes a class default, below.

The class defaults are mm from rest in the head frame (what EMA measures), the sizes of the shipped
table's ground truth (corpus-synthetic/ground_truth.py): the tip up ~9 mm to the teeth and the
ridge at /t d n l/, the body up ~11 mm to the velum at /k g/, lowered with the jaw at /a/, forwards
at /i/ and back at /o u/. Labials and sounds no class covers take little part (low dominance), so
the tongue moves through them from one neighbour to the next.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.runtime.animate import Animation, animate, neutral_posture
from coartic.runtime.shipped import SHIPPED_TABLE, load_shipped_table, shipped_table_path
from coartic.table import PAUSE, TONGUE_CHANNELS, ParameterTable

# (TTH, TTA, TBH, TBA) mm from rest, and whether the tongue makes a contact there (k_R 1, strong)
_CLASSES: dict[str, tuple[tuple[float, float, float, float], str]] = {
    "alveolar_stop": ((9.0, 2.5, 2.0, 0.5), "contact"),
    "lateral": ((9.5, 1.0, 0.5, -0.5), "contact"),
    "trill": ((7.5, 0.5, 1.0, -1.0), "strong"),
    "sibilant": ((7.0, 1.5, 3.0, 0.5), "strong"),
    "postalveolar": ((7.0, -1.5, 6.0, 0.0), "strong"),
    "palatal": ((3.0, 0.5, 11.0, 2.0), "contact"),
    "velar": ((-1.5, -2.0, 11.5, -3.0), "contact"),
    "i": ((2.0, 2.0, 8.0, 3.0), "vowel"),
    "e": ((0.0, 1.5, 5.0, 2.0), "vowel"),
    "E": ((-3.0, 0.5, 1.0, 1.0), "vowel"),
    "a": ((-9.0, -1.5, -8.0, -2.0), "vowel"),  # the jaw's ~10 mm takes the tongue down with it
    "O": ((-6.0, -3.0, -3.0, -5.0), "vowel"),
    "o": ((-3.5, -3.5, 1.0, -5.5), "vowel"),
    "u": ((-2.0, -4.0, 5.0, -6.0), "vowel"),
    "free": ((0.0, 0.0, 0.0, 0.0), "free"),
}
PHONEME_CLASS: dict[str, str] = {
    **{p: "alveolar_stop" for p in ("t", "d", "n", "tt", "dd", "nn")},
    **{p: "lateral" for p in ("l", "ll")},
    **{p: "trill" for p in ("r", "rr")},
    **{p: "sibilant" for p in ("s", "z", "ts", "dz", "ss")},
    **{p: "postalveolar" for p in ("tS", "dZ", "S")},
    **{p: "palatal" for p in ("J", "L", "j")},
    **{p: "velar" for p in ("k", "g", "kk", "gg")},
    **{v: v for v in ("i", "e", "E", "a", "O", "o", "u")},
    "w": "u",
}
# dominance of each kind: alpha, theta (both sides), c (both sides), k_r
_DOMINANCE: dict[str, tuple[float, float, float, float]] = {
    "contact": (3.0, 40.0, 1.3, 1.0), "strong": (2.0, 35.0, 1.2, 0.8), "vowel": (1.0, 15.0, 1.0, 0.5),
    "free": (0.05, 10.0, 1.0, 0.0), "rest": (1.0, 15.0, 1.0, 1.0),  # the pause is the reference: alpha 1
}


def default_tongue_table(phonemes: list[str], source: str = "coartic default tongue") -> ParameterTable:
    """A table of the tongue channels for `phonemes`, by phoneme class (module docstring)."""
    doc: dict[str, Any] = {"schema": "coartic.table/1", "variant": "modified",
                           "channels": {c: {"unit": "mm", "reference_phoneme": PAUSE} for c in TONGUE_CHANNELS},
                           "phonemes": {}, "metadata": {"method": "coartic.runtime.tongue default, by phoneme class"}}
    for ph in phonemes:
        kind = "rest" if ph == PAUSE else _CLASSES[PHONEME_CLASS.get(ph, "free")][1]
        targets = (0.0, 0.0, 0.0, 0.0) if ph == PAUSE else _CLASSES[PHONEME_CLASS.get(ph, "free")][0]
        alpha, theta, c, k_r = _DOMINANCE[kind]
        doc["phonemes"][ph] = {ch: {"target": t, "alpha": alpha, "theta_bw": theta, "theta_fw": theta, "c_bw": c,
                                    "c_fw": c, "k_r": k_r, "sigma": 0.0, "psi": 500.0, "delta": 0.0}
                               for ch, t in zip(TONGUE_CHANNELS, targets)}
    return ParameterTable.from_json_dict(doc, source)


def shipped_tongue_table(phonemes: list[str]) -> ParameterTable:
    """The default tongue for `phonemes`: the shipped table's tongue channels, and for a phoneme
    it lacks (or a shipped table without them) the class default of `default_tongue_table`.

    Made once per set of phonemes and shipped file (its path, size and time of change): every FAP
    sequence of an animation without tongue channels asks for it (coartic.runtime.fap, several times
    per `coartic speak`), and reading and validating the whole shipped table cost 15 ms each time.
    The table is shared: its users read it (they animate it), as they read any table."""
    path = shipped_table_path()
    try:
        st = path.stat()
        version: tuple[str, int, int] | None = (str(path), st.st_size, st.st_mtime_ns)
    except OSError:
        version = None  # load_shipped_table says what is wrong
    if version is None:
        return _shipped_tongue_table(tuple(phonemes))
    return _cached_shipped_tongue_table(tuple(phonemes), version)


@functools.lru_cache(maxsize=64)
def _cached_shipped_tongue_table(phonemes: tuple[str, ...], version: tuple[str, int, int]) -> ParameterTable:
    return _shipped_tongue_table(phonemes)


def _shipped_tongue_table(phonemes_given: tuple[str, ...]) -> ParameterTable:
    phonemes = list(phonemes_given)
    shipped = load_shipped_table()
    if all(c in shipped.channels for c in TONGUE_CHANNELS):
        # the channels' reference phoneme (alpha = 1) comes along, said or not
        phonemes = sorted(set(phonemes) | {shipped.channels[c].reference_phoneme for c in TONGUE_CHANNELS})
    doc = default_tongue_table(phonemes).to_json_dict()
    if all(c in shipped.channels for c in TONGUE_CHANNELS):
        sdoc = shipped.to_json_dict()
        doc["channels"] = {c: sdoc["channels"][c] for c in TONGUE_CHANNELS}
        for ph in phonemes:
            if ph in shipped.values:
                doc["phonemes"][ph] = {c: sdoc["phonemes"][ph][c] for c in TONGUE_CHANNELS}
        doc["metadata"] = {"method": f"the tongue channels of {SHIPPED_TABLE} (shipped with coartic); "
                                     "the class default of coartic.runtime.tongue for phonemes it lacks"}
    return ParameterTable.from_json_dict(doc, f"{SHIPPED_TABLE} (tongue)")


def tongue_channels(animation: Animation) -> tuple[dict[str, NDArray[np.float64]], dict[str, float], list[str]]:
    """The tongue channels at the animation's frames, their rest values, and which of them came from
    the animation's table (the others from the shipped table's, `shipped_tongue_table`)."""
    table = animation.table
    have = [c for c in TONGUE_CHANNELS if table is not None and c in table.channels
            and all(c in table.values.get(p, {}) for p in set(animation.segments.labels))]
    out: dict[str, NDArray[np.float64]] = {}
    rest: dict[str, float] = {}
    if table is not None and have:
        anim = animate(table, animation.segments, animation.fps, duration=animation.duration, channels=have)
        out.update(anim.channels)
        rest.update(neutral_posture(table, have))
    missing = [c for c in TONGUE_CHANNELS if c not in have]
    if missing:
        default = shipped_tongue_table(sorted(set(animation.segments.labels) | {PAUSE}))
        anim = animate(default, animation.segments, animation.fps, duration=animation.duration, channels=missing)
        out.update(anim.channels)
        rest.update(neutral_posture(default, missing))
    for c in out:
        out[c] = out[c][: animation.n_frames]
    return out, rest, have
