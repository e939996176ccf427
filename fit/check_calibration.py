"""Are least-squares error bars right on the synthetic session? Why the MCMC samples per-utterance offsets.

For each seed, the /p t f/ trials of the quick synthetic session (corpus-synthetic/, repetitions
1-2, both rates) are generated and one channel is fitted by least squares, with target, θ_bw, θ_fw
and k_R free and every other parameter at the generator's value, twice:

* recorded: the channel as the readers give it (lab-frame markers with noise, head frame, a rest
  reference estimated per trial);
* independent: the same trials and timings, the generator's noiseless channel plus independent
  Gaussian noise of the recorded residual RMS.

Over all seeds and parameters (k_R = 1 on its bound left out) it prints the spread of
z = (truth − estimate) / standard error, which is 1 when the error bars are right, and the share
outside ±1.96; and the spread of each utterance's mean residual against what independent noise
explains (σ / √n). On the recorded channel the utterance means spread more, by a per-utterance
offset: the error of the rest reference, which `coartic mcmc` integrates out (docs/MCMC.md).

Run: .venv/bin/python fit/check_calibration.py [--seeds 40] [--channel LLO]
(output saved in fit/results/check_calibration.txt; about 3 s per seed)
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SPEC = """
[corpus]
manifest = "{manifest}"
[model]
channels = ["{channel}"]
reference_phoneme = "a"
[parameters]
free = ["target", "theta_bw", "theta_fw", "k_r"]
start_table = "{truth}"
[staging]
enabled = false
"""


def z_scores(fit_dir: Path, truth: object, channel: str) -> list[float]:
    out = []
    for row in csv.DictReader(open(fit_dir / "parameters.csv", encoding="utf-8")):
        if row["free"] != "True" or row["at_bound"] == "True" or not row["stderr"]:
            continue
        value = truth.values[row["phoneme"]][channel][row["parameter"]]  # type: ignore[attr-defined]
        if row["parameter"] == "k_r" and value == 1.0:
            continue  # on its bound: no symmetric error bar
        out.append((value - float(row["value"])) / float(row["stderr"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--channel", default="LLO")
    args = ap.parse_args()

    from coartic.fit import run
    from coartic.fit.data import load_utterances
    from coartic.fit.spec import load_spec
    from coartic.synthetic_cli import load_generator
    from coartic.table import ParameterTable

    generator = load_generator()
    truth = ParameterTable.load(generator.GROUND_TRUTH)
    ch = args.channel
    z: dict[str, list[float]] = {"recorded": [], "independent": []}
    spread: dict[str, list[float]] = {"recorded": [], "independent": []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            root = Path(tmp) / f"seed{seed}"
            manifest = generator.generate(root / "session", seed=seed, quick=True, progress=False, consonants=["p", "t", "f"])
            (root / "spec.toml").write_text(SPEC.format(manifest=manifest, channel=ch, truth=generator.GROUND_TRUTH))
            spec = load_spec(root / "spec.toml")
            recorded = load_utterances(spec)
            rng = np.random.default_rng(seed)
            independent = []
            results = {"recorded": run(spec, root / "recorded", utterances=recorded, quiet=True)}
            data = results["recorded"].channels[ch].problem.data
            valid = data.weights > 0
            rms = float(np.sqrt(np.mean((data.observed - results["recorded"].channels[ch].fitted)[valid] ** 2)))
            for u in recorded:
                clean = np.load(root / "session" / u.meta["truth"])[ch]
                noisy = clean + rng.normal(0.0, rms, clean.size)
                independent.append(replace(u, observed={ch: np.where(u.valid[ch], noisy, np.nan)}))
            results["independent"] = run(spec, root / "independent", utterances=independent, quiet=True)
            for name, result in results.items():
                z[name] += z_scores(root / name, truth, ch)
                cf = result.channels[ch]
                d = cf.problem.data
                residual = d.observed - cf.fitted
                for k in range(len(d.utterances)):
                    r = residual[d.utterance_samples(k)][d.weights[d.utterance_samples(k)] > 0]
                    if r.size > 1:
                        spread[name].append(float(r.mean() / (rms / np.sqrt(r.size))))
            print(f"seed {seed} done", file=sys.stderr)
    print(f"{args.seeds} seeds (from {args.first_seed}), /p t f/ in /i a u/, quick session, channel {ch}; "
          "target, theta_bw, theta_fw, k_r free")
    print(f"{'channel data':12s} {'n':>5s} {'sd of z':>8s} {'|z| > 1.96':>10s} {'utterance means / (sigma/sqrt n)':>34s}")
    for name in z:
        zz, ss = np.array(z[name]), np.array(spread[name])
        print(f"{name:12s} {zz.size:5d} {zz.std():8.3f} {np.mean(np.abs(zz) > 1.96):10.3f} {ss.std():34.3f}")


if __name__ == "__main__":
    main()
