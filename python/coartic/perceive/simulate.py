"""Simulated participants: answers drawn from a stated model, stored through the same path as the
browser's (storage.Store.record), to check a study's power and the analysis before real people come.

Each participant and each item has a random effect (normal, sd `participant_sd` and `item_sd`, on
the logit scale for right/wrong answers and preferences, in points for MUSHRA ratings); each
condition has its planted effect (`effects`, 0 for those not named), SNR adds `snr_slope` per dB.

- intelligibility / emotion: P(right) = logistic(intercept + effect[condition] + snr_slope * snr +
  u_participant + v_item); a wrong answer is another choice, four times likelier within the right
  answer's viseme (the confusions a face cannot resolve); typed answers keep each word with P(right);
- preference: P(choose a, shown first, over b) = logistic(effect[a] - effect[b] + position);
- MUSHRA: rating = clip(round(mushra_mean + effect[condition] + u + v + noise), 0, 100), the hidden
  reference at reference_mean (sd reference_sd);
- attention checks are passed with P = attention_pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coartic.perceive.design import words
from coartic.perceive.storage import Store


@dataclass(frozen=True)
class Plant:
    """The model simulated answers are drawn from (see the module docstring)."""

    effects: dict[str, float] = field(default_factory=dict)
    intercept: float = 0.5
    snr_slope: float = 0.15
    participant_sd: float = 0.5
    item_sd: float = 0.3
    position: float = 0.0
    attention_pass: float = 0.97
    mushra_mean: float = 60.0
    reference_mean: float = 97.0
    reference_sd: float = 2.0
    rating_sd: float = 8.0


def _logistic(x: float) -> float:
    return float(1.0 / (1.0 + np.exp(-x)))


def _viseme(answer: str) -> str:
    from coartic.runtime.rigs import PHONEME_VISEME

    return PHONEME_VISEME.get(answer, answer)


def _wrong_choice(rng: np.random.Generator, expected: str, choices: list[str]) -> str:
    others = [c for c in choices if c != expected]
    if not others:
        return expected
    w = np.array([4.0 if _viseme(c) == _viseme(expected) else 1.0 for c in others])
    return others[int(rng.choice(len(others), p=w / w.sum()))]


def simulate(store: Store, n: int, plant: Plant, seed: int) -> int:
    """`n` simulated participants answer every trial; returns the number of answers stored."""
    m = store.manifest
    rng = np.random.default_rng([seed, 271828])
    item_u = rng.normal(0.0, plant.item_sd, len(m["items"]))
    reference = {c["name"] for c in m["conditions"] if c.get("reference")}
    stored = 0
    for _ in range(n):
        p = store.start(simulated=True)
        u = rng.normal(0.0, plant.participant_sd)
        for k, t in enumerate(p.trials):
            response: Any
            if t["kind"] == "attention":
                ok = rng.random() < plant.attention_pass
                response = t["answer"] if ok else _wrong_choice(rng, t["answer"], t["choices"])
            elif m["design"] in ("intelligibility", "emotion"):
                eta = plant.intercept + plant.effects.get(t["conditions"][0], 0.0) + u + item_u[t["item"]]
                if t["snr_db"] is not None:
                    eta += plant.snr_slope * t["snr_db"]
                pr = _logistic(eta)
                if m["response"] == "text":
                    response = " ".join(w for w in words(t["answer"]) if rng.random() < pr) or "?"
                else:
                    response = t["answer"] if rng.random() < pr else _wrong_choice(rng, t["answer"], m["choices"])
            elif m["design"] == "preference":
                a, b = t["conditions"]
                # a is the face shown first (design.stimulus_trials)
                eta = plant.effects.get(a, 0.0) - plant.effects.get(b, 0.0) + plant.position
                response = a if rng.random() < _logistic(eta) else b
            else:
                response = {}
                for c in t["conditions"]:
                    mean = plant.reference_mean if c in reference else plant.mushra_mean + plant.effects.get(c, 0.0)
                    if c in reference:
                        r = mean + rng.normal(0, plant.reference_sd)
                    else:
                        r = mean + 10 * u + 10 * item_u[t["item"]] + rng.normal(0, plant.rating_sd)
                    response[c] = int(np.clip(np.rint(r), 0, 100))
            stored += store.record(p, k, response, rt_ms=int(rng.integers(400, 3000)))
    return stored


def parse_effects(pairs: list[str], conditions: list[str]) -> dict[str, float]:
    """`["keyframe=-1.0"]` → {"keyframe": -1.0}, each name checked against the study's conditions."""
    from coartic.errors import UsageError

    out: dict[str, float] = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or name not in conditions:
            raise UsageError(f"--effect {pair!r}: give CONDITION=NUMBER with a condition of the study "
                             f"({', '.join(conditions)})")
        try:
            out[name] = float(value)
        except ValueError:
            raise UsageError(f"--effect {pair!r}: {value!r} is not a number") from None
    return out
