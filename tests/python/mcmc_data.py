"""A small model-generated VCV channel for the MCMC tests and benchmark (ground truth known)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from coartic import _core
from coartic.estimation.data import ChannelData
from coartic.estimation.packing import Packing
from coartic.model import Utterance
from coartic.estimation.settings import DEFAULT_BETA_BOUNDS, DEFAULT_FIT_BOUNDS
from coartic.table import PARAMETERS

PHONEMES = ("#", "a", "i", "u", "p", "t", "l")
# target, alpha, theta_bw, theta_fw, c_bw, c_fw, k_r, sigma, psi, delta  (lower-lip opening, mm)
TRUTH = np.array(
    [
        [0.0, 0.6, 15.0, 15.0, 1.0, 1.0, 0.2, 0.0, 500.0, 0.0],  # pause: rest
        [12.0, 1.0, 30.0, 30.0, 1.0, 1.0, 0.3, 0.0, 500.0, 0.0],  # a: open (reference, alpha 1)
        [6.0, 0.9, 35.0, 28.0, 1.1, 1.0, 0.3, 0.0, 500.0, 0.0],  # i
        [3.0, 1.2, 25.0, 35.0, 1.0, 1.2, 0.4, 0.0, 500.0, 0.01],  # u
        [-2.0, 2.0, 40.0, 45.0, 1.0, 1.0, 1.0, 0.0, 500.0, 0.0],  # p: closure, fully resistant
        [4.0, 0.8, 50.0, 40.0, 1.2, 1.0, 0.5, 0.0, 500.0, 0.0],  # t
        [5.0, 0.7, 45.0, 55.0, 1.0, 0.9, 0.3, 0.0, 500.0, -0.01],  # l
    ]
)
BETA = 1.0
NOISE = 0.1  # mm
RATE = 100.0


def utterances(
    consonants: tuple[str, ...] = ("p", "t", "l"),
    vowels: tuple[str, ...] = ("a", "i", "u"),
    repetitions: int = 3,
    seed: int = 1,
    noise: float = NOISE,
    pause: float = 0.25,
) -> list[Utterance]:
    """# V C V # at a normal and a fast rate, durations jittered ±10 %, sampled at 100 Hz, with noise."""
    rng = np.random.default_rng(seed)
    out: list[Utterance] = []
    for c in consonants:
        for v in vowels:
            for rate, scale in (("normal", 1.0), ("fast", 0.6)):
                for r in range(repetitions):
                    dur = np.array([pause, 0.15, 0.10, 0.15, pause])
                    dur[1:4] *= scale
                    dur *= rng.uniform(0.9, 1.1, size=5)
                    ends = np.cumsum(dur)
                    starts = np.concatenate([[0.0], ends[:-1]])
                    times = np.arange(0.0, ends[-1], 1.0 / RATE)
                    labels = ("#", v, c, v, "#")
                    u = Utterance(labels, starts, ends, times, name=f"{v}{c}{v}_{rate}_{r + 1}",
                                  observed={"LLO": np.zeros_like(times)}, valid={"LLO": np.ones(len(times), dtype=bool)},
                                  meta={"vowel": v, "consonant": c, "repetition": str(r + 1), "rate": rate})
                    out.append(u)
    data = ChannelData.build(out, "LLO", PHONEMES)
    clean = _core.evaluate(data.corpus, TRUTH, BETA, _core.ModelOptions("modified"))
    for k, u in enumerate(out):
        sl = data.utterance_samples(k)
        u.observed["LLO"] = clean[sl] + noise * rng.standard_normal(sl.stop - sl.start)
    return out


def channel(utts: list[Utterance]) -> ChannelData:
    return ChannelData.build(utts, "LLO", PHONEMES)


def packing(free_parameters: tuple[str, ...] = ("target", "alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "k_r", "delta"),
            base: NDArray[np.float64] | None = None) -> Packing:
    """Every non-pause phoneme's listed parameters free (alpha of the reference 'a' fixed)."""
    n = len(PHONEMES)
    free = np.zeros((n, len(PARAMETERS)), dtype=bool)
    for k, p in enumerate(PARAMETERS):
        free[1:, k] = p in free_parameters
    free[PHONEMES.index("a"), PARAMETERS.index("alpha")] = False
    lower = np.array([DEFAULT_FIT_BOUNDS.get(p, (-10.0, 20.0))[0] for p in PARAMETERS])[None].repeat(n, 0)
    upper = np.array([DEFAULT_FIT_BOUNDS.get(p, (-10.0, 20.0))[1] for p in PARAMETERS])[None].repeat(n, 0)
    return Packing(PHONEMES, free, False, lower, upper, DEFAULT_BETA_BOUNDS,
                   (TRUTH if base is None else base).copy(), BETA)
