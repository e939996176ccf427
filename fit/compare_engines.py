"""Compare the engines on one channel with the same spec and start (a driver to copy).

    .venv/bin/python fit/compare_engines.py [fit/synthetic.toml] [LLO] [p,f,t,l,s]

Fits the channel on the trials of the listed consonants with scipy, nlopt and casadi, and prints
RMSE, the largest target error against the session's ground truth (when there is one), the
number of evaluations and the wall time.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from coartic.fit.data import load_utterances, manifest_rows
from coartic.fit.runner import fit_channel
from coartic.fit.spec import load_spec
from coartic.table import ParameterTable

ENGINES = [("scipy", {}), ("nlopt", {}), ("casadi", {"max_iter": 1000})]


def main(spec_path: str, channel: str, consonants: list[str]) -> None:
    spec = load_spec(spec_path)
    spec = spec.with_options(channels=(channel,))
    rows = [r for r in manifest_rows(spec) if r.get("consonant") in consonants]
    utts = load_utterances(spec, rows)
    truth = None
    if spec.corpus.manifest is not None and (spec.corpus.manifest.parent / "ground_truth.json").is_file():
        truth = ParameterTable.load(spec.corpus.manifest.parent / "ground_truth.json")
    for engine, options in ENGINES:
        t0 = time.perf_counter()
        fit = fit_channel(spec.with_options(engine={"name": engine, "options": options}), utts, channel)
        wall = time.perf_counter() - t0
        err = ""
        if truth is not None:
            e = max(abs(fit.params[i, 0] - truth.values[p][channel]["target"]) for i, p in enumerate(fit.phonemes))
            err = f", max target error {e:.3f} mm"
        print(f"{engine:7} {len(utts)} trials {channel}: RMSE {fit.rmse:.4f} mm{err}, {fit.nfev} evaluations, "
              f"{wall:.1f} s, {fit.status}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else str(Path("fit/synthetic.toml")),
         sys.argv[2] if len(sys.argv) > 2 else "LLO",
         (sys.argv[3] if len(sys.argv) > 3 else "p,f,t,l,s").split(","))
