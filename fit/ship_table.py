"""Ship the Italian table: copy a checked fit of the Italian synthetic session into the package.

    .venv/bin/python fit/ship_table.py [results/italian] [build/italian]

The last step of `make table-italian` (which generates the session, fits it with --validate and
checks recovery with fit/check_recovery.py first). Refuses a fit that does not meet the recovery
bar. Writes, inside the package (python/coartic/runtime/, shipped by `pip install`):

- italian_table.json: the fit's table.json, byte for byte;
- italian_table.provenance.json: the command, the SHA-256 of the table and of the inputs it was
  made from (ground truth, session settings, fit spec), the fit's RMSE, its held-out RMSE per split
  beside two baselines measured on the same held-out trials (the ground truth itself: the noise
  floor; and the default session's /i a u/ table with the Italian phone map's fallbacks, which is
  what `coartic speak` animated before this table existed), and the recovery check's output.

tests/python/test_runtime_shipped.py checks the shipped files against this record (no refit).
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import shutil
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "fit"))

import check_recovery  # noqa: E402  (fit/check_recovery.py, a sibling script)

from coartic.fit.spec import load_spec  # noqa: E402
from coartic.model import Utterance  # noqa: E402
from coartic.outputs import atomic_write_text  # noqa: E402
from coartic.runtime.festival import PhoneMap  # noqa: E402
from coartic.runtime.shipped import SHIPPED_PROVENANCE, SHIPPED_TABLE  # noqa: E402
from coartic.table import ParameterTable  # noqa: E402

SPEC = "fit/italian.toml"
# What the table is made from; a change to any of them calls for `make table-italian` again (tested).
INPUTS = ("corpus-synthetic/ground_truth_italian.json", "corpus-synthetic/session.toml", SPEC)
COMMAND = "make table-italian"
PACKAGE = ROOT / "python" / "coartic" / "runtime"


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def held_out_baselines(session: Path) -> dict[str, dict[str, dict[str, float]]]:
    """RMSE per split and channel, on each split's held-out trials, of the ground truth and of the
    default session's 3-vowel table with the Italian phone map's fallbacks."""
    from coartic.fit.data import load_utterances
    from coartic.fit.score import score_utterances
    from coartic.fit.validate import splits

    spec = load_spec(ROOT / SPEC)
    truth = ParameterTable.load(session / "ground_truth.json")
    old = ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth.json")
    fallbacks = PhoneMap.load().fallbacks
    have = set(old.phonemes)

    def as_old(u: Utterance) -> Utterance:
        labels = [next((p for p in (lab, *fallbacks.get(lab, ())) if p in have), lab) for lab in u.labels]
        return Utterance(labels, u.starts, u.ends, u.times, u.name, u.observed, u.valid, u.meta)

    out: dict[str, dict[str, dict[str, float]]] = {}
    for name, _train, test in splits(spec, load_utterances(spec)):
        rows = {
            "ground_truth": score_utterances(truth, test).channel_rows(),
            "three_vowel_table_with_fallbacks": score_utterances(old, [as_old(u) for u in test]).channel_rows(),
        }
        out[name] = {k: {r["channel"]: float(r["rmse_mm"]) for r in v} for k, v in rows.items()}
    return out


def main(fit_dir: Path, session: Path) -> int:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        status = check_recovery.main(fit_dir, session / "ground_truth.json")
    print(buf.getvalue(), end="")
    if status != 0:
        print(f"ship_table: {fit_dir} does not meet the recovery bar; nothing shipped", file=sys.stderr)
        return 1
    validation = fit_dir / "validation" / "validation.csv"
    if not validation.is_file():
        print(f"ship_table: {validation} is missing: fit with --validate ({COMMAND} does)", file=sys.stderr)
        return 1
    table = ParameterTable.load(fit_dir / "table.json")
    summary = json.loads((fit_dir / "summary.json").read_text(encoding="utf-8"))
    with validation.open(newline="", encoding="utf-8") as fh:
        held: dict[str, dict[str, float]] = {}
        for r in csv.DictReader(fh):
            held.setdefault(r["split"], {})[r["channel"]] = float(r["test_rmse_mm"])
    baselines = held_out_baselines(session)
    provenance: dict[str, Any] = {
        "command": COMMAND,
        "table": SHIPPED_TABLE,
        "table_sha256": sha256(fit_dir / "table.json"),
        "inputs_sha256": {p: sha256(ROOT / p) for p in INPUTS},
        "phonemes": list(table.phonemes),
        "channels": list(table.channels),
        "fitted": table.metadata.get("date"),
        "software": table.metadata.get("software"),
        "rmse_mm": {ch: v["rmse_mm"] for ch, v in summary["channels"].items()},
        "held_out_rmse_mm": {split: {"fitted_table": held[split], **baselines.get(split, {})} for split in held},
        "recovery_check": buf.getvalue().rstrip("\n").splitlines(),
    }
    PACKAGE.mkdir(parents=True, exist_ok=True)
    tmp = PACKAGE / (SHIPPED_TABLE + ".part")
    shutil.copyfile(fit_dir / "table.json", tmp)
    tmp.replace(PACKAGE / SHIPPED_TABLE)
    atomic_write_text(PACKAGE / SHIPPED_PROVENANCE, json.dumps(provenance, indent=1, ensure_ascii=False) + "\n")
    print(f"shipped {PACKAGE / SHIPPED_TABLE} ({len(table.phonemes)} phonemes, {len(table.channels)} channels) "
          f"and {SHIPPED_PROVENANCE}")
    return 0


if __name__ == "__main__":
    fit_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "results/italian")
    session = Path(sys.argv[2] if len(sys.argv) > 2 else "build/italian")
    sys.exit(main(fit_dir, session))
