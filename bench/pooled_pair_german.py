"""Why the pooled default loses one German (split, channel) pair: LOO 0024, JO (fit 0020, predict 0024).

Issue 25's last per-pair failure on the German EMA (docs/REAL_DATA.md, "Issue 25's done-when against
these figures"): there the pooled default (``--freedom pooled --reg tprior-eb``) is the worst of
{shared, pooled, per-phoneme} and above the step model as measured. This script takes the default
apart on that pair only, with bench/real_data.py's own cells, fits and scoring (same samples, same
fallbacks), and prints every figure docs/REAL_DATA.md quotes ("LOO 0024 JO: what costs"):

1. the cells, reproduced;
2. where the differences are: each model's squared error minus the pooled default's, per scored
   segment of the test utterance; the final /n/ (a label that runs 1.31 s to the end of the file,
   mostly rest) against the other segments, with an SE that takes each segment as a unit;
3. that final /n/: measured and predicted means along it, and each utterance's level there;
4. every part of the default switched on or off (refits): the target prior (fixed 0.3 mm / estimated),
   each pooled family alone or in pairs, the evidence's data weight w scaled, the default 32 starts,
   the per-phoneme optimum as the start;
5. single parameters swapped between fitted tables (no refit): /e/'s θ_fw, /n/'s target;
6. is /e/'s θ_fw determined by the training utterance? The per-phoneme fit refitted with it fixed.

Not part of `make test` (about 3 CPU-minutes). Output: bench/results/pooled_pair_german.txt

    nice -n 10 .venv/bin/python bench/pooled_pair_german.py --out bench/results/pooled_pair_german.txt
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path
from typing import Any, Callable
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_data as rd  # noqa: E402

from coartic.estimation.pooling import residual_weight  # noqa: E402
from coartic.evaluation.score import score_utterances, with_fallbacks  # noqa: E402
from coartic.fit import run  # noqa: E402
from coartic.fit.data import load_utterances  # noqa: E402
from coartic.fit.result import FitResult  # noqa: E402
from coartic.fit.spec import FitSpec, Override  # noqa: E402
from coartic.io.labelmap import resolve_label_map  # noqa: E402
from coartic.outputs import atomic_write_text  # noqa: E402
from coartic.pauses import is_pause  # noqa: E402

CHANNEL = "JO"
SPLIT = "LOO 0024"
CELLS = {"pooled": ("pooled", "tprior-eb"), "per-phoneme": ("tat", "tprior:0.3"), "shared": ("t+shared", "tprior:0.3")}

Edit = Callable[[FitSpec], FitSpec]


class Pair:
    """The split's training and test utterances, and fitting / scoring on them."""

    def __init__(self) -> None:
        self.base = rd.corpus_spec(rd.CORPORA[0]).with_options(channels=(CHANNEL,))
        assert self.base.corpus is not None and self.base.corpus.label_map
        self.label_map = resolve_label_map(self.base.corpus.label_map)
        self.train, self.test = {n: (tr, te) for n, tr, te in rd.splits(load_utterances(self.base), ("loo",))}[SPLIT]
        self.lines: list[str] = []

    def say(self, line: str = "") -> None:
        print(line, flush=True)
        self.lines.append(line)

    def spec(self, cell: str, starts: int | None = 1, edit: Edit | None = None) -> FitSpec:
        freedom, reg = CELLS[cell]
        spec = rd.cell_spec(self.base, "rate-aware", freedom, reg, starts).with_options(channels=(CHANNEL,))
        return edit(spec) if edit else spec

    def fit(self, cell: str, label: str, starts: int | None = 1, edit: Edit | None = None) -> tuple[FitResult, dict[str, Any]]:
        spec = self.spec(cell, starts, edit)
        c0 = time.process_time()
        trained = run(spec, utterances=list(self.train), quiet=True)
        got = rd.fit_and_score(spec, self.train, self.test, CHANNEL, self.label_map, "constant", trained=trained)
        self.say(f"{label:46s} {got['table']:6.3f} {got['table_off']:6.3f} {got['table_all']:6.3f} {got['table_nolast']:6.3f} "
                 f"{got['in_sample']:6.3f}  {got['status']}, {time.process_time() - c0:.0f} CPU-s")
        p = got["pooling"]
        if p:
            fams = "; ".join(f"{f} {v['sd']:.3g} ({v['effective_parameters']:.1f}/{v['rank']})" for f, v in p["families"].items())
            self.say(f"{'':6s}w {p['data_weight']:.4f}, σ {p['sigma_mm']:.3f}, {p['rounds']} rounds"
                     f"{'' if p['settled'] else ' (not settled)'}, log evidence {p['log_evidence']:.2f}: {fams}")
        return trained, got

    def rescore(self, cell: str, trained: FitResult, edits: dict[tuple[str, str], float], label: str) -> None:
        """``trained``'s table with some values replaced, scored as the cell is (no refit)."""
        table = copy.deepcopy(trained.table())
        for (phoneme, par), v in edits.items():
            table.values[phoneme][CHANNEL][par] = v
        with mock.patch.object(trained, "table", lambda: table):
            got = rd.fit_and_score(self.spec(cell), self.train, self.test, CHANNEL, self.label_map, "constant", trained=trained)
        sc = in_sample(self, table)
        self.say(f"{label:46s} {got['table']:6.3f} {got['table_off']:6.3f} {got['table_all']:6.3f} {got['table_nolast']:6.3f} {sc:6.3f}")

    def final(self, u: Any) -> Any:
        """The valid samples of ``u``'s last non-pause segment."""
        last = max(i for i, lab in enumerate(u.labels) if not is_pause(lab))
        return (u.sample_segments() == last) & u.valid[CHANNEL], u.labels[last]


def in_sample(pair: Pair, table: Any) -> float:
    """The RMSE of ``table`` on the training utterance (all its valid samples): the fit's own figure."""
    mapped, _ = with_fallbacks(pair.train, table, (CHANNEL,), pair.label_map)
    sc = score_utterances(table, mapped, (CHANNEL,), train=pair.train)
    r = np.concatenate([sc.residuals(CHANNEL, k) for k in range(len(mapped))])
    return float(np.sqrt(np.nanmean(r ** 2)))


HEAD = f"{'':46s} {'held':>6s} {'-off':>6s} {'all':>6s} {'nolast':>6s} {'in-smp':>6s}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=rd.ROOT / "bench" / "results" / "pooled_pair_german.txt")
    a = ap.parse_args()
    c0 = time.process_time()
    pair = Pair()
    say = pair.say
    say("# bench/pooled_pair_german.py: the pooled default on German LOO 0024 JO (fit 0020, predict 0024), taken apart")
    say(f"# command: nice -n 10 .venv/bin/python bench/pooled_pair_german.py {' '.join(sys.argv[1:])}".rstrip())
    say("# RMSE (mm) held out (speech as measured), offset removed, all samples, without the final segment (nolast), in-sample")

    say("\n## 1. the cells (one start), as in bench/results/real_data_pooling_german.txt")
    say(HEAD)
    fits = {c: pair.fit(c, f"{c} ({' '.join(CELLS[c])})") for c in CELLS}
    step = fits["pooled"][1]
    say(f"{'step model':46s} {step['step']:6.3f} {step['step_off']:6.3f} {step['step_all']:6.3f} {step['step_nolast']:6.3f}")

    say("\n## 2. where the differences are: SSE (mm^2) of each against the pooled default, per scored segment of 0024")
    segs = {c: g["segments"] for c, (_, g) in fits.items()}
    for other in ("per-phoneme", "shared", "step"):
        if other == "step":
            d = np.array([x[3] * (x[4] ** 2 - x[5] ** 2) for x in segs["pooled"]])
        else:
            d = np.array([x[3] * x[4] ** 2 - y[3] * y[4] ** 2 for x, y in zip(segs["pooled"], segs[other])])
        rest = d[:-1]
        say(f"pooled - {other:11s}: {d.sum():+7.1f} in all; final /{segs['pooled'][-1][2]}/ ({segs['pooled'][-1][3]} of "
            f"{step['samples']} samples) {d[-1]:+7.1f}; the other {rest.size} segments {rest.sum():+7.1f} ± "
            f"{np.sqrt(rest.size) * rest.std(ddof=1):.1f} (each segment a unit)")

    say("\n## 3. the final segment: each utterance's level there, and what the fits predict along 0024's")
    for name, u in (("0020 (training)", pair.train[0]), ("0024 (test)", pair.test[0])):
        m, lab = pair.final(u)
        y = u.observed[CHANNEL][m]
        seg = u.sample_segments()
        speech = u.valid[CHANNEL] & ~m & np.array([not is_pause(x) for x in u.labels] + [False])[seg]
        say(f"{name}: final /{lab}/ {m.sum()} samples, mean {y.mean():.2f} mm (first 60 {y[:60].mean():.2f}, after {y[60:].mean():.2f}); "
            f"the rest of its speech {u.observed[CHANNEL][speech].mean():.2f}")
    ranges = ((0, 10), (10, 30), (30, 60), (60, 120), (120, 240))
    say("samples of 0024's final /n/: " + "  ".join(f"{lo:>5d}-{hi:<5d}" for lo, hi in ranges))
    u = pair.test[0]
    m, _ = pair.final(u)
    say(f"{'measured':28s} " + "  ".join(f"{u.observed[CHANNEL][m][lo:hi].mean():11.2f}" for lo, hi in ranges))
    for c, (trained, _) in fits.items():
        table, mapped, _ = rd.predict_channel(pair.spec(c), trained, CHANNEL, pair.test, pair.label_map, "constant", pair.train)
        sc = score_utterances(table, mapped, (CHANNEL,), train=pair.train)
        f = sc.predicted[CHANNEL][0][m]
        say(f"{c:28s} " + "  ".join(f"{f[lo:hi].mean():11.2f}" for lo, hi in ranges))
        if c == "pooled":
            st = sc.baselines["step"][CHANNEL][0][m]
            say(f"{'step model':28s} " + "  ".join(f"{st[lo:hi].mean():11.2f}" for lo, hi in ranges))
    t = {c: tr.table().values for c, (tr, _) in fits.items()}
    say("fitted (target, α, θ_bw, θ_fw) of /e/ (the segment before the final /n/) and /n/:")
    for c in CELLS:
        say(f"  {c:12s} " + "  ".join(f"/{p}/ " + ", ".join(f"{t[c][p][CHANNEL][q]:.3g}" for q in ("target", "alpha", "theta_bw", "theta_fw"))
                                      for p in ("e", "n")))

    say("\n## 4. each part of the default on or off (refits, one start unless said)")
    say(HEAD)
    pair.fit("pooled", "pooled, target sd fixed 0.3", edit=lambda s: s.with_options(target_prior=0.3))
    pair.fit("pooled", "pooled, no target prior", edit=lambda s: s.with_options(target_prior=None))
    pair.fit("per-phoneme", "per-phoneme, target sd estimated", edit=lambda s: s.with_options(target_prior="estimated"))
    for fams in (("alpha",), ("theta_bw",), ("theta_fw",), ("alpha", "theta_bw"), ("alpha", "theta_fw"), ("theta_bw", "theta_fw")):
        def only(s: FitSpec, f: tuple[str, ...] = fams) -> FitSpec:
            return s.with_options(pooled=f)
        pair.fit("pooled", f"pooled {' + '.join(fams)} only", edit=only)
    for k in (0.25, 0.5, 2.0, 4.0, 18.0):
        # the evidence's data weight w = n_eff / n scaled by k (at most 1): the default's is 0.055
        def scaled(*args: Any, k: float = k) -> tuple[float, float]:
            w, t_int = residual_weight(*args)
            return min(1.0, k * w), t_int
        with mock.patch("coartic.fit.staged.residual_weight", scaled):
            pair.fit("pooled", f"pooled, w x {k:g}")
    pair.fit("pooled", "pooled, the default 32 starts", starts=None)
    start = Path(a.out).with_suffix(".per_phoneme_table.json")
    fits["per-phoneme"][0].table().save(start)
    pair.fit("pooled", "pooled, started from the per-phoneme table", edit=lambda s: s.with_options(start_table=str(start)))
    start.unlink()

    say("\n## 5. single values swapped between the fitted tables (no refit)")
    say(HEAD)
    pooled, perph, shared = (fits[c][0] for c in CELLS)
    pair.rescore("pooled", pooled, {}, "pooled as fitted")
    pair.rescore("pooled", pooled, {("e", "theta_fw"): t["per-phoneme"]["e"][CHANNEL]["theta_fw"]}, "pooled, /e/ θ_fw of per-phoneme")
    for th in (1.0, 2.0, 5.0, 10.0):
        pair.rescore("pooled", pooled, {("e", "theta_fw"): th}, f"pooled, /e/ θ_fw {th:g}")
    pair.rescore("per-phoneme", perph, {}, "per-phoneme as fitted")
    pair.rescore("per-phoneme", perph, {("e", "theta_fw"): t["pooled"]["e"][CHANNEL]["theta_fw"]}, "per-phoneme, /e/ θ_fw of pooled")
    pair.rescore("pooled", pooled, {("n", "target"): t["shared"]["n"][CHANNEL]["target"]}, "pooled, /n/ target of shared")
    pair.rescore("shared", shared, {("n", "target"): t["pooled"]["n"][CHANNEL]["target"]}, "shared, /n/ target of pooled")

    say("\n## 6. does 0020 determine /e/'s θ_fw? per-phoneme refitted with it fixed")
    say(HEAD)
    for th in (1.0, 5.0, 24.0, 100.0):
        fix = Override(phonemes=("e",), channels=(CHANNEL,), fixed={"theta_fw": th})
        def fixed(s: FitSpec, o: Override = fix) -> FitSpec:
            return s.with_options(overrides=s.parameters.overrides + (o,))
        pair.fit("per-phoneme", f"per-phoneme, /e/ θ_fw fixed {th:g}", edit=fixed)
    say(f"\n({time.process_time() - c0:.0f} CPU-s)")
    atomic_write_text(a.out, "\n".join(pair.lines) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
