"""MCMC 95 % intervals of every emotion's deviation from the neutral targets of a fit with
``[model] emotions = "targets"`` (coartic.mcmc.emotions: the joint posterior of each phoneme's
targets, neutral and per emotion, with the fit's deviation prior; dynamics at the optimum).

    .venv/bin/python fit/emotion_intervals.py fit/emotive.toml results/emotive results/emotive_mcmc \
        [--channels LR,ULO] [--phonemes a,b] [--steps 1000] [--ensembles 3] [--truth GROUND_TRUTH]

Every channel and phoneme by default (the whole session). Writes OUT/emotion_intervals.csv
(channel, emotion, phoneme, fitted, q2.5, q50, q97.5, credible, converged) and
OUT/emotion_intervals.txt, which it also prints: per channel and emotion the credible deviations
with their intervals (coartic.mcmc.emotions.credible_report). The posteriors are resumable
(OUT/<channel>/<phoneme>/). With the truth (--truth build/emotive/ground_truth.json) it also says
how many of the truth's non-zero deviations are credible, how many zero ones are called credible
and how often the interval holds the true deviation. Exit status 3 when a posterior did not converge.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from coartic.fit.data import load_utterances
from coartic.fit.spec import load_spec
from coartic.mcmc.emotions import session_intervals, write_intervals
from coartic.mcmc.sampler import SamplerSettings
from coartic.table import ParameterTable


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("spec", type=Path)
    ap.add_argument("fit_dir", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--channels", default="", help="comma-separated (default: the table's)")
    ap.add_argument("--phonemes", default="", help="comma-separated (default: every phoneme)")
    ap.add_argument("--steps", type=int, default=1000, help="minimum steps per ensemble (default %(default)s)")
    ap.add_argument("--ensembles", type=int, default=3, help="independent ensembles per posterior (default %(default)s)")
    ap.add_argument("--truth", type=Path, default=None)
    a = ap.parse_args(argv)
    spec = load_spec(a.spec)
    table = ParameterTable.load(a.fit_dir / "table.json")
    utterances = load_utterances(spec)
    settings = SamplerSettings(n_ensembles=a.ensembles, min_steps=a.steps, chunk_steps=min(500, a.steps),
                               max_steps=max(20000, a.steps))
    truth = None
    if a.truth is not None:
        truth = ParameterTable.load(a.truth).metadata["emotions"]["channels"]

    def said(ch: str, ph: str, done: int, total: int) -> None:
        print(f"[{done}/{total}] {ch} /{ph}/ sampled", file=sys.stderr, flush=True)

    try:
        out = session_intervals(spec, utterances, table, a.out, settings,
                                [c for c in a.channels.split(",") if c] or None,
                                [p for p in a.phonemes.split(",") if p] or None, said)
    except KeyboardInterrupt as e:
        print(f"interrupted ({e or 'Ctrl-C'}): the posteriors sampled so far are kept in {a.out}; "
              "rerun the same command to resume", file=sys.stderr)
        return 130
    paths = write_intervals(out, a.out, truth)
    print(paths["text"].read_text(encoding="utf-8"), end="")
    print(f"written: {paths['csv']}, {paths['text']}")
    return 0 if all(d.converged for d in out) else 3


if __name__ == "__main__":
    sys.exit(main())
