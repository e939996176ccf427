"""The answers as a tidy table: one row per answer (per rated face, for MUSHRA), one column per variable.

Columns: study, participant (P0001…: the arrival number, never the link token or panel identifier),
simulated (1 for coartic perceive simulate's), trial (position in the participant's sequence, from 0),
kind (stimulus | attention), item, item_text, condition, snr_db, stimulus, expected, response,
correct, rt_ms, answered_at; preference adds shown_first, shown_second, chosen, chosen_position
(condition is then the chosen one); MUSHRA gives each face its row (condition, stimulus, response =
its rating, reference 1 for the hidden reference).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

COLUMNS = ["study", "participant", "simulated", "trial", "kind", "item", "item_text", "condition", "snr_db",
           "stimulus", "expected", "response", "correct", "rt_ms", "answered_at"]
PREFERENCE_COLUMNS = ["shown_first", "shown_second", "chosen", "chosen_position"]


def participant_code(number: int) -> str:
    return f"P{number + 1:04d}"


def tidy_answers(manifest: dict[str, Any], rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The database's answer rows (storage.Store.answer_rows) as the tidy table."""
    design = manifest["design"]
    texts = {it["index"]: it["text"] for it in manifest["items"]}
    reference = {c["name"] for c in manifest["conditions"] if c.get("reference")}
    out: list[dict[str, Any]] = []
    for r in rows:
        conditions = json.loads(r["conditions"])
        stimuli = json.loads(r["stimuli"])
        response = json.loads(r["response"])
        base = {"study": manifest["name"], "participant": participant_code(int(r["number"])),
                "simulated": int(r["simulated"]), "trial": int(r["trial"]), "kind": r["kind"], "item": int(r["item"]),
                "item_text": texts.get(int(r["item"]), ""), "snr_db": r["snr_db"], "expected": r["expected"],
                "correct": r["correct"], "rt_ms": r["rt_ms"], "answered_at": r["answered_at"]}
        if r["kind"] == "stimulus" and design == "mushra":
            for cond, sid in zip(conditions, stimuli):
                out.append({**base, "condition": cond, "stimulus": sid, "response": response[cond],
                            "reference": int(cond in reference)})
        elif r["kind"] == "stimulus" and design == "preference":
            out.append({**base, "condition": response, "stimulus": "+".join(stimuli), "response": response,
                        "shown_first": conditions[0], "shown_second": conditions[1], "chosen": response,
                        "chosen_position": conditions.index(response) + 1})
        else:
            out.append({**base, "condition": conditions[0], "stimulus": stimuli[0], "response": response})
    columns = COLUMNS + (PREFERENCE_COLUMNS if design == "preference" else []) + (["reference"] if design == "mushra" else [])
    return pd.DataFrame(out, columns=columns)


def write_csv(frame: pd.DataFrame, path: Path) -> Path:
    """The tidy table as CSV (UTF-8, a header, no index), written atomically."""
    from coartic.outputs import atomic_write_text

    atomic_write_text(path, frame.to_csv(index=False, lineterminator="\n"))
    return path
