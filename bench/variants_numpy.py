"""Dominance variants that may explain rate effects, fitted in the NumPy reference (issue 10 item 3).

The gestures flavour of the synthetic session (critically damped gestures, corpus-synthetic/
gestures.py) is data the model did not make: its segments undershoot more at the fast rate. This
script fits each dominance variant of tests/python/numpy_model.py (docs/VARIANTS.md) by SciPy
least squares (trf, finite differences grouped by the sparsity "a phoneme only moves the trials it
occurs in") and scores it on data the fit did not see:

- fit the normal rate (all repetitions), RMSE on the fast rate;
- fit repetitions 1-4 (both rates), RMSE on repetition 5.

It mirrors fit/synthetic.toml (modified model, /a/ the reference α = 1, every parameter free but
σ ψ, which are free for /a p b m/ on LLO only; staged: targets, then α θ c δ, then k_R σ ψ; the
spec's default starts and bounds), so that the "centre" row is the product's fit redone in NumPy.
The product's own numbers are bench/generalisation.py's. Not part of `make test` (minutes of CPU):

    coartic corpus synth build/gestures --flavour gestures
    .venv/bin/python bench/variants_numpy.py build/gestures/manifest.csv      # -> bench/results/variants_numpy.txt

``--dominance`` / ``--channels`` / ``--splits`` restrict the runs (CPU is scarce: one variant, one
channel and one split is a minute or two); ``--append`` adds a run to the results file, whose
header lines record each run's arguments; ``--out`` writes elsewhere.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.optimize import least_squares

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))
import numpy_model as nm  # type: ignore[import-not-found]  # noqa: E402

from coartic.model import Utterance  # noqa: E402
from coartic.estimation.settings import DEFAULT_FIT_BOUNDS, DEFAULT_START  # noqa: E402
from coartic.io import load_trial  # noqa: E402
from coartic.table import PARAMETERS  # noqa: E402

F64 = npt.NDArray[np.float64]
LOG = {"alpha", "theta_bw", "theta_fw", "psi"}
STAGES = (("target",), ("alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "delta"), ("k_r", "sigma", "psi"))
FREE = ("target", "alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "k_r", "delta")
SHAPE_FREE = {"LLO": ("a", "p", "b", "m")}  # fit/synthetic.toml's [[override]] (ULO too; not fitted here)
REFERENCE = "a"
# Each variant: (label, keyword arguments of numpy_model.evaluate_batch).
VARIANTS: dict[str, dict[str, Any]] = {
    "centre": {"dominance": "centre"},
    "segment": {"dominance": "segment"},
    "interval": {"dominance": "interval"},
    "plateau-0.25": {"dominance": "plateau", "plateau_fraction": 0.25},
    "plateau-0.5": {"dominance": "plateau", "plateau_fraction": 0.5},
    "handover": {"dominance": "centre", "handover": True},
    "plateau-0.4+handover": {"dominance": "plateau", "plateau_fraction": 0.4, "handover": True},
    "plateau-0.5+handover": {"dominance": "plateau", "plateau_fraction": 0.5, "handover": True},
    "plateau-0.6+handover": {"dominance": "plateau", "plateau_fraction": 0.6, "handover": True},
    "segment+handover": {"dominance": "segment", "handover": True},
}


def load(manifest: Path, channels: tuple[str, ...]) -> list[Utterance]:
    """Every trial of a manifest through coartic.io (the reader the product uses; sil -> #)."""
    with manifest.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out = []
    for r in rows:
        trial = load_trial(manifest.parent / r["file"], labels=manifest.parent / r["labels"])
        ch = trial.channels(list(channels))
        seg = trial.segments
        assert seg is not None
        out.append(Utterance(name=r["stimulus"], labels=tuple(seg.labels), starts=np.asarray(seg.starts, float),
                             ends=np.asarray(seg.ends, float), times=np.asarray(ch.times, float),
                             observed={c: np.asarray(ch[c], float) for c in channels},
                             valid={c: np.asarray(ch.valid[c], bool) for c in channels},
                             meta={k: r[k] for k in ("vowel", "consonant", "repetition", "rate")}))
    return out


@dataclass
class Batch:
    """Utterances of one channel padded to one array (all VCV trials have 5 segments)."""

    rows: npt.NDArray[np.int64]  # [B, N]
    starts: F64
    ends: F64
    times: F64  # [B, S], padded with the last time
    y: F64
    mask: npt.NDArray[np.bool_]  # valid and not padding
    vowel: list[str]

    @classmethod
    def build(cls, utts: list[Utterance], channel: str, phonemes: list[str]) -> Batch:
        n = {len(u.labels) for u in utts}
        if len(n) != 1:
            raise ValueError(f"segment counts differ: {sorted(n)}")
        s = max(len(u.times) for u in utts)
        times = np.array([np.pad(u.times, (0, s - len(u.times)), mode="edge") for u in utts])
        y = np.array([np.pad(u.observed[channel], (0, s - len(u.times))) for u in utts])
        mask = np.array([np.pad(u.valid[channel] & np.isfinite(u.observed[channel]), (0, s - len(u.times)))
                         for u in utts])
        return cls(np.array([[phonemes.index(lab) for lab in u.labels] for u in utts]),
                   np.array([u.starts for u in utts]), np.array([u.ends for u in utts]), times,
                   np.where(mask, y, 0.0), mask, [u.meta["vowel"] for u in utts])

    def evaluate(self, params: F64, kw: dict[str, Any]) -> F64:
        return nm.evaluate_batch(params, self.rows, self.starts, self.ends, self.times, **kw)  # type: ignore[no-any-return]

    def rmse(self, params: F64, kw: dict[str, Any]) -> float:
        r = (self.evaluate(params, kw) - self.y)[self.mask]
        return float(np.sqrt(np.mean(r**2)))

    def vowel_rmse(self, params: F64, kw: dict[str, Any]) -> dict[str, float]:
        r2 = np.where(self.mask, (self.evaluate(params, kw) - self.y) ** 2, 0.0)
        v = np.array(self.vowel)
        return {k: float(np.sqrt(r2[v == k].sum() / self.mask[v == k].sum())) for k in sorted(set(self.vowel))}


def fit(train: Batch, channel: str, phonemes: list[str], kw: dict[str, Any], max_nfev: int) -> tuple[F64, int, list[str]]:
    """Staged least squares as fit/synthetic.toml; returns params, evaluations, parameters at a bound."""
    n_ph = len(phonemes)
    params = np.tile([DEFAULT_START[p] for p in PARAMETERS], (n_ph, 1)).astype(float)
    lower = np.tile([DEFAULT_FIT_BOUNDS.get(p, (-np.inf, np.inf))[0] for p in PARAMETERS], (n_ph, 1))
    upper = np.tile([DEFAULT_FIT_BOUNDS.get(p, (-np.inf, np.inf))[1] for p in PARAMETERS], (n_ph, 1))
    # Targets start at the data's mean at each phoneme's segment midpoints, box = data range ± 5 mm.
    mid = 0.5 * (train.starts + train.ends)
    for k in range(n_ph):
        vals = [np.interp(m, t, y) for b in range(len(train.rows)) for m, t, y, r in
                zip(mid[b], [train.times[b]] * 5, [train.y[b]] * 5, train.rows[b]) if r == k]
        params[k, 0] = np.mean(vals)
    ymin, ymax = train.y[train.mask].min(), train.y[train.mask].max()
    lower[:, 0], upper[:, 0] = ymin - 5.0, ymax + 5.0
    free = np.zeros((n_ph, 10), bool)
    for j, p in enumerate(PARAMETERS):
        free[:, j] = p in FREE
    free[phonemes.index(REFERENCE), PARAMETERS.index("alpha")] = False
    for ph in SHAPE_FREE.get(channel, ()):
        if ph in phonemes:
            free[phonemes.index(ph), [PARAMETERS.index("sigma"), PARAMETERS.index("psi")]] = True
    log_col = np.array([p in LOG for p in PARAMETERS])
    present = np.zeros((len(train.rows), n_ph), bool)
    for b, r in enumerate(train.rows):
        present[b, r] = True
    nfev = 0
    for st in range(len(STAGES)):
        names = {p for s in STAGES[: st + 1] for p in s}
        stage = free & np.array([p in names for p in PARAMETERS])[None, :]
        idx = np.flatnonzero(stage.ravel())
        lg = np.tile(log_col, n_ph)[idx]
        lo, hi = lower.ravel()[idx], upper.ravel()[idx]
        lo = np.where(lg, np.log(np.maximum(lo, 1e-300)), lo)
        hi = np.where(lg, np.log(hi), hi)

        def unpack(x: F64, idx: npt.NDArray[np.intp] = idx, lg: npt.NDArray[np.bool_] = lg) -> F64:
            p = params.copy()
            p.ravel()[idx] = np.where(lg, np.exp(x), x)
            return p

        def resid(x: F64) -> F64:
            return (train.evaluate(unpack(x), kw) - train.y)[train.mask]

        # Residual rows of trial b depend on the columns of the phonemes it contains.
        rows_of = np.repeat(np.arange(len(train.rows)), train.mask.sum(axis=1))
        col_ph = idx // 10
        sparsity = sp.csr_matrix(present[rows_of][:, col_ph].astype(np.int8))
        v = params.ravel()[idx]
        x0 = np.clip(np.where(lg, np.log(np.maximum(v, 1e-300)), v), lo, hi)
        res = least_squares(resid, x0, bounds=(lo, hi), jac_sparsity=sparsity, x_scale="jac",
                            method="trf", max_nfev=max_nfev)
        nfev += res.nfev
        params = unpack(res.x)
    final = np.flatnonzero(free.ravel())
    vals, lo_n, hi_n = params.ravel()[final], lower.ravel()[final], upper.ravel()[final]
    # k_R at 0 or 1 is expected (MODEL.md); other parameters at a bound are listed, "+" at the upper.
    at = [f"{phonemes[i // 10]}.{PARAMETERS[i % 10]}{'+' if np.isclose(v, b, rtol=1e-6) else '-'}"
          for i, v, a, b in zip(final, vals, lo_n, hi_n)
          if PARAMETERS[i % 10] not in ("target", "k_r") and (np.isclose(v, a, rtol=1e-6) or np.isclose(v, b, rtol=1e-6))]
    return params, nfev, at


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("manifest", type=Path)
    ap.add_argument("--channels", default="LLO,JO")
    ap.add_argument("--dominance", default=",".join(VARIANTS), help=f"comma-separated, of {', '.join(VARIANTS)}")
    ap.add_argument("--splits", default="rate,repetition")
    ap.add_argument("--max-nfev", type=int, default=60, help="per stage")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "variants_numpy.txt")
    ap.add_argument("--append", action="store_true", help="add this run to --out instead of replacing it")
    a = ap.parse_args()
    channels = tuple(a.channels.split(","))
    utts = load(a.manifest, channels)
    phonemes = ["#"] + sorted({lab for u in utts for lab in u.labels} - {"#"})
    splits = {
        "rate": ("normal -> fast", [u for u in utts if u.meta["rate"] == "normal"],
                 [u for u in utts if u.meta["rate"] == "fast"]),
        "repetition": ("reps 1-4 -> rep 5", [u for u in utts if u.meta["repetition"] != "5"],
                       [u for u in utts if u.meta["repetition"] == "5"]),
    }
    lines = [f"# bench/variants_numpy.py {' '.join(sys.argv[1:])}: {a.manifest.parent.name} ({len(utts)} trials), "
             f"max_nfev {a.max_nfev} per stage; RMSE in mm",
             f"{'dominance':14s} {'channel':7s} {'split':18s} {'train':>7s} {'test':>7s}  worst vowel (test)   "
             "evals  s    at a bound (not k_R)"]
    print(lines[0]), print(lines[1])
    for name in a.dominance.split(","):
        kw = VARIANTS[name]
        for ch in channels:
            for sp_name in a.splits.split(","):
                label, tr, te = splits[sp_name]
                train, test = Batch.build(tr, ch, phonemes), Batch.build(te, ch, phonemes)
                t0 = time.process_time()
                params, nfev, at = fit(train, ch, phonemes, kw, a.max_nfev)
                vr = test.vowel_rmse(params, kw)
                worst = max(vr.items(), key=lambda kv: kv[1])
                line = (f"{name:14s} {ch:7s} {label:18s} {train.rmse(params, kw):7.3f} {test.rmse(params, kw):7.3f}  "
                        f"{worst[1]:.3f} ({worst[0]})          {nfev:5d} {time.process_time() - t0:4.0f}  "
                        f"{len(at)} {' '.join(at)}")
                print(line, flush=True)
                lines.append(line)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=a.out.parent, prefix=a.out.name + ".")
    earlier = a.out.read_text() if a.append and a.out.exists() else ""
    with os.fdopen(fd, "w") as f:
        f.write(earlier + "\n".join(lines) + "\n")
    os.replace(tmp, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
