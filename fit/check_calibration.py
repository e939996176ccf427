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

With ``--mcmc`` it also samples the joint posterior of the channel on the recorded data with
`coartic mcmc` (``scope = "channel"``, the command's defaults otherwise, as the calibration test
does) and prints, per seed, how many identified parameters hold the truth inside their 95 %
interval: about 3 minutes per seed on 2 CPUs.

Run: .venv/bin/python fit/check_calibration.py [--seeds 40] [--channel LLO]
     .venv/bin/python fit/check_calibration.py --mcmc --seed 20021014 --seed 1 ... --seed 6
(output saved in fit/results/check_calibration.txt and check_calibration_mcmc.txt; about 3 s per
seed without --mcmc)
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
{override}
[staging]
enabled = false
[mcmc]
scope = "channel"
ensembles = 2
max_steps = 20000
plots = false
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


def mcmc_coverage(root: Path, truth: object, channel: str, median_z: dict[str, list[float]]) -> tuple[int, int]:
    """`coartic mcmc` on the recorded fit; (truths inside the 95 % interval, identified parameters).
    Appends (truth − median) / sd of every identified parameter to ``median_z``."""
    import json

    from typer.testing import CliRunner

    from coartic.cli import app
    from coartic.mcmc.summary import covers

    out = root / "mcmc"
    r = CliRunner().invoke(app, ["mcmc", str(root / "spec.toml"), "--fit", str(root / "recorded"), "--out", str(out), "--quiet"])
    if r.exit_code != 0:
        raise SystemExit(f"{root}: coartic mcmc failed: {r.output}")
    summary = json.loads((out / channel / "_joint" / "summary.json").read_text())
    if not summary["converged"]:
        print(f"{root}: NOT CONVERGED: {summary['convergence']['problems']}", flush=True)
    inside = identified = 0
    for p in summary["parameters"]:
        if "." not in p["name"] or not p["identified"]:
            continue
        phoneme, parameter = p["name"].split(".")
        value = truth.values[phoneme][channel][parameter]  # type: ignore[attr-defined]
        q = p["quantiles"]
        median_z.setdefault(p["name"], []).append((value - q["q50"]) / p["sd"])
        identified += 1
        inside += covers(value, q["q2.5"], q["q97.5"], truth.bounds_for(channel, parameter))  # type: ignore[attr-defined]
    return inside, identified


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--seed", type=int, action="append", help="these seeds instead of --first-seed/--seeds")
    ap.add_argument("--channel", default="LLO")
    ap.add_argument("--mcmc", action="store_true", help="also sample the joint posterior and count covered truths")
    ap.add_argument("--fix-kr", default="", metavar="PHONEMES",
                    help="hold k_R = 1 (its true value, on its bound) for these phonemes, e.g. '#,p,f'")
    args = ap.parse_args()
    seeds = args.seed or list(range(args.first_seed, args.first_seed + args.seeds))
    fixed = [p for p in args.fix_kr.split(",") if p]
    override = f"[[override]]\nphonemes = {fixed!r}\nfixed = {{ k_r = 1.0 }}".replace("'", '"') if fixed else ""

    from coartic.jobs.fit import fit_job
    from coartic.fit.data import load_utterances
    from coartic.fit.spec import load_spec
    from coartic.synthetic_cli import load_generator
    from coartic.table import ParameterTable

    generator = load_generator()
    truth = ParameterTable.load(generator.GROUND_TRUTH)
    ch = args.channel
    z: dict[str, list[float]] = {"recorded": [], "independent": []}
    coverage: list[tuple[int, int, int]] = []
    median_z: dict[str, list[float]] = {}
    spread: dict[str, list[float]] = {"recorded": [], "independent": []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            root = Path(tmp) / f"seed{seed}"
            manifest = generator.generate(root / "session", seed=seed, quick=True, progress=False, consonants=["p", "t", "f"])
            (root / "spec.toml").write_text(SPEC.format(manifest=manifest, channel=ch, truth=generator.GROUND_TRUTH, override=override))
            spec = load_spec(root / "spec.toml")
            recorded = load_utterances(spec)
            rng = np.random.default_rng(seed)
            independent = []
            results = {"recorded": fit_job(spec, root / "recorded", utterances=recorded, quiet=True)}
            data = results["recorded"].channels[ch].problem.data
            valid = data.weights > 0
            rms = float(np.sqrt(np.mean((data.observed - np.asarray(results["recorded"].channels[ch].fitted))[valid] ** 2)))
            for u in recorded:
                clean = np.load(root / "session" / u.meta["truth"])[ch]
                noisy = clean + rng.normal(0.0, rms, clean.size)
                independent.append(replace(u, observed={ch: np.where(u.valid[ch], noisy, np.nan)}))
            results["independent"] = fit_job(spec, root / "independent", utterances=independent, quiet=True)
            for name, result in results.items():
                z[name] += z_scores(root / name, truth, ch)
                cf = result.channels[ch]
                d = cf.problem.data
                residual = d.observed - np.asarray(cf.fitted)
                for k in range(len(d.utterances)):
                    r = residual[d.utterance_samples(k)][d.weights[d.utterance_samples(k)] > 0]
                    if r.size > 1:
                        spread[name].append(float(r.mean() / (rms / np.sqrt(r.size))))
            if args.mcmc:
                coverage.append((seed, *mcmc_coverage(root, truth, ch, median_z)))
                print(f"seed {seed}: {coverage[-1][1]} of {coverage[-1][2]} identified truths inside their 95 % intervals",
                      flush=True)
            print(f"seed {seed} done", file=sys.stderr)
    if args.mcmc:
        inside, identified = sum(c[1] for c in coverage), sum(c[2] for c in coverage)
        print(f"joint posterior, {len(coverage)} seeds: {inside} of {identified} = {100 * inside / identified:.1f} %; "
              f"seeds below 90 %: {sum(c[1] < 0.9 * c[2] for c in coverage)}")
    print(f"{len(seeds)} seeds ({', '.join(map(str, seeds[:3]))}{' ...' if len(seeds) > 3 else ''}), /p t f/ in /i a u/, "
          f"quick session, channel {ch}; target, theta_bw, theta_fw, k_r free"
          + (f"; k_r held at 1 for {' '.join(fixed)}" if fixed else ""))
    if args.mcmc:
        print("posterior medians against the truth, (truth - median) / sd, mean over seeds:")
        for name, zs in sorted(median_z.items()):
            print(f"  {name:14s} {np.mean(zs):6.2f}")
    print(f"{'channel data':12s} {'n':>5s} {'sd of z':>8s} {'|z| > 1.96':>10s} {'utterance means / (sigma/sqrt n)':>34s}")
    for name in z:
        zz, ss = np.array(z[name]), np.array(spread[name])
        print(f"{name:12s} {zz.size:5d} {zz.std():8.3f} {np.mean(np.abs(zz) > 1.96):10.3f} {ss.std():34.3f}")


if __name__ == "__main__":
    main()
