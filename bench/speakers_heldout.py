"""Several speakers in one fit, and a speaker the fit never saw (issue 10 item 2).

For each ``[model] speakers`` mode (none, offset, offset_scale, targets: docs/FITTING.md, "Several
speakers in one fit"), with the product's own fitting and validation (``coartic.fit.run`` and
``coartic.evaluation.validate`` with ``[validate] group = "speaker"``, what ``coartic fit --validate``
does):

* **in-sample**: one fit of every speaker together; RMSE of each speaker's own prediction (a_s +
  b_s·F, or its own targets);
* **leave one speaker out**: fit the other speakers, predict the held-out one. A speaker the table
  does not know is predicted with the *population* mapping (a = 0, b = 1: the reference speaker's
  targets under offset/offset_scale, the mean targets under targets, the pooled fit under none),
  and again after *calibrating* its offset and scale (a, b by linear least squares on its own
  data, as ``coartic score`` reports it). Under "targets" a held-out speaker has no targets of
  its own: only the population targets or that calibration can speak for it.

Not part of `make test` (about 15 CPU minutes). Output in bench/results/speakers_heldout.txt:

    coartic corpus synth build/speakers3 --speakers 3 --quick
    .venv/bin/python bench/speakers_heldout.py build/speakers3/manifest.csv

The corpus's speakers differ in target scale (about the rest posture) and speaking rate
(corpus-synthetic/speakers.toml). The spec is fit/synthetic.toml (staged, 8 parameters free per
phoneme) on ``--channels`` (default LLO, JO) and the manifest rows ``--select`` keeps (default
repetition 1, to keep the run short).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from coartic.fit import load_spec, run
from coartic.fit.data import load_utterances
from coartic.evaluation.validate import kfold_splits, score
from coartic.outputs import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
MODES = ("none", "offset", "offset_scale", "targets")


def by_speaker(fit, column: str) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """In-sample RMSE per speaker of one channel's fit."""
    return {k[0]: rm for k, (rm, _) in fit.rmse_by((column,)).items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("manifest", type=Path, help="manifest.csv of `coartic corpus synth DIR --speakers N`")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--channels", default="LLO,JO")
    ap.add_argument("--select", default="repetition=1", help="manifest rows kept: COLUMN=V1|V2,... ('' for all)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "speakers_heldout.txt")
    a = ap.parse_args()
    modes = a.modes.split(",")
    bad = sorted(set(modes) - set(MODES))
    if bad:
        ap.error(f"--modes: unknown {bad} (choose from {', '.join(MODES)})")
    select = {k: v.split("|") for k, _, v in (s.partition("=") for s in a.select.split(",") if s)}
    channels = tuple(a.channels.split(","))
    base = load_spec(ROOT / "fit" / "synthetic.toml")
    base = base.with_options(corpus=dataclasses.replace(base.corpus, manifest=a.manifest.resolve(), select=select),
                             channels=channels)
    utts = load_utterances(base)
    speakers = sorted({u.meta["speaker"] for u in utts})
    lines = ["# bench/speakers_heldout.py: several speakers in one fit, and a held-out speaker (RMSE, mm)",
             f"# {a.manifest}: {len(utts)} trials of speakers {' '.join(speakers)} (select {select}), "
             f"fit/synthetic.toml, channels {' '.join(channels)}",
             "# in-sample: one fit of all speakers, each speaker's own prediction; held out: fit the others,",
             "# predict it with the population mapping (a = 0, b = 1) and after calibrating a, b on its own data",
             f"{'mode':13s} {'ch':4s} {'in-sample':>9s} " + " ".join(f"{s:>6s}" for s in speakers)
             + f" | {'held out':>8s} {'calibr.':>8s}  per speaker held out (population / calibrated)   CPU s"]
    print("\n".join(lines), flush=True)
    for mode in modes:
        spec = base.with_options(speakers=mode, validate={"group": "speaker"})
        t0 = time.process_time()
        full = run(spec, utterances=utts, quiet=True)
        held: dict[str, list[tuple[str, float, float, int]]] = {c: [] for c in channels}
        for split, train, test in kfold_splits(spec, utts):
            res = run(spec, utterances=train, quiet=True)
            for sc in score(res, test, split):
                held[sc.channel].append((test[0].meta["speaker"], sc.test_rmse, sc.test_rmse_calibrated,
                                         sc.test_samples))
        cpu = time.process_time() - t0
        for c in channels:
            fit = full.channels[c]
            own = by_speaker(fit, "speaker")
            rows = held[c]
            n = np.array([r[3] for r in rows], dtype=float)
            pop = float(np.sqrt(np.sum(n * np.array([r[1] for r in rows]) ** 2) / n.sum()))
            cal = float(np.sqrt(np.sum(n * np.array([r[2] for r in rows]) ** 2) / n.sum()))
            lines.append(f"{mode:13s} {c:4s} {fit.rmse:9.3f} " + " ".join(f"{own.get(s, float('nan')):6.3f}" for s in speakers)
                         + f" | {pop:8.3f} {cal:8.3f}  "
                         + "  ".join(f"{s} {p:.3f}/{q:.3f}" for s, p, q, _ in rows) + f"   {cpu:.0f}")
            print(lines[-1], flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(a.out, "\n".join(lines) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
