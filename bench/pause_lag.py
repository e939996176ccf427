"""Why pause postures raised the synthetic session's held-out speech error (docs/REAL_DATA.md, "Why
the synthetic figures moved"): one channel, the rate split (normal -> fast), one start, the pooled
default (rate-aware, target prior estimated) as bench/real_data.py fits it; the held-out speech RMSE
by position in the # V C V # utterances, and the pause rows' fitted target, α, θ.

    --corpus synthetic|gestures  the synthetic session (default) or its gestures flavour (needs
                              build/gestures; --true-lag is the synthetic session's truth only)
    --pauses one|postures     [model] pauses
    --tie PARAMS              also tie these parameters of '#' and '#end' (a [[tie]], e.g. target)
    --true-lag                fix the pauses' δ and k_R at the ground truth's (0.075 s, 1): the lag
                              the fitted model otherwise lacks

    nice -n 10 .venv/bin/python bench/pause_lag.py --channel LLO --pauses postures

Needs build/session (coartic corpus synth build/session). Prints; writes nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_data as rd  # noqa: E402

from coartic.fit import run  # noqa: E402
from coartic.fit.spec import Override, Tie  # noqa: E402
from coartic.pauses import FINAL_PAUSE  # noqa: E402
from coartic.table import PARAMETERS, PAUSE  # noqa: E402

# the synthetic session's ground truth for its one pause (corpus-synthetic/ground_truth.json)
TRUE_LAG = {"delta": 0.075, "k_r": 1.0}
SHOWN = ("target", "alpha", "theta_bw", "theta_fw", "delta")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--channel", default="LLO")
    ap.add_argument("--corpus", default="synthetic", choices=("synthetic", "gestures"))
    ap.add_argument("--pauses", default="postures", choices=("postures", "one"))
    ap.add_argument("--tie", default="", help="comma-separated parameters of '#' and '#end' to tie")
    ap.add_argument("--true-lag", action="store_true")
    a = ap.parse_args()
    if a.true_lag and a.corpus != "synthetic":
        ap.error("--true-lag is the synthetic session's ground truth")
    corpus = next(c for c in rd.CORPORA if c.key == a.corpus)
    base = rd.corpus_spec(corpus).with_options(channels=(a.channel,), pauses=a.pauses)
    spec = rd.cell_spec(base, "rate-aware", "pooled", "tprior-eb", 1)
    if a.tie:
        spec = spec.with_options(ties=spec.parameters.ties + (Tie(phonemes=(PAUSE, FINAL_PAUSE), parameters=tuple(a.tie.split(","))),))
    if a.true_lag:
        spec = spec.with_options(overrides=spec.parameters.overrides + (Override(phonemes=(PAUSE, FINAL_PAUSE), fixed=TRUE_LAG),))
    _, train, test = rd.splits(rd.load_utterances(base), ["rate"])[0]
    trained = run(spec, utterances=list(train), quiet=True)
    got = rd.fit_and_score(spec, train, test, a.channel, None, "constant", trained=trained)
    sse: dict[int, list[float]] = {}
    for _, i, _, n, rt, _, _ in got["segments"]:
        acc = sse.setdefault(i, [0.0, 0.0])
        acc[0] += rt * rt * n
        acc[1] += n
    print(f"{a.corpus} {a.channel} pauses {a.pauses} tie [{a.tie}] true lag {a.true_lag}: held-out speech {got['table']:.3f}, "
          f"all {got['table_all']:.3f}, in-sample {got['in_sample']:.3f} mm")
    print("held-out speech by segment (1 = first vowel, 2 = consonant, 3 = last vowel): "
          + ", ".join(f"{i}: {np.sqrt(s / n):.3f}" for i, (s, n) in sorted(sse.items())))
    fit = trained.channels[a.channel]
    for p in fit.phonemes:
        if p in (PAUSE, FINAL_PAUSE):
            row = fit.params[fit.phonemes.index(p)]
            print(f"  {p:4s} " + ", ".join(f"{k} {row[PARAMETERS.index(k)]:.3f}" for k in SHOWN))
    return 0


if __name__ == "__main__":
    sys.exit(main())
