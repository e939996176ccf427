"""MCMC 95 % intervals of every emotion's deviation from the neutral targets of a fit with
``[model] emotions = "targets"`` (coartic.mcmc.emotions: the joint posterior of each phoneme's
targets, neutral and per emotion, with the fit's deviation prior; dynamics at the optimum).

    .venv/bin/python fit/emotion_intervals.py fit/emotive.toml results/emotive results/emotive_mcmc \
        [--channels LR,ULO] [--phonemes a,b] [--steps 1000]

Writes OUT/emotion_intervals.csv (channel, emotion, phoneme, fitted, q2.5, q50, q97.5, credible,
converged) and prints how many deviations are credible per channel. The posteriors are resumable
(OUT/<channel>/<phoneme>/). With the truth (--truth build/emotive/ground_truth.json) it also prints
how often the interval holds the true deviation.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

from coartic.estimation.problem import build_problem
from coartic.fit.data import load_utterances
from coartic.fit.spec import load_spec
from coartic.mcmc.emotions import DeviationInterval, deviation_intervals
from coartic.mcmc.sampler import SamplerSettings
from coartic.outputs import atomic_path
from coartic.table import ParameterTable


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("spec", type=Path)
    ap.add_argument("fit_dir", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--channels", default="", help="comma-separated (default: the table's)")
    ap.add_argument("--phonemes", default="", help="comma-separated (default: every phoneme)")
    ap.add_argument("--steps", type=int, default=1000, help="minimum steps per ensemble (default %(default)s)")
    ap.add_argument("--truth", type=Path, default=None)
    a = ap.parse_args(argv)
    spec = load_spec(a.spec)
    table = ParameterTable.load(a.fit_dir / "table.json")
    channels = [c for c in a.channels.split(",") if c] or list(table.channels)
    utterances = load_utterances(spec)
    settings = SamplerSettings(min_steps=a.steps, chunk_steps=min(500, a.steps), max_steps=max(20000, a.steps))
    truth = None
    if a.truth is not None:
        truth = ParameterTable.load(a.truth).metadata["emotions"]["channels"]
    out: list[DeviationInterval] = []
    for ch in channels:
        problem = build_problem(spec, utterances, ch, table)
        assert problem.speaker_rows is not None
        phonemes = [p for p in a.phonemes.split(",") if p] or list(problem.speaker_rows.base)
        for ph in phonemes:
            out.extend(deviation_intervals(problem, ph, a.out / ch / ph, settings))
        rows = [d for d in out if d.channel == ch]
        line = f"{ch}: {sum(d.credible for d in rows)} of {len(rows)} deviations credible"
        if truth is not None:
            held = [d.q2_5 <= truth[ch]["deviations"][d.emotion][d.phoneme] <= d.q97_5 for d in rows]
            line += f"; the interval holds the truth for {sum(held)} of {len(held)}"
        print(line + ("" if all(d.converged for d in rows) else " (NOT every posterior converged)"))
    a.out.mkdir(parents=True, exist_ok=True)
    with atomic_path(a.out / "emotion_intervals.csv") as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(out[0].row()))
        w.writeheader()
        w.writerows(d.row() for d in out)
    return 0 if all(d.converged for d in out) else 3


if __name__ == "__main__":
    sys.exit(main())
