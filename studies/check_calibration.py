"""Are coartic perceive's intervals calibrated? Simulated intelligibility studies (coartic.perceive.simulate:
2 conditions x 6 VCV items x 2 SNRs, every participant every stimulus) with and without a planted
condition effect of -1.0 logit, analysed as `coartic perceive analyse` does. Printed per setting: the
spread (sd) of the condition estimate over the studies, the mean interval half-width / 1.96 of the
jackknife (what the report uses) and of variational Bayes' posterior sd (what BinomialBayesMixedGLM
gives alone), and how often the 95 % interval missed the truth.

    PYTHONPATH=python nice python studies/check_calibration.py [--studies 40] [--participants 20]

Results of a run: studies/results/calibration.txt.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))

from coartic.perceive.analysis import analyse  # noqa: E402
from coartic.perceive.simulate import Plant, simulate  # noqa: E402
from coartic.perceive.storage import Store  # noqa: E402
from coartic.perceive.tidy import tidy_answers  # noqa: E402
from test_perceive_study import fake_manifest  # noqa: E402


def vb_sd(tidy: object) -> float:
    """Variational Bayes' own posterior sd of the condition effect (the same model, no jackknife)."""
    from statsmodels.genmod.bayes_mixed_glm import BinomialBayesMixedGLM

    data = tidy[tidy["kind"] == "stimulus"]  # type: ignore[index]
    model = BinomialBayesMixedGLM.from_formula("correct ~ C(condition) + C(snr_db)",
                                               {"participant": "0 + C(participant)", "item": "0 + C(item)"}, data)
    return float(model.fit_vb().fe_sd[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--studies", type=int, default=40)
    ap.add_argument("--participants", type=int, default=20)
    args = ap.parse_args()
    m = fake_manifest(conditions=2, items=6, snrs=(-6.0, 0.0), attention_every=0)
    print(f"{args.studies} simulated studies of {args.participants} participants x 24 trials each")
    for effect in (0.0, -1.0):
        est, jk, vb, miss_jk, miss_vb = [], [], [], 0, 0
        for seed in range(args.studies):
            with tempfile.TemporaryDirectory() as d:
                store = Store(f"sqlite:///{d}/r.sqlite", m, "k", durable=False)
                simulate(store, args.participants, Plant(effects={"c1": effect}), seed=1000 + seed)
                tidy = tidy_answers(m, store.answer_rows())
                store.close()
            e = analyse(m, tidy).effect("condition[c1]")
            s = vb_sd(tidy)
            est.append(e.estimate)
            jk.append((e.high - e.low) / 2 / 1.96)
            vb.append(s)
            miss_jk += not (e.low <= effect <= e.high)
            miss_vb += abs(e.estimate - effect) > 1.96 * s
        print(f"planted {effect:+.1f}: estimates mean {np.mean(est):+.3f}, sd {np.std(est, ddof=1):.3f}; "
              f"jackknife sd {np.mean(jk):.3f} (95 % interval missed {miss_jk}/{args.studies}); "
              f"variational Bayes sd {np.mean(vb):.3f} (missed {miss_vb}/{args.studies})", flush=True)


if __name__ == "__main__":
    main()
