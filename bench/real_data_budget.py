"""Does the evaluation budget stop the rate-aware fits of the real German EMA? (issue 19 item 3)

bench/real_data.py showed rate-aware fits ending at "max-evaluations" with per-phoneme dynamics
free. This fits the training set of every held-out split of bench/real_data.py (utterance 0024
alone, 0020 alone, the two first halves) with the rate-aware model, one local fit each
(``--starts 1``), at the engine's default budget (``coartic.fit.engines.base.evaluation_budget``)
and at ``--factor`` times it, and prints per channel: the status and evaluations of every stage, the
in-sample SSE, and the held-out RMSE (bench/real_data.py's scoring) of both. If more evaluations
lower neither the SSE nor the held-out error materially, the cap is not what limits the fit.
Output in bench/results/real_data_budget.txt:

    nice -n 10 .venv/bin/python bench/real_data_budget.py --out bench/results/real_data_budget.txt
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from real_data import FREEDOM, cell_spec, fit_and_score, splits  # noqa: E402

from coartic.fit import load_spec, run  # noqa: E402
from coartic.fit.data import load_utterances  # noqa: E402
from coartic.fit.engines.base import evaluation_budget  # noqa: E402
from coartic.estimation.problem import build_problem  # noqa: E402
from coartic.io.labelmap import resolve_label_map  # noqa: E402
from coartic.outputs import atomic_write_text  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--freedom", default="tat")
    ap.add_argument("--reg", default="none")
    ap.add_argument("--variant", default="rate-aware")
    ap.add_argument("--factor", type=int, default=4)
    ap.add_argument("--channels", default="LA,JO")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    base = load_spec(ROOT / "fit" / "ema_german.toml").with_options(channels=tuple(a.channels.split(",")))
    utts = load_utterances(base)
    label_map = resolve_label_map(base.corpus.label_map)
    lines = ["# bench/real_data_budget.py: rate-aware fits of the German EMA at the default budget and at "
             f"{a.factor}x it (one local fit each)",
             f"# command: nice -n 10 .venv/bin/python bench/real_data_budget.py {' '.join(sys.argv[1:])}".rstrip(),
             f"{'freedom':9s} {'reg':10s} {'train of':11s} {'ch':3s} {'budget':>7s} {'status':16s} {'evals':>6s} "
             f"{'SSE':>10s} {'held-out':>8s}  stages (status evaluations)"]
    print("\n".join(lines), flush=True)
    t0 = time.perf_counter()
    for f in a.freedom.split(","):
        for reg in a.reg.split(","):
            spec = cell_spec(base, a.variant, FREEDOM[f], reg, starts=1)
            for name, train, test in splits(utts):
                for ch in spec.channels:
                    one = spec.with_options(channels=(ch,))
                    prob = build_problem(one.estimation_settings(), train, ch)
                    # the budget of the biggest stage: the full free set's is an upper bound
                    default = evaluation_budget(prob)
                    for label, opts in (("default", {}), (f"{a.factor}x", {"max_nfev": a.factor * default})):
                        sp = one.with_options(engine={"options": opts})
                        res = run(sp, utterances=train, quiet=True)
                        fit = res.channels[ch]
                        sse = fit.rmse ** 2 * fit.problem.data.n_valid
                        got = fit_and_score(sp, train, test, ch, label_map, "constant", trained=res)
                        stages = ", ".join(f"{st.engine.status} {st.engine.nfev}" for st in fit.stages)
                        lines.append(f"{f:9s} {reg:10s} {name:11s} {ch:3s} {label:>7s} {fit.status:16s} {fit.nfev:6d} "
                                     f"{sse:10.2f} {got['table']:8.3f}  {stages}")
                        print(lines[-1], flush=True)
    lines.append(f"({time.perf_counter() - t0:.0f} s wall)")
    if a.out:
        atomic_write_text(a.out, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
