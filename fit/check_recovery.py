"""Compare a fit of the synthetic session with its ground truth, against issue 4's bar.

    .venv/bin/python fit/check_recovery.py results/synthetic [build/session/ground_truth.json]

Prints per channel: RMSE overall and per vowel context (bar: < 0.3 mm), the largest target errors
(bar: within 0.2 mm of the truth) and k_R of /p b m f v/ where the truth has k_R = 1 (bar: >= 0.9). A driver to copy: it only
reads the fit's table.json and rmse.csv.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

from coartic.table import ParameterTable

BILABIAL_LABIODENTAL = ("p", "b", "m", "f", "v")


def main(fit_dir: Path, truth_path: Path) -> int:
    fitted = ParameterTable.load(fit_dir / "table.json")
    truth = ParameterTable.load(truth_path)
    with (fit_dir / "rmse.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    ok = True
    print(f"{'channel':8} {'RMSE':>6} {'worst vowel':>14} {'max |dT|':>16} {'T > 0.2 mm off':>15} {'min k_R pbmfv (truth 1)':>24}")
    for ch in fitted.channels:
        rm = float(next(r["rmse_mm"] for r in rows if r["channel"] == ch and r["group"] == "all"))
        vowels = [(float(r["rmse_mm"]), r["value"]) for r in rows if r["channel"] == ch and r["group"] == "vowel"]
        worst_v = max(vowels) if vowels else (float("nan"), "-")
        errs = sorted(((abs(fitted.values[p][ch]["target"] - truth.values[p][ch]["target"]), p)
                       for p in fitted.phonemes_for(ch) if p in truth.values), reverse=True)
        off = [p for e, p in errs if e > 0.2]
        critical = [p for p in BILABIAL_LABIODENTAL if p in fitted.values and truth.values[p][ch]["k_r"] >= 0.999]
        kr = min(((fitted.values[p][ch]["k_r"], p) for p in critical), default=(float("nan"), "-"))
        print(f"{ch:8} {rm:6.3f} {worst_v[0]:8.3f} ({worst_v[1]}) {errs[0][0]:9.3f} ({errs[0][1]:>3}) "
              f"{len(off):6d} of {len(errs):2d} {kr[0]:9.3f} ({kr[1]})" + (f"   off: {' '.join(off)}" if off else ""))
        ok &= rm < 0.3 and worst_v[0] < 0.3 and not off and not kr[0] < 0.9
    print("bar met" if ok else "bar NOT met on every count (see above)")
    return 0 if ok else 1


if __name__ == "__main__":
    fit_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "results/synthetic")
    truth = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("build/session/ground_truth.json")
    sys.exit(main(fit_dir, truth))
