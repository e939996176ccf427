"""Does a fitted table predict speech it was not fitted on? (issue 10 item 5)

With the product's own fitting (``coartic.fit.run`` and ``coartic.evaluation.validate``, exactly what
``coartic fit --validate`` does), for each model variant the core offers:

1. **Gestures flavour** of the synthetic session (``coartic corpus synth DIR --flavour gestures``:
   critically damped gestures, data the model did not make), channels LLO and JO, fit/synthetic.toml:
   fit the normal rate and score the fast rate; fit repetitions 1-4 and score repetition 5.
2. **German EMA** (fit/ema_german.toml, two utterances of speaker mo1), leave one utterance out. The
   two utterances share only 12 of their phonemes (0020 has /p t/ that 0024 lacks, 0024 has
   /O g u m S v d/ that 0020 lacks), so the held-out utterance cannot be predicted as a whole. What is
   measured instead: the shared phonemes' parameters are fixed at the training fit, only the
   phonemes the training utterance lacks are fitted on the held-out one ("transfer"), and the RMSE
   is reported on the samples inside shared-phoneme segments and on all samples, next to a fit of
   the held-out utterance on its own (every phoneme free: the in-sample floor).

Not part of `make test` (tens of CPU minutes). Output in bench/results/generalisation.txt:

    coartic corpus synth build/gestures --flavour gestures
    .venv/bin/python bench/generalisation.py build/gestures/manifest.csv

``--variants`` picks among original, modified, rate-aware (plateau dominance + handover,
docs/VARIANTS.md; skipped with a note while the core has no such option); ``--skip-gestures`` /
``--skip-german`` run one half.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from coartic.fit import load_spec, run
from coartic.fit.data import load_utterances
from coartic.estimation.data import ChannelData
from coartic.model import Utterance
from coartic.fit.spec import FitSpec, Override
from coartic.evaluation.choose import cross_validate
from coartic.evaluation.validate import score, splits
from coartic.outputs import atomic_write_text
from coartic.table import PARAMETERS

ROOT = Path(__file__).resolve().parents[1]
# Model options of each variant, as FitSpec fields.
VARIANTS: dict[str, dict[str, Any]] = {
    "original": {"variant": "original"},
    "modified": {"variant": "modified"},
    "rate-aware": {"variant": "modified", "dominance": "plateau", "plateau_fraction": 0.5, "handover": True},
    "rate-aware-h0.4": {"variant": "modified", "dominance": "plateau", "plateau_fraction": 0.4, "handover": True},
}


# Classes for shrinkage toward a class mean ([[shrink]], docs/FITTING.md), by place of articulation;
# vowels one class. A class with fewer than two members in a corpus applies to nothing there.
CLASSES: dict[str, tuple[str, ...]] = {
    "bilabial": ("p", "b", "m"), "labiodental": ("f", "v"),
    "alveolar": ("t", "d", "n", "l", "r", "s", "z", "ts", "dz"), "postalveolar": ("tS", "dZ", "S"),
    "palatal": ("J", "L"), "velar": ("k", "g"), "vowels": ("i", "e", "a", "o", "u", "E", "O"),
}
# The dynamics shrunk: the positive scales on the log scale, the others as they are.
SHRINK_LOG = ("alpha", "theta_bw", "theta_fw")
SHRINK_NATURAL = ("c_bw", "c_fw", "k_r")
SHRINK_GRID = (0.03, 0.1, 0.3, 1.0)  # sd of every [[shrink]] (log units / natural units)
SHRINK_GROUP, SHRINK_FOLDS = "repetition", 3  # the CV inside each training set (gestures)


def shrink_options(spec: FitSpec, sd: float = 1.0, grid: Sequence[float] | None = SHRINK_GRID) -> dict[str, Any]:
    """[[shrink]] tables for every class and the free dynamics of ``spec``, and (``grid``) a
    [choose] of their sd by CV over repetitions inside the training data (the 1-SE rule)."""
    from coartic.fit.spec import Choose, Shrink

    shrinks = []
    for cls, members in CLASSES.items():
        for scale, pars in (("log", SHRINK_LOG), ("natural", SHRINK_NATURAL)):
            free = tuple(p for p in pars if p in spec.parameters.free and not (spec.model.variant == "original" and p == "k_r"))
            if free:
                shrinks.append(Shrink(members, free, sd, scale == "log", None, f"shrink {cls} {scale}"))
    opts: dict[str, Any] = {"shrinks": tuple(shrinks)}
    if grid is not None:
        opts["choose"] = Choose("shrink.sd", tuple(grid), SHRINK_GROUP, SHRINK_FOLDS, "1se")
    return opts


# Variants with shrinkage: a base variant plus shrink_options.
SHRUNK: dict[str, str] = {"rate-aware-h0.4+shrink-cv": "rate-aware-h0.4", "modified+shrink-cv": "modified",
                          "original+shrink-cv": "original"}


def variant_spec(spec: FitSpec, name: str) -> FitSpec | None:
    """The spec with the variant's options, or None when this build's FitSpec lacks one of them."""
    fields = {f.name for f in dataclasses.fields(FitSpec)}
    opts = VARIANTS[SHRUNK.get(name, name)]
    if not set(opts) <= fields:
        return None
    spec = spec.with_options(**opts)
    return spec.with_options(**shrink_options(spec)) if name in SHRUNK else spec


def gestures(manifest: Path, variants: Sequence[str], channels: tuple[str, ...], out: list[str],
             repetitions: Sequence[str] | None = None) -> None:
    base = load_spec(ROOT / "fit" / "synthetic.toml")
    base = base.with_options(corpus=dataclasses.replace(base.corpus, manifest=manifest.resolve()), channels=channels)
    utts = load_utterances(base)
    if repetitions:  # a data-poor session: only these repetitions (CV over utterances, not repetitions)
        utts = [u for u in utts if str(int(u.meta.get("repetition", "0"))) in repetitions]
    out.append(f"## gestures flavour: {manifest.parent.name}, {len(utts)} trials"
               + (f" (repetitions {','.join(repetitions)} only)" if repetitions else "")
               + f", fit/synthetic.toml, channels {' '.join(channels)}")
    out.append(f"{'variant':15s} {'split':36s} {'channel':7s} {'train':>7s} {'test':>7s} {'-offset':>7s}  "
               "worst vowel  at a bound (fit of the split)")
    for name in variants:
        spec = variant_spec(base, name)
        if spec is not None and spec.choose is not None and repetitions and len(repetitions) < 3:
            # folds dealt round-robin over the sorted files: 4 (coprime with the 21 consonants) keeps
            # every consonant in each fold's training; 3 would hold out all of a consonant's contexts
            spec = spec.with_options(choose=dataclasses.replace(spec.choose, group="utterance", folds=4))
        if spec is None:
            out.append(f"{name:15s} (skipped: this core/FitSpec has no {sorted(VARIANTS[SHRUNK.get(name, name)])} options)")
            print(out[-1], flush=True)
            continue
        for split, train, test in splits(spec, utts):
            t0 = time.process_time()
            res = run(spec, utterances=train, quiet=True, choose=cross_validate)
            if res.choice is not None:  # the CV curve inside this split's training data
                out.extend(f"{'':15s}   {line}" for line in res.choice.text_lines())
                print("\n".join(out[-len(res.choice.text_lines()):]), flush=True)
            for s in score(res, test, split):
                fit = res.channels[s.channel]
                # each with its category (coartic.estimation.bounds: domain, active, optimal, insensitive, unexplained)
                notes = fit.stats.bounds if fit.stats is not None else {}
                at = [f"{nm}({notes[nm].category if nm in notes else '?'})"
                      for nm in (fit.stats.at_bound if fit.stats is not None else [])]
                off = getattr(s, "test_rmse_offset_removed", float("nan"))  # each test utterance's offset removed
                out.append(f"{name:15s} {split:36s} {s.channel:7s} {s.train_rmse:7.3f} {s.test_rmse:7.3f} {off:7.3f}  "
                           f"{s.worst_vowel[1]:.3f} ({s.worst_vowel[0]})  {len(at)}: {' '.join(at)}")
                print(out[-1], flush=True)
            out.append(f"{'':15s} ({time.process_time() - t0:.0f} s CPU)")


def select_plateau_fraction(manifest: Path, grid: Sequence[float], channels: tuple[str, ...],
                            out: list[str]) -> None:
    """Choose h (plateau_fraction of the rate-aware variant) as a user with only normal-rate data
    would: ``[choose]`` (coartic.evaluation.choose) by 5-fold cross-validation over repetitions *within
    the normal rate*, lowest mean held-out RMSE; then score the chosen h on the fast rate, which
    took no part in the choice."""
    from coartic.fit.spec import Choose

    base = load_spec(ROOT / "fit" / "synthetic.toml")
    base = base.with_options(corpus=dataclasses.replace(base.corpus, manifest=manifest.resolve()), channels=channels)
    utts = load_utterances(base)
    normal = [u for u in utts if u.meta.get("rate") == base.validate.train_rate]
    fast = [u for u in utts if u.meta.get("rate") == base.validate.test_rate]
    out.append(f"## choosing h by 5-fold CV over repetitions within the {base.validate.train_rate} rate "
               f"({len(normal)} trials); the {base.validate.test_rate} rate ({len(fast)} trials) is scored only after")
    spec = base.with_options(**VARIANTS["rate-aware"],
                             choose=Choose("plateau_fraction", tuple(sorted(grid)), "repetition", 5, "min"))
    res = run(spec, utterances=normal, quiet=True, choose=cross_validate)
    assert res.choice is not None
    out.extend(res.choice.text_lines())
    for s in score(res, fast, f"fit {base.validate.train_rate}, test {base.validate.test_rate}"):
        out.append(f"{s.channel}: CV chooses h = {res.choice.chosen[s.channel]:g}; fit {base.validate.train_rate} rate, test "
                   f"{base.validate.test_rate} rate: train {s.train_rmse:.3f}, test {s.test_rmse:.3f} mm")
    print("\n".join(out), flush=True)


def _rmse(f: np.ndarray, data: ChannelData, keep: np.ndarray, offset: bool = False) -> float:
    w = data.weights * keep
    r = f - data.observed
    if offset:
        r = r - np.sum(w * r) / np.sum(w)
    return float(np.sqrt(np.sum(w * r**2) / np.sum(w)))


def german(variants: Sequence[str], out: list[str]) -> None:
    base = load_spec(ROOT / "fit" / "ema_german.toml")
    utts = load_utterances(base)
    out.append(f"## German EMA (fit/ema_german.toml), leave one utterance out; RMSE (mm) on the held-out "
               "utterance")
    out.append("shared segs: samples inside segments of phonemes both utterances have (pauses excluded); "
               "-offset: after removing the mean residual there")
    out.append(f"{'variant':15s} {'held out':30s} {'ch':3s} {'shared':>6s} {'transfer':>9s} {'-offset':>8s} "
               f"{'own fit':>8s} {'transfer':>9s} {'own fit':>8s}  unseen phonemes (fitted on the held-out one)")
    out.append(f"{'':15s} {'':30s} {'':3s} {'phon.':>6s} {'shared segs':>27s} {'all samples':>18s}")
    runs: list[tuple[str, FitSpec | None]] = []
    for name in variants:
        if name in SHRUNK:
            # One training utterance has no repetitions or sentences to cross-validate over, so no
            # strength can be chosen here: every value of the grid is shown (not a choice).
            plain = variant_spec(base, SHRUNK[name])
            runs += [(f"{SHRUNK[name]}+shrink sd {sd:g}",
                      None if plain is None else plain.with_options(**shrink_options(plain, sd, None)))
                     for sd in SHRINK_GRID]
        else:
            runs.append((name, variant_spec(base, name)))
    for name, spec in runs:
        if spec is None:
            out.append(f"{name:15s} (skipped: this core/FitSpec lacks the variant's options)")
            continue
        for k, held in enumerate(utts):
            train = [u for j, u in enumerate(utts) if j != k]
            trained = run(spec, utterances=train, quiet=True, choose=cross_validate)
            own = run(spec, utterances=[held], quiet=True, choose=cross_validate)
            for ch in spec.channels:
                fit = trained.channels[ch]
                known = set(fit.phonemes)
                shared = sorted(known & set(held.labels))
                unseen = sorted(set(held.labels) - known)
                # Every parameter of a shared phoneme fixed at the training fit; the others fitted.
                row = {p: i for i, p in enumerate(fit.phonemes)}
                fixes = tuple(Override(phonemes=(p,), channels=(ch,),
                                       fixed={par: float(fit.params[row[p], j]) for j, par in enumerate(PARAMETERS)})
                              for p in shared)
                # Shrinkage pulls the unseen phonemes toward their class means, which include the
                # shared members at their trained values; a class with no unseen member has nothing free.
                tspec = spec.with_options(channels=(ch,), overrides=spec.parameters.overrides + fixes,
                                          shrinks=tuple(g for g in spec.priors.shrinks if set(g.phonemes) & set(unseen)))
                transfer = run(tspec, utterances=[held], quiet=True, choose=cross_validate).channels[ch]
                mine = own.channels[ch]
                data = transfer.problem.data
                # Samples inside segments of shared phonemes (the ones the training fit can speak for).
                keep = np.zeros_like(data.weights)
                t = held.times
                for lab, s, e in zip(held.labels, held.starts, held.ends):
                    if lab in shared and lab != "#":
                        keep[(t >= s) & (t < e)] = 1.0
                ft = transfer.problem.evaluate(transfer.params, transfer.beta)
                fo = mine.problem.evaluate(mine.params, mine.beta)
                ones = np.ones_like(keep)
                out.append(f"{name:15s} {held.name:30s} {ch:3s} {len(shared):6d} {_rmse(ft, data, keep):9.3f} "
                           f"{_rmse(ft, data, keep, offset=True):8.3f} {_rmse(fo, mine.problem.data, keep):8.3f} {_rmse(ft, data, ones):9.3f} "
                           f"{_rmse(fo, mine.problem.data, ones):8.3f}  {' '.join(unseen)}")
                print(out[-1], flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("manifest", type=Path, nargs="?", help="manifest.csv of a --flavour gestures session")
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help=f"comma-separated, among {', '.join([*VARIANTS, *SHRUNK])}")
    ap.add_argument("--channels", default="LLO,JO")
    ap.add_argument("--skip-gestures", action="store_true")
    ap.add_argument("--repetitions", metavar="R1,R2", help="gestures: keep only these repetitions (a data-poor "
                    "session; the shrinkage variants then cross-validate over utterances)")
    ap.add_argument("--skip-german", action="store_true")
    ap.add_argument("--select-h", metavar="GRID",
                    help="only choose the rate-aware variant's plateau_fraction among GRID (e.g. 0.3,0.4,0.5,0.6) "
                         "by CV within the normal rate, then score the fast rate (default --out: "
                         "bench/results/generalisation_select_h.txt)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    if a.select_h:
        if a.manifest is None:
            ap.error("--select-h needs the gestures session's manifest.csv")
        lines = ["# bench/generalisation.py --select-h: the plateau fraction chosen without looking at the fast rate"]
        select_plateau_fraction(a.manifest, [float(h) for h in a.select_h.split(",")], tuple(a.channels.split(",")),
                                lines)
        return _write(lines, a.out or ROOT / "bench" / "results" / "generalisation_select_h.txt")
    variants = a.variants.split(",")
    bad = sorted(set(variants) - set(VARIANTS) - set(SHRUNK))
    if bad:
        ap.error(f"--variants: unknown {bad} (choose from {', '.join(VARIANTS)})")
    if not a.skip_gestures and a.manifest is None:
        ap.error("give the gestures session's manifest.csv (or --skip-gestures)")
    lines = ["# bench/generalisation.py: RMSE (mm) of fitted tables on data the fit did not see"]
    if not a.skip_gestures:
        gestures(a.manifest, variants, tuple(a.channels.split(",")), lines,
                 a.repetitions.split(",") if a.repetitions else None)
    if not a.skip_german:
        german(variants, lines)
    return _write(lines, a.out or ROOT / "bench" / "results" / "generalisation.txt")


def _write(lines: list[str], out: Path) -> int:
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, "\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
