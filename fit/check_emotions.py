"""Compare a fit of the emotive synthetic session with its ground truth: every emotion's deviation
from the neutral target, per channel and phoneme, within a stated tolerance.

    .venv/bin/python fit/check_emotions.py results/emotive [build/emotive/ground_truth.json] [--tolerance 0.3]

The tolerance (default 0.3 mm) is the fit's 0.2 mm target bar (fit/check_recovery.py) for a difference
of two targets, each within it: 0.2·√2 ≈ 0.3 mm. Also printed: the neutral targets' largest error,
how many deviations the fit calls credible (the fit's 95 % interval excludes 0) and how many of the
truth's non-zero ones that catches, the data-estimated shrinkage scale τ per emotion, and the corner
asymmetries (each emotion's, from the markers, relative to neutral) against the truth's, within the
same tolerance. A driver:
it reads only the two tables. Exit status 0 when every deviation is within the tolerance.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from coartic.table import ParameterTable

TOLERANCE_MM = 0.3
# an emotion's own rates ([model] emotions = "targets+dynamics"): log deviations within 0.1 (10 %)
TOLERANCE_LOG = 0.1
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Deviation:
    channel: str
    emotion: str
    phoneme: str
    truth: float
    fitted: float
    sd: float

    @property
    def error(self) -> float:
        return abs(self.fitted - self.truth)

    @property
    def credible(self) -> bool:
        """The fit's 95 % interval (Laplace, fitted ± 1.96 sd) excludes 0."""
        return abs(self.fitted) > Z95 * self.sd


def emotions_of(table: ParameterTable) -> dict[str, Any]:
    meta = (table.metadata or {}).get("emotions")
    if not isinstance(meta, dict) or "channels" not in meta:
        raise SystemExit(f"{table.source}: no metadata.emotions: fitted without [model] emotions = \"targets\"?")
    return meta


def deviations(fitted: ParameterTable, truth: ParameterTable) -> list[Deviation]:
    """Every deviation of the truth that the fit has (channel, emotion, phoneme)."""
    fm, tm = emotions_of(fitted), emotions_of(truth)
    out = []
    for ch, fc in fm["channels"].items():
        tc = tm["channels"].get(ch)
        if tc is None:
            continue
        for emotion, per in fc["deviations"].items():
            for ph, d in per.items():
                if ph in tc["deviations"].get(emotion, {}):
                    out.append(Deviation(ch, emotion, ph, float(tc["deviations"][emotion][ph]), float(d),
                                         float(fc.get("deviation_sd", {}).get(emotion, {}).get(ph, float("nan")))))
    return out


def dynamics_report(fitted: ParameterTable, truth: ParameterTable, tolerance: float) -> bool:
    """A fit with ``[model] emotions = "targets+dynamics"``: per channel and parameter the largest error of
    the emotions' log deviations (the truth's, 0 where it plants none), and the sd per emotion that
    empirical Bayes gave (metadata.pooling; near 0: pooled into the neutral rates). True when every one is
    within ``tolerance``; True without a word for a fit without them."""
    fm, tm = emotions_of(fitted), emotions_of(truth)
    pooling = (fitted.metadata or {}).get("pooling") or {}
    ok = True
    for ch, fc in fm["channels"].items():
        truth_dyn = (tm["channels"].get(ch) or {}).get("dynamics") or {}
        for q, d in (fc.get("dynamics") or {}).items():
            errs = [(abs(v - float(truth_dyn.get(q, {}).get("deviations", {}).get(e, {}).get(ph, 0.0))), e, ph)
                    for e, per in d["deviations"].items() for ph, v in per.items() if ph in truth.values]
            if not errs:
                continue
            worst = max(errs)
            fams = (pooling.get(ch) or {}).get("families") or {}
            sds = " ".join(f"{e[:4]} {fams[f'emotion {q} {e}']['sd']:.3f}" for e in d["deviations"]
                           if f"emotion {q} {e}" in fams)
            print(f"{ch:8} {q:9} log deviations: max error {worst[0]:.3f} ({worst[1][:4]} {worst[2]}), "
                  f"{sum(x <= tolerance for x, _, _ in errs)}/{len(errs)} within {tolerance:g}; sd per emotion {sds}")
            ok &= worst[0] <= tolerance
    return ok


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("fit_dir", type=Path, nargs="?", default=Path("results/emotive"))
    ap.add_argument("truth", type=Path, nargs="?", default=Path("build/emotive/ground_truth.json"))
    ap.add_argument("--tolerance", type=float, default=TOLERANCE_MM, help="mm (default %(default)s)")
    ap.add_argument("--dynamics-tolerance", type=float, default=TOLERANCE_LOG,
                    help="log units, for a fit with emotions = \"targets+dynamics\" (default %(default)s)")
    a = ap.parse_args(argv)
    fitted = ParameterTable.load(a.fit_dir / "table.json")
    truth = ParameterTable.load(a.truth)
    devs = deviations(fitted, truth)
    if not devs:
        print("no deviation of the truth in the fit")
        return 1
    fm = emotions_of(fitted)
    ok = True
    print(f"{'channel':8} {'neutral max|dT|':>16} {'max |dd|':>18} {'within':>10} {'credible':>9} "
          f"{'true non-0 caught':>18}  tau per emotion (mm)")
    for ch in fm["channels"]:
        rows = [d for d in devs if d.channel == ch]
        if not rows:
            continue
        worst = max(rows, key=lambda d: d.error)
        within = sum(d.error <= a.tolerance for d in rows)
        nonzero = [d for d in rows if abs(d.truth) > 0]
        caught = sum(d.credible for d in nonzero)
        terr = max(abs(fitted.values[p][ch]["target"] - truth.values[p][ch]["target"])
                   for p in fitted.phonemes_for(ch) if p in truth.values)
        tau = fm["channels"][ch].get("tau", {})
        print(f"{ch:8} {terr:16.3f} {worst.error:9.3f} ({worst.emotion[:4]} {worst.phoneme:>2}) "
              f"{within:4d}/{len(rows):<4d} {sum(d.credible for d in rows):9d} {caught:9d} of {len(nonzero):<6d}  "
              + " ".join(f"{e[:4]} {t:.2f}" for e, t in tau.items()))
        ok &= within == len(rows)
    fa, ta = fm.get("asymmetry") or {}, emotions_of(truth).get("asymmetry") or {}
    if ta:  # the corner asymmetries (measured on the markers, relative to the neutral trials)
        rows_a = [(e, k, float(fa[e][k]["value"]), float(ta[e][k]) - float(ta.get("neutral", {}).get(k, 0.0)),
                   float(fa[e][k]["q2.5"]), float(fa[e][k]["q97.5"]))
                  for e in ta if e in fa for k in ("ASYMX", "ASYMY")]
        missing = [e for e in ta if e != "neutral" and e not in fa]
        print("corner asymmetry (mm, fitted [95 %] / truth): " + "  ".join(
            f"{e[:4]} {k[-1]} {v:+.2f} [{lo:+.2f},{hi:+.2f}]/{t:+.1f}" for e, k, v, t, lo, hi in rows_a))
        off_a = [(e, k) for e, k, v, t, _, _ in rows_a if abs(v - t) > a.tolerance]
        if off_a or missing:
            print(f"  asymmetry off or missing: {off_a} {missing}")
            ok = False
    ok &= dynamics_report(fitted, truth, a.dynamics_tolerance)
    bad = [d for d in devs if d.error > a.tolerance]
    for d in sorted(bad, key=lambda d: -d.error)[:10]:
        print(f"  off: {d.channel} {d.emotion} /{d.phoneme}/ fitted {d.fitted:+.3f} truth {d.truth:+.3f} mm")
    print(f"every deviation within {a.tolerance:g} mm ({len(devs)} of them)" if ok
          else f"{len(bad)} of {len(devs)} deviations NOT within {a.tolerance:g} mm")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
