"""Each participant's trials: which stimuli, in which order, with which attention checks.

Everything derives from the study's seed and the participant's number (their arrival order,
counted from 0), so a participant's trials can be rebuilt exactly; the server still stores them
with the participant when they start, so that resuming never depends on this code's version.

- counterbalance "full": every stimulus (intelligibility, emotion), every pair of conditions per
  item and SNR (preference), every item (MUSHRA: all its conditions on one page);
- counterbalance "latin": each item once per SNR, in condition (item + number) mod n_conditions, so
  that over n_conditions participants every item is seen in every condition once (a Latin square);
- preference: which condition is shown first alternates over pairs, items and participants;
  MUSHRA: the conditions' order on the page is shuffled per trial;
- the order of the trials is shuffled per participant;
- attention checks: after every `attention_every` trials, one trial whose instruction names the
  answer to give ("choose «x»"); it shows a stimulus like the others.
"""

from __future__ import annotations

from itertools import combinations
from typing import Any

import numpy as np

Trial = dict[str, Any]


def _stimulus_index(manifest: dict[str, Any]) -> dict[tuple[int, str, float | None], dict[str, Any]]:
    return {(s["item"], s["condition"], s["snr_db"]): s for s in manifest["stimuli"]}


def _answer_of(manifest: dict[str, Any], item: int, condition: str) -> str | None:
    if manifest["design"] == "intelligibility":
        a = manifest["items"][item]["answer"]
        return None if a is None else str(a)
    if manifest["design"] == "emotion":
        return str(next(c["answer"] for c in manifest["conditions"] if c["name"] == condition))
    return None


def stimulus_trials(manifest: dict[str, Any], number: int) -> list[Trial]:
    """The participant's stimulus trials, before shuffling (see the module docstring)."""
    index = _stimulus_index(manifest)
    conds = [c["name"] for c in manifest["conditions"]]
    items = range(len(manifest["items"]))
    snrs = manifest["snr_db"]
    design = manifest["design"]
    trials: list[Trial] = []
    if design in ("intelligibility", "emotion"):
        for i in items:
            chosen = conds if manifest["counterbalance"] == "full" else [conds[(i + number) % len(conds)]]
            for c in chosen:
                for snr in snrs:
                    s = index[(i, c, snr)]
                    trials.append({"kind": "stimulus", "item": i, "conditions": [c], "snr_db": snr,
                                   "stimuli": [s["id"]], "answer": _answer_of(manifest, i, c)})
    elif design == "preference":
        pairs = list(combinations(conds, 2))
        for i in items:
            for j, (a, b) in enumerate(pairs):
                for k, snr in enumerate(snrs):
                    first, second = (a, b) if (number + i + j + k) % 2 == 0 else (b, a)
                    trials.append({"kind": "stimulus", "item": i, "conditions": [first, second], "snr_db": snr,
                                   "stimuli": [index[(i, first, snr)]["id"], index[(i, second, snr)]["id"]],
                                   "answer": None})
    else:  # mushra
        rng = np.random.default_rng([manifest["seed"], number, 1])
        for i in items:
            for snr in snrs:
                order = [conds[k] for k in rng.permutation(len(conds))]
                ref = next(c["name"] for c in manifest["conditions"] if c["reference"])
                trials.append({"kind": "stimulus", "item": i, "conditions": order, "snr_db": snr,
                               "stimuli": [index[(i, c, snr)]["id"] for c in order],
                               "reference": index[(i, ref, snr)]["id"], "answer": None})
    return trials


def attention_choices(manifest: dict[str, Any]) -> list[str]:
    """The buttons of an attention check: the design's answers, or words of its own."""
    return list(manifest["choices"]) if manifest["design"] in ("intelligibility", "emotion") and \
        manifest["response"] == "choice" else ["red", "green", "blue"]


def participant_trials(manifest: dict[str, Any], number: int) -> list[Trial]:
    """Participant `number`'s trials in the order they are shown, attention checks included."""
    rng = np.random.default_rng([manifest["seed"], number])
    trials = stimulus_trials(manifest, number)
    order = rng.permutation(len(trials))
    shuffled = [trials[k] for k in order]
    every = int(manifest["attention_every"])
    out: list[Trial] = []
    choices = attention_choices(manifest)
    for k, t in enumerate(shuffled):
        out.append(t)
        if every and (k + 1) % every == 0:
            target = choices[int(rng.integers(len(choices)))]
            shown = manifest["stimuli"][int(rng.integers(len(manifest["stimuli"])))]
            out.append({"kind": "attention", "item": shown["item"], "conditions": [shown["condition"]],
                        "snr_db": shown["snr_db"], "stimuli": [shown["id"]], "answer": target,
                        "choices": choices})
    for position, t in enumerate(out):
        t["position"] = position
    return out


def words(text: str) -> list[str]:
    """Lower-case words without accents or punctuation ("Perché no?" → ["perche", "no"])."""
    import re
    import unicodedata

    plain = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode().lower()
    return re.findall(r"[a-z0-9]+", plain)


def score(manifest: dict[str, Any], trial: Trial, response: Any) -> float | None:
    """How right the response is: 1/0 for a closed-set answer (and an attention check), the share of
    the item's words typed (each word counted as often as it occurs) for a typed one, None where there
    is no right answer (preference, MUSHRA)."""
    if trial["answer"] is None:
        return None
    if trial["kind"] == "stimulus" and manifest["response"] == "text":
        expected = words(str(trial["answer"]))
        typed = words(str(response))
        hits = sum(min(expected.count(w), typed.count(w)) for w in set(expected))
        return hits / len(expected) if expected else None
    return 1.0 if response == trial["answer"] else 0.0


def check_response(manifest: dict[str, Any], trial: Trial, response: Any) -> str | None:
    """Why `response` is not an answer to `trial` (None: it is one)."""
    if trial["kind"] == "attention":
        return None if response in trial["choices"] else "choose one of the buttons"
    design = manifest["design"]
    if design in ("intelligibility", "emotion"):
        if manifest["response"] == "text":
            return None if isinstance(response, str) and response.strip() and len(response) <= 500 else \
                "type what was said (at most 500 characters)"
        return None if response in manifest["choices"] else "choose one of the buttons"
    if design == "preference":
        return None if response in trial["conditions"] else "choose one of the two faces"
    if not isinstance(response, dict) or set(response) != set(trial["conditions"]):
        return "rate every face"
    if not all(isinstance(v, int) and 0 <= v <= 100 for v in response.values()):
        return "ratings are whole numbers from 0 to 100"
    return None
