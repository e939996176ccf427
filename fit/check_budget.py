"""Does the default evaluation budget let a small real fit end converged? (issue 11)

Fits the first German EMA utterance of fit/ema_german.toml (LA and JO), staged and joint, with a
budget of 200 evaluations per stage (the former default) and with the engine's default, and prints
status, evaluations and SSE per channel. Output kept in fit/results/check_budget.txt:

    .venv/bin/python fit/check_budget.py | tee fit/results/check_budget.txt
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from coartic.fit import load_spec, run

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    spec = load_spec(ROOT / "fit" / "ema_german.toml")
    one = spec.with_options(corpus=dataclasses.replace(spec.corpus, limit=1))
    for label, options in (("max_nfev = 200 (old default)", {"max_nfev": 200}), ("default", {})):
        for staging in (True, False):
            r = run(one.with_options(staging={"enabled": staging}, engine={"options": options}), quiet=True)
            for ch, f in r.channels.items():
                sse = f.rmse**2 * f.problem.data.n_valid
                stages = ", ".join(f"{st.engine.status} {st.engine.nfev}" for st in f.stages)
                print(f"{label:<30} {'staged' if staging else 'joint ':<6} {ch}: {f.status:<15} {f.nfev:>5} evaluations, "
                      f"SSE {sse:8.3f}, RMSE {f.rmse:.4f} mm, {f.packing.n_free} free; stages: {stages}", flush=True)


if __name__ == "__main__":
    main()
