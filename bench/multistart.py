"""Multi-start estimation (coartic.fit.multistart): its cost as a ratio to one start, the share of
starts that reach the best optimum, against nlopt's global MLSL and against the single start.

    .venv/bin/python bench/multistart.py [synthetic|german|workers ...]   (default: all)

- synthetic: LLO of the synthetic session, the 150 trials of /p f t l s/ (fit/synthetic.toml;
  `coartic corpus synth build/session` first), as in fit/compare_engines.py;
- german: LA and JO of the two German EMA utterances (fit/ema_german.toml);
- workers: 8 starts one after the other (rayon inside each evaluation) against two at once in
  threads, on the synthetic LLO.

Every line is measured in the same run: ratios are to the single start of the same data.
Output saved in bench/results/multistart.txt (all parts) or multistart_<parts>.txt;
bench/results/multistart_synthetic_german.txt has the default [fit], and
multistart_quasirandom_only.txt the same before start 0 was [parameters.start] (with the workers).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from coartic.fit import runner
from coartic.fit.data import load_utterances, manifest_rows
from coartic.model import Utterance
from coartic.fit.runner import fit_channel
from coartic.fit.spec import FitSpec, load_spec

ROOT = Path(__file__).resolve().parent.parent


def line(label: str, fit: Any, wall: float, ref_wall: float | None) -> str:
    ms = fit.multistart
    ratio = f"{wall / ref_wall:5.2f}x" if ref_wall else "  1.00x"
    extra = ""
    if ms is not None:
        n = fit.problem.data.n_valid
        rm = ", ".join(f"{math.sqrt(o.sse / n):.4f}" for o in ms.optima[:4])
        extra = (f"; {len(ms.optima)} optima (RMSE {rm}{' ...' if len(ms.optima) > 4 else ''}), best reached by "
                 f"{ms.best.hits}/{len(ms.continued)} continued of {ms.n_starts}")
    return (f"  {label:<34} RMSE {fit.rmse:.4f} mm  {fit.nfev:6d} evals  {wall:7.1f} s  {ratio}  "
            f"[{fit.status}]{extra}")


def timed(spec: FitSpec, utts: Sequence[Utterance], ch: str) -> tuple[Any, float]:
    t0 = time.perf_counter()
    fit = fit_channel(spec, utts, ch)
    return fit, time.perf_counter() - t0


def compare(title: str, spec: FitSpec, utts: Sequence[Utterance], channels: Sequence[str]) -> list[str]:
    out = [title]
    print(title, flush=True)
    for ch in channels:
        s1 = spec.with_options(starts=1)
        one, w1 = timed(s1, utts, ch)
        rows = [line(f"{ch} one start ([parameters.start])", one, w1, None)]
        for label, s in [
            ("32 starts, seed 0 (default)", spec.with_options(starts=32, seed=0)),
            ("32 starts, seed 1", spec.with_options(starts=32, seed=1)),
            ("nlopt MLSL-LDS + L-BFGS, one start", s1.with_options(
                engine="nlopt", engine_options={"global": "mlsl", "global_maxeval": 4000})),
        ]:
            fit, w = timed(s, utts, ch)
            rows.append(line(f"{ch} {label}", fit, w, w1))
            print(rows[-1], flush=True)
        print(rows[0], flush=True)
        out += rows
    return out


def synthetic_data() -> tuple[FitSpec, list[Utterance]]:
    spec = load_spec(ROOT / "fit/synthetic.toml").with_options(channels=("LLO",))
    rows = [r for r in manifest_rows(spec) if r.get("consonant") in ("p", "f", "t", "l", "s")]
    return spec, load_utterances(spec, rows)


def german_data() -> tuple[FitSpec, list[Utterance]]:
    spec = load_spec(ROOT / "fit/ema_german.toml")
    return spec, load_utterances(spec, manifest_rows(spec))


def workers() -> list[str]:
    spec, utts = synthetic_data()
    out = ["workers: 8 starts on synthetic LLO (150 trials), one after the other vs two threads"]
    print(out[0], flush=True)
    ref = None
    for w in (1, 2):
        runner.MULTISTART_WORKERS = w
        fit, wall = timed(spec.with_options(starts=8), utts, "LLO")
        ref = ref or wall
        out.append(line(f"LLO 8 starts, {w} worker(s)", fit, wall, ref))
        print(out[-1], flush=True)
    runner.MULTISTART_WORKERS = 1
    return out


def main(parts: Sequence[str]) -> None:
    lines: list[str] = []
    name = "multistart.txt" if set(parts) >= {"synthetic", "german", "workers"} else f"multistart_{'_'.join(parts)}.txt"

    def save() -> None:  # after every part: a long run keeps what it measured
        (ROOT / "bench/results" / name).write_text("\n".join(lines) + "\n", encoding="utf-8")

    for part in parts:
        if part == "synthetic":
            spec, utts = synthetic_data()
            lines += compare(f"synthetic session, LLO, {len(utts)} trials of /p f t l s/ (fit/synthetic.toml)", spec,
                             utts, ["LLO"])
        elif part == "german":
            spec, utts = german_data()
            lines += compare("German EMA, two utterances, LA and JO (fit/ema_german.toml)", spec, utts, ["LA", "JO"])
        elif part == "workers":
            lines += workers()
        else:
            raise SystemExit(f"unknown part {part!r} (synthetic, german, workers)")
        save()
    print(f"saved bench/results/{name}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["synthetic", "workers", "german"])
