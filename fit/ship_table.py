"""Ship the Italian table: merge checked fits of the Italian synthetic session into the package.

    .venv/bin/python fit/ship_table.py [--lips results/italian] [--tongue results/italian_tongue]
                                       [--session build/italian] [--keep-unchanged]

The last step of `make table-italian` (which generates the session, fits its lip and jaw channels
with fit/italian.toml and its tongue channels with fit/italian_tongue.toml, both with --validate)
and of `make table-italian-changed`. Every fit is checked for recovery against the session's ground
truth (fit/check_recovery.py, the bar of `make fit`); a fit that misses it is refused. Writes, inside
the package (python/coartic/runtime/, shipped by `pip install`):

- italian_table.json: the lip and jaw channels of --lips and the tongue channels of --tongue in one
  table (each channel's parameters as its fit wrote them; metadata names the fit of each channel);
- italian_table.provenance.json: the command, the SHA-256 of the table and of the inputs it was
  made from, the fits' RMSE, held-out RMSE per split beside baselines measured on the same held-out
  trials (the ground truth itself: the noise floor; for the lips the default session's /i a u/ table
  with the Italian phone map's fallbacks, what `coartic speak` animated before this table existed;
  for the tongue the runtime's class default, what the face's tongue did before), and the recovery
  checks' output.

--keep-unchanged: --lips holds only some lip and jaw channels (`coartic fit --channels`), those
that fit/changed_channels.py found changed (SESSION/changed_channels.json, which must name exactly
them); the others are kept from the table shipped now, after checking that its provenance's inputs
are those of the commit the comparison was made against and that the ground truth of the kept
channels is the same there. The model is fitted per channel, so a channel whose data are identical
bit for bit refits to what it was. The provenance says which channels were refitted and which kept.

tests/python/test_runtime_shipped.py checks the shipped files against this record (no refit).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import csv
import hashlib
import io
import json
import subprocess
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
from coartic.runtime.shipped import SHIPPED_PROVENANCE, SHIPPED_TABLE, shipped_provenance  # noqa: E402
from coartic.runtime.tongue import default_tongue_table  # noqa: E402
from coartic.table import CHANNELS, TONGUE_CHANNELS, ParameterTable  # noqa: E402

SPEC = "fit/italian.toml"
TONGUE_SPEC = "fit/italian_tongue.toml"
TRUTH = "corpus-synthetic/ground_truth_italian.json"
# What the table is made from; a change to any of them calls for `make table-italian` again (tested).
INPUTS = (TRUTH, "corpus-synthetic/session.toml", SPEC, TONGUE_SPEC)
PACKAGE = ROOT / "python" / "coartic" / "runtime"


class ShipError(Exception):
    """A fit or a record that cannot be shipped; the message says which and why."""


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def held_out_baselines(session: Path, spec_path: str, channels: list[str]) -> dict[str, dict[str, dict[str, float]]]:
    """RMSE per split and channel, on each split's held-out trials, of the ground truth and of the
    table the runtime used before: for the lips the default session's 3-vowel table with the Italian
    phone map's fallbacks, for the tongue the class default of coartic.runtime.tongue."""
    from coartic.fit.data import load_utterances
    from coartic.evaluation.score import score_utterances
    from coartic.evaluation.validate import splits

    spec = load_spec(ROOT / spec_path)
    truth = ParameterTable.load(session / "ground_truth.json")
    tongue = set(channels) <= set(TONGUE_CHANNELS)
    if tongue:
        name = "class_default_tongue"
        old = default_tongue_table(sorted(truth.phonemes))
    else:
        name = "three_vowel_table_with_fallbacks"
        old = ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth.json")
    fallbacks = PhoneMap.load().fallbacks
    have = set(old.phonemes)

    def as_old(u: Utterance) -> Utterance:
        labels = [next((p for p in (lab, *fallbacks.get(lab, ())) if p in have), lab) for lab in u.labels]
        return Utterance(labels, u.starts, u.ends, u.times, u.name, u.observed, u.valid, u.meta)

    out: dict[str, dict[str, dict[str, float]]] = {}
    for split, _train, test in splits(spec, load_utterances(spec)):
        rows = {"ground_truth": score_utterances(truth, test, channels=channels).channel_rows(),
                name: score_utterances(old, [as_old(u) for u in test], channels=channels).channel_rows()}
        out[split] = {k: {r["channel"]: float(r["rmse_mm"]) for r in v} for k, v in rows.items()}
    return out


def checked_fit(fit_dir: Path, session: Path) -> tuple[ParameterTable, dict[str, Any], dict[str, dict[str, float]], list[str]]:
    """A fit's table, summary, held-out RMSE per split and channel, and its recovery check's lines."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        status = check_recovery.main(fit_dir, session / "ground_truth.json")
    print(buf.getvalue(), end="")
    if status != 0:
        raise ShipError(f"{fit_dir} does not meet the recovery bar; nothing shipped")
    validation = fit_dir / "validation" / "validation.csv"
    if not validation.is_file():
        raise ShipError(f"{validation} is missing: fit with --validate (make table-italian does)")
    held: dict[str, dict[str, float]] = {}
    with validation.open(newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            held.setdefault(r["split"], {})[r["channel"]] = float(r["test_rmse_mm"])
    summary = json.loads((fit_dir / "summary.json").read_text(encoding="utf-8"))
    return ParameterTable.load(fit_dir / "table.json"), summary, held, buf.getvalue().rstrip("\n").splitlines()


def _git_show(commit: str, rel: str) -> bytes:
    return subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{rel}"], check=True,
                          capture_output=True).stdout


def kept_channels(session: Path, fitted: list[str], previous: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
    """The lip and jaw channels to keep from the shipped table, after the checks of --keep-unchanged."""
    record_path = session / "changed_channels.json"
    if not record_path.is_file():
        raise ShipError(f"{record_path} is missing: run fit/changed_channels.py (make table-italian-changed does)")
    record = json.loads(record_path.read_text(encoding="utf-8"))
    if sorted(record["changed"]) != sorted(fitted):
        raise ShipError(f"the lip fit has channels {fitted} but {record_path} found {record['changed']} changed: "
                        f"fit exactly those (coartic fit --channels {','.join(record['changed'])})")
    since = record["since"]
    for rel, digest in previous["inputs_sha256"].items():
        if rel in (TRUTH, "corpus-synthetic/session.toml", SPEC) and hashlib.sha256(_git_show(since, rel)).hexdigest() != digest:
            raise ShipError(f"{rel} at {since} is not what the shipped table was fitted from: the comparison "
                            "of fit/changed_channels.py was made against another session")
    kept = [ch for ch in CHANNELS if ch not in fitted]
    old_truth = ParameterTable.from_json_dict(json.loads(_git_show(since, TRUTH)), f"{since}:{TRUTH}")
    truth = ParameterTable.load(ROOT / TRUTH)
    for ch in kept:
        for ph in truth.phonemes:
            if truth.values[ph][ch] != old_truth.values[ph][ch]:
                raise ShipError(f"the ground truth of /{ph}/ on {ch} changed since {since}: refit {ch} too")
    return kept, record


def merge(base: dict[str, Any], other: dict[str, Any], channels: list[str]) -> None:
    """Put ``channels`` of the table document ``other`` into ``base`` (settings, values, bounds)."""
    for ch in channels:
        base["channels"][ch] = other["channels"][ch]
        for ph, per in other["phonemes"].items():
            base["phonemes"].setdefault(ph, {})[ch] = per[ch]
        for key in ("bounds", "uncertainty"):
            if ch in other.get(key, {}):
                base.setdefault(key, {})[ch] = other[key][ch]
        for key in ("rmse", "status"):
            if ch in other["metadata"].get(key, {}):
                base["metadata"].setdefault(key, {})[ch] = other["metadata"][key][ch]


def main(lips_dir: Path, tongue_dir: Path, session: Path, keep_unchanged: bool) -> int:
    lips, lips_summary, lips_held, lips_check = checked_fit(lips_dir, session)
    tongue, tongue_summary, tongue_held, tongue_check = checked_fit(tongue_dir, session)
    fitted = [ch for ch in CHANNELS if ch in lips.channels]
    if list(tongue.channels) != list(TONGUE_CHANNELS):
        raise ShipError(f"{tongue_dir}: the tongue fit has channels {list(tongue.channels)}, not {list(TONGUE_CHANNELS)}")
    previous = shipped_provenance()
    old_doc = json.loads((PACKAGE / SHIPPED_TABLE).read_text(encoding="utf-8"))
    kept: list[str] = []
    record: dict[str, Any] | None = None
    if fitted != list(CHANNELS):
        if not keep_unchanged:
            raise ShipError(f"{lips_dir} has only {fitted}: fit every lip and jaw channel, or give --keep-unchanged")
        kept, record = kept_channels(session, fitted, previous)
    lips_doc, tongue_doc = lips.to_json_dict(), tongue.to_json_dict()
    doc: dict[str, Any] = copy.deepcopy(old_doc if kept else lips_doc)
    doc["channels"] = {ch: doc["channels"][ch] for ch in CHANNELS if ch in kept}
    doc["metadata"] = copy.deepcopy(lips_doc["metadata"])
    doc["metadata"]["rmse"], doc["metadata"]["status"] = {}, {}
    merge(doc, old_doc, kept)
    merge(doc, lips_doc, fitted)
    merge(doc, tongue_doc, list(TONGUE_CHANNELS))
    doc["channels"] = {ch: doc["channels"][ch] for ch in (*CHANNELS, *TONGUE_CHANNELS)}
    for key in ("rmse", "status"):
        doc["metadata"][key] = {ch: doc["metadata"][key][ch] for ch in doc["channels"]}
    doc["metadata"]["spec"] = {SPEC: fitted, TONGUE_SPEC: list(TONGUE_CHANNELS)} | (
        {f"kept from the table of {old_doc['metadata'].get('date')}": kept} if kept else {})
    doc["metadata"]["corpus"] = (f"{lips_doc['metadata'].get('corpus')} (lips and jaw: column file; "
                                 "tongue: column ema)")
    table = ParameterTable.from_json_dict(doc, SHIPPED_TABLE)
    table.validate()

    rmse = {ch: v["rmse_mm"] for ch, v in lips_summary["channels"].items()} | {
        ch: v["rmse_mm"] for ch, v in tongue_summary["channels"].items()}
    held_fitted = {split: dict(per) for split, per in lips_held.items()}
    for split, per in tongue_held.items():
        held_fitted.setdefault(split, {}).update(per)
    baselines = held_out_baselines(session, SPEC, fitted)
    for split, per in held_out_baselines(session, TONGUE_SPEC, list(TONGUE_CHANNELS)).items():
        for name, values in per.items():
            baselines.setdefault(split, {}).setdefault(name, {}).update(values)
    lines = {line.split()[0]: line for line in lips_check[1:-1] + tongue_check[1:-1]}
    if kept:
        old_held = previous["held_out_rmse_mm"]
        for ch in kept:
            rmse[ch] = previous["rmse_mm"][ch]
            for split in held_fitted:
                held_fitted[split][ch] = old_held[split]["fitted_table"][ch]
                for name in ("ground_truth", "three_vowel_table_with_fallbacks"):
                    baselines[split][name][ch] = old_held[split][name][ch]
        old_lines = {line.split()[0]: line for line in previous["recovery_check"][1:-1]}
        lines |= {ch: old_lines[ch] + "   (kept: fitted before)" for ch in kept}
    order = list(doc["channels"])
    recovery = [lips_check[0], *(lines[ch] for ch in order), "bar met"]
    provenance: dict[str, Any] = {
        "command": "make table-italian-changed" if kept else "make table-italian",
        "table": SHIPPED_TABLE,
        "table_sha256": "",
        "inputs_sha256": {p: sha256(ROOT / p) for p in INPUTS},
        "phonemes": list(table.phonemes),
        "channels": order,
        "fitted": {SPEC: lips.metadata.get("date"), TONGUE_SPEC: tongue.metadata.get("date")},
        "software": lips.metadata.get("software"),
        "refit": ({"fitted_now": fitted + list(TONGUE_CHANNELS), "kept": kept,
                   "kept_from": {"table_sha256": previous["table_sha256"], "fitted": previous["fitted"],
                                 "inputs_sha256": previous["inputs_sha256"]},
                   "why": "the model is fitted per channel and the kept channels' data are identical bit for "
                          "bit in every trial (fit/changed_channels.py); their ground truth is unchanged",
                   "changed_channels": record} if kept else
                  {"fitted_now": order, "kept": []}),
        "rmse_mm": {ch: rmse[ch] for ch in order},
        "held_out_rmse_mm": {split: {name: {ch: values[ch] for ch in order if ch in values}
                                     for name, values in {"fitted_table": per, **baselines.get(split, {})}.items()}
                             for split, per in held_fitted.items()},
        "recovery_check": recovery,
    }
    PACKAGE.mkdir(parents=True, exist_ok=True)
    text = json.dumps(table.to_json_dict(), indent=2) + "\n"
    provenance["table_sha256"] = hashlib.sha256(text.encode("utf-8")).hexdigest()
    atomic_write_text(PACKAGE / SHIPPED_TABLE, text)
    atomic_write_text(PACKAGE / SHIPPED_PROVENANCE, json.dumps(provenance, indent=1, ensure_ascii=False) + "\n")
    print(f"shipped {PACKAGE / SHIPPED_TABLE} ({len(table.phonemes)} phonemes, {len(order)} channels: "
          f"{', '.join(fitted + list(TONGUE_CHANNELS))} fitted now" + (f", {', '.join(kept)} kept" if kept else "")
          + f") and {SHIPPED_PROVENANCE}")
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lips", type=Path, default=Path("results/italian"))
    ap.add_argument("--tongue", type=Path, default=Path("results/italian_tongue"))
    ap.add_argument("--session", type=Path, default=Path("build/italian"))
    ap.add_argument("--keep-unchanged", action="store_true")
    a = ap.parse_args()
    try:
        sys.exit(main(a.lips, a.tongue, a.session, a.keep_unchanged))
    except ShipError as err:
        print(f"ship_table: {err}", file=sys.stderr)
        sys.exit(1)
