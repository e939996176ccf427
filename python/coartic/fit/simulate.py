"""Utterances made by the model itself from known parameters (plus noise): for tests, benchmarks and
checks of recovery where the truth is known. Not a corpus generator (that is corpus-synthetic/)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from coartic import _core
from coartic.model import Utterance, build_corpus
from coartic.settings import default
from coartic.table import PAUSE

# A small, identifiable VCV model for one channel (rows: # a i p t l; columns in PARAMETERS order).
PHONEMES: tuple[str, ...] = ("#", "a", "i", "p", "t", "l")
TRUTH: NDArray[np.float64] = np.array([
    # target alpha th_bw th_fw c_bw c_fw k_r  sigma psi   delta
    [0.0,    2.0,  15.0, 10.0, 1.0, 1.0, 1.0, 0.0,  500., 0.0],    # pause: rest posture
    [12.0,   1.0,  20.0, 20.0, 1.0, 1.0, 0.4, 0.0,  500., 0.0],    # /a/ open
    [6.0,    1.3,  25.0, 22.0, 1.0, 1.0, 0.4, 0.0,  500., 0.0],    # /i/
    [-2.5,   2.5,  40.0, 50.0, 1.3, 1.3, 1.0, 0.0,  500., 0.0],    # /p/ closure, always reached
    [3.0,    0.6,  45.0, 55.0, 1.0, 1.0, 0.3, 0.0,  500., 0.0],    # /t/ lips free
    [4.0,    0.7,  35.0, 35.0, 1.0, 1.0, 0.3, 0.0,  500., 0.0],    # /l/
])
DURATIONS = {"#": 0.30, "a": 0.16, "i": 0.14, "p": 0.10, "t": 0.09, "l": 0.07}


def vcv_utterances(rng: np.random.Generator, params: NDArray[np.float64] = TRUTH,
                   phonemes: Sequence[str] = PHONEMES, vowels: Sequence[str] = ("a", "i"),
                   consonants: Sequence[str] = ("p", "t", "l"), repetitions: int = 3,
                   rates: dict[str, float] | None = None, noise: float = 0.1, channel: str = "LLO",
                   rate_hz: float = 100.0, beta: float = default("beta")) -> list[Utterance]:
    """# V C V # for every vowel, consonant, repetition and rate, evaluated by the Rust core + noise."""
    rates = rates or {"normal": 1.0, "fast": 0.6}
    out: list[Utterance] = []
    for v in vowels:
        for c in consonants:
            for rate, factor in rates.items():
                for rep in range(1, repetitions + 1):
                    labels = ("#", v, c, v, "#")
                    d = np.array([DURATIONS[x] * (1.0 if x == PAUSE else factor) for x in labels])
                    d *= rng.uniform(0.9, 1.1, d.size)
                    ends = np.cumsum(d)
                    starts = np.concatenate([[0.0], ends[:-1]])
                    t = np.arange(0.0, ends[-1], 1.0 / rate_hz)
                    u = Utterance(labels, starts, ends, t, name=f"{v}{c}{v}_{rate}_{rep}",
                                  meta={"stimulus": f"{v} {c} {v}", "vowel": v, "consonant": c,
                                        "repetition": str(rep), "rate": rate})
                    f = _core.evaluate(build_corpus([u], phonemes), params, beta,
                                       _core.ModelOptions("modified", 0.5, 1.0))
                    u.observed[channel] = np.asarray(f) + rng.normal(0.0, noise, t.size)
                    u.valid[channel] = np.ones(t.size, dtype=bool)
                    out.append(u)
    return out
