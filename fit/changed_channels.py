"""Which lip and jaw channels of the Italian session differ from those of the session the shipped
table was fitted on, trial by trial, bit for bit.

    .venv/bin/python fit/changed_channels.py [--since COMMIT] [--session build/italian] [--previous DIR]

The model is fitted per channel (every parameter belongs to one phoneme on one channel, and a
channel's residuals depend on that channel's data alone), so a channel whose data are identical in
every trial refits to the same table: only the changed channels need fitting again
(`make table-italian-changed`). The previous session is regenerated from COMMIT's
corpus-synthetic/ (its generator, ground truth and settings; default: the newest commit whose
inputs have the checksums recorded in the shipped table's provenance) into --previous, then every trial of both sessions is read through
coartic.io exactly as `coartic fit` reads it (the manifest's `file` column, its labels) and each
channel compared with numpy.array_equal (NaN equal to NaN). Labels and trial lists must be
identical too, else every channel counts as changed.

Prints one line per channel and, last, the changed channels comma-separated (what `--channels`
of `coartic fit` takes); writes the same record as JSON to SESSION/changed_channels.json.
Exit 0 when the comparison ran (whatever it found), 1 when it could not.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import importlib.util
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from coartic.io.load import load_trial
from coartic.outputs import atomic_write_text
from coartic.runtime.shipped import shipped_provenance
from coartic.table import CHANNELS

ROOT = Path(__file__).resolve().parents[1]


def regenerate(commit: str, out: Path, quick: bool = False) -> None:
    """COMMIT's Italian session into ``out``, from COMMIT's corpus-synthetic/ (git archive): its
    generate.py imported from there, so that it reads its own ground truth and settings."""
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "corpus-synthetic"],
                                 check=True, capture_output=True).stdout
        tar = Path(tmp) / "c.tar"
        tar.write_bytes(archive)
        with tarfile.open(tar) as t:
            t.extractall(tmp, filter="data")
        spec = importlib.util.spec_from_file_location("coartic_previous_generate",
                                                      Path(tmp) / "corpus-synthetic" / "generate.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # its dataclasses look their module up there
        try:
            spec.loader.exec_module(module)
        finally:
            del sys.modules[spec.name]
        if out.exists():
            shutil.rmtree(out)
        module.generate(out, quick=quick, progress=False, flavour="italian")


def provenance_commit(inputs: dict[str, str], depth: int = 200) -> str | None:
    """The newest commit whose files are the inputs the shipped table was fitted from (their SHA-256)."""
    log = subprocess.run(["git", "-C", str(ROOT), "log", f"-{depth}", "--format=%H", "--", *inputs],
                         check=True, capture_output=True, text=True).stdout.split()
    for commit in log:
        shown = [subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{rel}"], capture_output=True)
                 for rel in inputs]
        if all(r.returncode == 0 and hashlib.sha256(r.stdout).hexdigest() == inputs[rel]
               for r, rel in zip(shown, inputs)):
            return commit
    return None


def _rows(session: Path) -> list[dict[str, str]]:
    with (session / "manifest.csv").open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def compare(previous: Path, session: Path) -> dict[str, Any]:
    old, new = _rows(previous), _rows(session)
    if [r["file"] for r in old] != [r["file"] for r in new]:
        return {"changed": list(CHANNELS), "why": "the trial lists differ", "trials": len(new)}
    changed: dict[str, list[str]] = {ch: [] for ch in CHANNELS}
    for ro, rn in zip(old, new):
        if (previous / ro["labels"]).read_bytes() != (session / rn["labels"]).read_bytes():
            return {"changed": list(CHANNELS), "why": f"the labels of {rn['file']} differ", "trials": len(new)}
        a = load_trial(previous / ro["file"], previous / ro["labels"]).channels(list(CHANNELS))
        b = load_trial(session / rn["file"], session / rn["labels"]).channels(list(CHANNELS))
        for ch in CHANNELS:
            if not (np.array_equal(a[ch], b[ch], equal_nan=True) and np.array_equal(a.valid[ch], b.valid[ch])):
                changed[ch].append(rn["file"])
    return {"changed": [ch for ch in CHANNELS if changed[ch]], "trials": len(new),
            "trials_changed": {ch: len(v) for ch, v in changed.items()},
            "why": "channels read from every trial's data file and compared bit for bit"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--since", help="the commit whose session the shipped table was fitted on (default: "
                                    "the newest commit whose inputs have the SHA-256 its provenance records)")
    ap.add_argument("--session", type=Path, default=ROOT / "build" / "italian")
    ap.add_argument("--previous", type=Path, default=ROOT / "build" / "italian-previous")
    args = ap.parse_args(argv)
    since = args.since or provenance_commit(shipped_provenance()["inputs_sha256"])
    if not since:
        print("changed_channels: no commit has the inputs the shipped table's provenance records: give --since",
              file=sys.stderr)
        return 1
    if not (args.session / "manifest.csv").is_file():
        print(f"changed_channels: {args.session}/manifest.csv is missing: "
              f"`coartic corpus synth {args.session} --flavour italian` first", file=sys.stderr)
        return 1
    quick = bool(json.loads((args.session / "session.json").read_text(encoding="utf-8")).get("quick"))
    regenerate(since, args.previous, quick)
    record = {"since": since, "previous": str(args.previous), "session": str(args.session)} | compare(
        args.previous, args.session)
    for ch in CHANNELS:
        n = record.get("trials_changed", {}).get(ch)
        state = "changed" if ch in record["changed"] else "identical"
        print(f"{ch:4} {state}" + (f" in {n} of {record['trials']} trials" if n else ""))
    atomic_write_text(args.session / "changed_channels.json", json.dumps(record, indent=1) + "\n")
    print(",".join(record["changed"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
