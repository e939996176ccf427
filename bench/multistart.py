"""Multi-start estimation (coartic.fit.multistart): its cost as a ratio to one start, the share of
starts that reach the best optimum, against nlopt's global MLSL and against the single start.

    .venv/bin/python bench/multistart.py [synthetic|german|workers|heldout|cost|cost-per-phoneme|cost-gestures|confirm-gestures|return-test ...]
                                                                      (default: the first four)

- synthetic: LLO of the synthetic session, the 150 trials of /p f t l s/ (fit/synthetic.toml;
  `coartic corpus synth build/session` first), as in fit/compare_engines.py;
- german: LA and JO of the two German EMA utterances (fit/ema_german.toml);
- workers: 8 starts one after the other (rayon inside each evaluation) against two at once in
  threads, on the synthetic LLO;
- heldout: start independence held out on the German EMA, as bench/real_data.py splits it (the
  time split; fit 0024, predict 0020): one start from θ = 15 and from θ = 100, the previous default
  and the default from θ = 15 (seed 0) and θ = 100 (seed 1); the table's held-out RMSE and the step
  model's on the same samples. heldout-one-start, heldout-previous-default, heldout-default: one
  kind of fit only (a CPU hour in all on the shared machine).

- cost: the cost of the default multi-start (with the stopping rule) and of the search before the
  rule, as ratios to one start of the same spec, with the share of the continued starts that
  reached the best, on the German EMA defaults spec (utterance 0024: the dynamics partially pooled,
  the empirical Bayes after the search included), and the previous default's (shared θ) one start
  beside it: the pooled fit's cost as a ratio to it (bench/results/multistart_cost.txt);
  cost-per-phoneme: the same with per-phoneme dynamics, nothing pooled
  (bench/results/multistart_cost-per-phoneme.txt); cost-gestures: the gestures flavour's LLO, with
  the rule only (bench/results/multistart_cost-gestures.txt); cost-gestures-rep1: the same on the
  normal rate's repetition 1 (63 trials), LLO and JO (bench/results/multistart_cost-gestures-rep1.txt).
  confirm-gestures: the stopping rule's confirming start on a part of the gestures flavour, drawn
  entry by entry (the default), per family, and the log entries only, and its return test: perturbed
  restarts from start 0's optimum, every entry moved by N(0, 0.5) (before HOP_BOX) and as
  multistart.hop moves them (bench/results/multistart_confirm-gestures.txt). return-test: where the
  return test's restarts end on the gestures flavour's LLO (repetition 1) and the German EMA's per-phoneme
  θ from θ = 100 and 15, against start 0's end (multistart.restart_verdict;
  bench/results/multistart_return-test.txt).
  Costs are evaluations (exact) and CPU seconds of this process (time.process_time: every thread,
  the core's rayon workers included; a short fit repeated, MIN_CPU): the machine is shared, and
  wall times there measure the other jobs.

"previous default" is the multi-start before the polish and the rounds (the best 4 of 32 probes
continued, nothing more): ``CHAINS = 0`` and one round, set here for that line only.

Every line is measured in the same run: ratios are to the single start of the same data.
Output saved in bench/results/multistart.txt (all parts) or multistart_<parts>.txt;
multistart_german.txt and multistart_heldout-default.txt the default with the polish and the
rounds (MULTISTART_NLOPT=0 for the former); multistart_synthetic_german.txt the default before them
(with nlopt), and multistart_quasirandom_only.txt before start 0 was [parameters.start] (with the
workers).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Iterator, Sequence

import coartic.fit.multistart as multistart
from coartic.fit import runner
from coartic.fit.data import load_utterances, manifest_rows
from coartic.model import Utterance
from coartic.fit.runner import fit_channel
from coartic.fit.spec import FitSpec, load_spec

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))


def line(label: str, fit: Any, wall: float, ref_wall: float | None) -> str:
    ms = fit.multistart
    ratio = f"{wall / ref_wall:5.2f}x" if ref_wall else "  1.00x"
    extra = ""
    if ms is not None:
        n = fit.problem.data.n_valid
        rm = ", ".join(f"{o.rmse:.4f}" for o in ms.optima[:4])
        extra = (f"; {len(ms.optima)} optima (RMSE {rm}{' ...' if len(ms.optima) > 4 else ''}), best reached from "
                 f"{ms.best.hits}/{len(ms.continued)} continued of {ms.n_starts}, {ms.hops} polishing restarts, "
                 f"{len(ms.best.unidentified)} parameters not identified in the best")
    return (f"  {label:<34} RMSE {fit.rmse:.4f} mm  {fit.nfev:6d} evals  {wall:7.1f} s  {ratio}  "
            f"[{fit.status}]{extra}")


def timed(spec: FitSpec, utts: Sequence[Utterance], ch: str) -> tuple[Any, float]:
    t0 = time.perf_counter()
    fit = fit_channel(spec, utts, ch)
    return fit, time.perf_counter() - t0


@contextlib.contextmanager
def previous_default() -> Iterator[None]:
    """The multi-start as it was before the polish and the rounds: the best `keep` probes
    continued, no polishing restarts, no further round."""
    chains, limit = multistart.CHAINS, multistart.max_continued
    multistart.CHAINS = 0
    setattr(multistart, "max_continued", lambda n, keep: keep)
    try:
        yield
    finally:
        multistart.CHAINS = chains
        setattr(multistart, "max_continued", limit)


def compare(title: str, spec: FitSpec, utts: Sequence[Utterance], channels: Sequence[str]) -> list[str]:
    out = [title]
    print(title, flush=True)
    for ch in channels:
        s1 = spec.with_options(starts=1)
        one, w1 = timed(s1, utts, ch)
        rows = [line(f"{ch} one start ([parameters.start])", one, w1, None)]
        for label, s in [
            ("32 starts, previous default", spec.with_options(starts=32, seed=0)),
            ("32 starts, seed 0 (default)", spec.with_options(starts=32, seed=0)),
            ("32 starts, seed 1", spec.with_options(starts=32, seed=1)),
            ("nlopt MLSL-LDS + L-BFGS, one start", s1.with_options(
                engine={"name": "nlopt", "options": {"global": "mlsl", "global_maxeval": 4000}})),
        ][: None if os.environ.get("MULTISTART_NLOPT", "1") == "1" else -1]:  # MULTISTART_NLOPT=0: without it
            with previous_default() if "previous" in label else contextlib.nullcontext():
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


# fit 0024, predict 0020 (the test's case on the whole spec); the time split too with
# MULTISTART_SPLITS="LOO 0020,time split" (each multi-start fit of both channels is CPU minutes)
HELDOUT_SPLITS = tuple(os.environ.get("MULTISTART_SPLITS", "LOO 0020").split(","))


def heldout(which: Sequence[str] = ("one start", "previous default", "default")) -> list[str]:
    """Start independence held out (module docstring): per split and channel, the held-out RMSE of
    each fit (those whose label starts with one of ``which``), the step model's, and the spread
    between the two fits of each kind."""
    import real_data  # bench/real_data.py: its splits, prediction (fallbacks, transfer) and masking

    from coartic.evaluation.score import score_utterances
    from coartic.io.labelmap import resolve_label_map
    from coartic.fit import run

    spec, utts = german_data()
    label_map = resolve_label_map(spec.corpus.label_map) if spec.corpus.label_map else None
    out = [f"start independence held out, German EMA (fit/ema_german.toml: {', '.join(spec.parameters.free)} free), "
           "RMSE mm: table, step model on the same samples, in-sample"]
    print(out[0], flush=True)

    def started(theta: float, **kw: Any) -> FitSpec:
        return spec.with_options(start={**spec.parameters.start, "theta_bw": theta, "theta_fw": theta}, **kw)

    fits = [("one start, θ 15", started(15.0, starts=1), False), ("one start, θ 100", started(100.0, starts=1), False),
            ("previous default, θ 15, seed 0", started(15.0, starts=32, seed=0), True),
            ("previous default, θ 100, seed 1", started(100.0, starts=32, seed=1), True),
            ("default, θ 15, seed 0", started(15.0, starts=32, seed=0), False),
            ("default, θ 100, seed 1", started(100.0, starts=32, seed=1), False)]
    fits = [f for f in fits if f[0].split(",")[0] in which]
    for name, train, test in real_data.splits(utts):
        if name not in HELDOUT_SPLITS:
            continue
        seen = {lab for u in train for lab in u.labels}
        held: dict[tuple[str, str], float] = {}
        for label, s, previous in fits:
            t0 = time.perf_counter()
            with previous_default() if previous else contextlib.nullcontext():
                trained = run(s, utterances=train, quiet=True)
            wall = time.perf_counter() - t0
            for ch in s.channels:
                fit = trained.channels[ch]
                table, mapped, _ = real_data.predict_channel(s, trained, ch, test, label_map)
                sc = score_utterances(table, [real_data.masked(m, o, seen) for m, o in zip(mapped, test)], (ch,),
                                      train=train)
                fig = {r["model"]: r for r in sc.baseline_rows()}
                held[label, ch] = float(fig["table"]["rmse_mm"])
                out.append(f"  {name:11s} {ch:3s} {label:32s} held-out {held[label, ch]:7.3f}  step "
                           f"{fig['step']['rmse_mm']:6.3f}  in-sample {fit.rmse:.4f}  {fit.nfev:6d} evals "
                           f"{wall:7.1f} s (both channels)  [{fit.status}]")
                print(out[-1], flush=True)
        for ch in spec.channels:
            for what in which:
                a, b = [v for (lab, c), v in held.items() if c == ch and lab.startswith(what + ",")]
                out.append(f"  {name:11s} {ch:3s} {what}: the two fits' held-out RMSE differ by {abs(a - b):.3f} mm")
                print(out[-1], flush=True)
    return out


@contextlib.contextmanager
def without_rule() -> Iterator[None]:
    """The multi-start before the stopping rule: every start probed, no confirmation first."""
    confirm = multistart.CONFIRM
    multistart.CONFIRM = 0
    try:
        yield
    finally:
        multistart.CONFIRM = confirm


def cost_line(label: str, fit: Any, cpu: float, one: Any, one_cpu: float) -> str:
    ms = fit.multistart
    extra = ""
    if ms is not None:
        extra = (f"; best reached from {ms.best.hits} of {len(ms.continued)} continued ({ms.share:.0%}), "
                 f"{ms.probed} probed, {len(ms.optima)} optima, {ms.returns} return-test restarts; stopped: {ms.stopped}")
    pool = getattr(fit, "pooling", None)
    if pool is not None:  # the empirical Bayes that follows the search: where it ended
        extra += (f"; pooling: log evidence {pool.log_evidence:.2f}, {pool.effective:.1f} effective parameters, "
                  f"{pool.rounds} re-solves{'' if pool.settled else ' (not settled)'}")
    return (f"  {label:<44} data RMSE {fit.rmse:.4f} mm  {fit.nfev:6d} evals = {fit.nfev / one.nfev:5.2f}x"
            f"  CPU {cpu:7.2f} s = {cpu / one_cpu:5.2f}x  [{fit.status}]{extra}")


# A fit shorter than this (CPU seconds) is repeated until the repeats add up to it, and its mean is
# taken: one German EMA fit of the shared default takes 0.1-0.2 s, where a single reading varied by 2x.
MIN_CPU = 5.0


def cpu_timed(spec: FitSpec, utts: Sequence[Utterance], ch: str) -> tuple[Any, float]:
    """The fit and the CPU seconds it took (this process, every thread: the core's rayon workers
    too; the mean of repeats for a short fit, MIN_CPU). CPU rather than wall time: the machine is
    shared, and a wall time measures the other jobs."""
    t0 = time.process_time()
    n = 0
    while True:
        fit = fit_channel(spec, utts, ch)
        n += 1
        spent = time.process_time() - t0
        if spent >= MIN_CPU:
            return fit, spent / n


def cost(title: str, spec: FitSpec, utts: Sequence[Utterance], channels: Sequence[str],
         before: bool = True, reference: tuple[str, FitSpec] | None = None) -> list[str]:
    """Issue 25 item 5: a multi-start's cost as a ratio to one start of the same spec (evaluations,
    and CPU seconds of this process), the share of the continued starts that reach the best, with the
    stopping rule (the default) and, with ``before``, without it (every start probed). With
    ``reference`` (label, spec), its one start first, and every line's CPU as a ratio to it too."""
    out = [title]
    print(title, flush=True)
    for ch in channels:
        rows = []
        ref_cpu = None
        if reference is not None:
            ref, ref_cpu = cpu_timed(reference[1].with_options(starts=1), utts, ch)
            rows.append(cost_line(f"{ch} {reference[0]}, one start", ref, ref_cpu, ref, ref_cpu))
            print(rows[-1], flush=True)
        one, c1 = cpu_timed(spec.with_options(starts=1), utts, ch)
        rows.append(cost_line(f"{ch} one start", one, c1, one, c1)
                    + (f"; CPU = {c1 / ref_cpu:.2f}x the {reference[0]}'s one start" if ref_cpu else ""))
        print(rows[-1], flush=True)
        kinds = [("32 starts, stopping rule (default)", False)] + ([("32 starts, before the rule", True)] if before else [])
        for label, old in kinds:
            with without_rule() if old else contextlib.nullcontext():
                fit, c = cpu_timed(spec.with_options(starts=32, seed=0), utts, ch)
            rows.append(cost_line(f"{ch} {label}", fit, c, one, c1)
                        + (f"; CPU = {c / ref_cpu:.2f}x the {reference[0]}'s one start" if ref_cpu else ""))
            print(rows[-1], flush=True)
        out += rows
    return out


def defaults_data(per_phoneme: bool = False) -> tuple[FitSpec, list[Utterance]]:
    """fit/ema_german_defaults_0024.toml (every default: per-phoneme dynamics partially pooled, the
    target prior's sd estimated), or the same with per-phoneme dynamics (target, α, θ_bw, θ_fw of
    every phoneme, nothing shared or pooled, the target prior at 0.3 mm: docs/REAL_DATA.md's
    "per-phoneme")."""
    spec = load_spec(ROOT / "fit/ema_german_defaults_0024.toml")
    if per_phoneme:
        spec = spec.with_options(free=("target", "alpha", "theta_bw", "theta_fw"), shared=(), pooled=(), target_prior=0.3)
    return spec, load_utterances(spec, manifest_rows(spec))


def shared_default(spec: FitSpec) -> FitSpec:
    """The previous default (before partial pooling): targets free, one θ_bw and θ_fw per channel
    shared by every phoneme, α = 1, the target prior at 0.3 mm (bench/real_data.py's "shared")."""
    return spec.with_options(free=("target", "theta_bw", "theta_fw"), shared=("theta_bw", "theta_fw"), pooled=(),
                             target_prior=0.3)


def gestures_data(rep1: bool = False) -> tuple[FitSpec, list[Utterance]]:
    """fit/gestures_rate_aware.toml (`coartic corpus synth build/gestures --flavour gestures` first);
    with ``rep1`` the normal rate's repetition 1 only (63 trials, as confirm-gestures)."""
    spec = load_spec(ROOT / "fit/gestures_rate_aware.toml")
    rows = manifest_rows(spec)
    if rep1:
        rows = [r for r in rows if r.get("rate") == "normal" and r.get("repetition") == "1"]
    return spec, load_utterances(spec, rows)


def family_starts(packing: Any, n: int, seed: int) -> Any:
    """``n`` starts drawn as a ``[parameters.start]`` is given: one value per parameter family (α,
    θ_bw, ..., δ), every phoneme at the same place in its box (engine coordinates), from a scrambled
    Sobol sequence over the families; targets stay at the packing's own values. The alternative to
    the multi-start's start 1 (sobol_starts: every entry on its own) measured by ``confirm``."""
    import warnings

    import numpy as np
    from scipy.stats import qmc

    from coartic.table import PARAMETERS

    x0 = packing.pack()
    lo, hi = packing.bounds()
    cols = multistart._columns(packing)
    drawn = (cols != PARAMETERS.index("target")) & np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
    out = np.tile(x0, (n, 1))
    families = sorted(set(cols[drawn].tolist()))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        u = qmc.Sobol(len(families), scramble=True, seed=seed).random(n)
    for k, f in enumerate(families):
        m = drawn & (cols == f)
        out[:, m] = lo[m] + u[:, [k]] * (hi[m] - lo[m])
    return out


def confirm_gestures() -> list[str]:
    """What the stopping rule's confirming start costs and where it ends on the gestures flavour
    (LLO, the normal rate's repetition 1: 63 trials, the spec's 207 free parameters): one staged fit
    (the spec's stages, full budget) from start 0 ([parameters.start]), from the multi-start's start 1
    (sobol_starts, seed 0) and from start 1 drawn per family (family_starts, seed 0); CPU and
    evaluations as ratios to start 0's, the objective, the data RMSE, and whether it is start 0's
    optimum (multistart.cluster)."""
    from coartic.estimation.problem import build_problem
    from coartic.fit.staged import channel_status, fit_staged

    spec = load_spec(ROOT / "fit/gestures_rate_aware.toml")
    rows = [r for r in manifest_rows(spec) if r.get("rate") == "normal" and r.get("repetition") == "1"]
    utts = load_utterances(spec, rows)
    prob = build_problem(spec.estimation_settings(), utts, "LLO")
    full = prob.packing
    out = [f"confirming start, gestures flavour LLO, normal rate repetition 1 ({len(utts)} trials, "
           f"{full.n_free} free; fit/gestures_rate_aware.toml): one staged fit from each start"]
    print(out[0], flush=True)
    import numpy as np

    from coartic.table import PARAMETERS

    drawn = multistart.sobol_starts(full, 32, 0)[1]
    logs_only = full.pack()
    logs_only[full.log_mask] = drawn[full.log_mask]  # c, k_R, δ, σ at [parameters.start]
    starts: list[tuple[str, Any]] = [
        ("start 0 ([parameters.start])", None), ("start 1, every entry drawn (the default)", drawn),
        ("start 1, drawn per family", family_starts(full, 32, 0)[1]),
        ("start 1, the log entries drawn (alpha, theta)", logs_only)]
    ends = []

    def fit_from(label: str, x: Any, staged: bool = True) -> None:
        p = prob.with_packing(full if x is None else full.with_free(full.free, full.beta_free, *full.unpack(x)))
        p.nfev = p.njev = 0
        t0 = time.process_time()
        f, r, st = fit_staged(p, spec.engine.name, spec.engine.options,
                              spec.staging.stages if spec.staging.enabled and staged else None)
        cpu = time.process_time() - t0
        xe = f.packing.pack()
        ends.append((label, xe, st[-1].sse_end, f.nfev, cpu, channel_status(r, st)[0], prob.data_rmse(xe)))

    for label, x in starts:
        fit_from(label, x)
    # the return test's restarts from start 0's optimum (a joint fit, full budget): every entry moved
    # by N(0, HOP_SCALE) as before HOP_BOX, and as multistart.hop moves them
    moved = multistart._columns(full) != PARAMETERS.index("target")
    for k in range(2):
        rng = np.random.default_rng([0, k])
        x = ends[0][1].copy()
        lo, hi = full.bounds()
        x[moved] = np.clip(x[moved] + rng.normal(0.0, multistart.HOP_SCALE, int(moved.sum())), lo[moved], hi[moved])
        fit_from(f"restart {k + 1} from start 0's optimum, N(0, 0.5) (before)", x, False)
        fit_from(f"restart {k + 1} from start 0's optimum, multistart.hop", multistart.hop(full, ends[0][1],
                                                                                       np.random.default_rng([0, k])), False)
    _, x0, s0, n0, c0, _, _ = ends[0]
    for label, x, s, n, c, status, rmse in ends:
        same = len(multistart.cluster([x0, x], [s0, s], [multistart.trajectory(prob, x0), multistart.trajectory(prob, x)],
                                      prob.data.n_valid, [0, 1], ["", ""], n_free=full.n_free)) == 1
        out.append(f"  {label:<56} objective {s:10.4f}  data RMSE {rmse:.4f} mm  {n:5d} evals = {n / n0:5.2f}x  "
                   f"CPU {c:7.2f} s = {c / c0:5.2f}x  [{status}]  " + ("start 0's optimum" if same else "another optimum"))
        print(out[-1], flush=True)
    return out


def return_test() -> list[str]:
    """Where the return test's restarts end (multistart.restart_verdict): start 0's staged fit, then
    the restarts of fit_multistart's return test (multistart.hop, the draws of default_rng([seed, 0,
    1]), a joint fit within start 0's evaluations), each with its Δχ² from start 0's end (by the
    residual variance), the distance of the fitted curves (RMS over the samples, as a share of the
    residual RMSE, and squared in units of s²), the highest objective on the straight segment between
    the two (Δχ² above the higher end), its status and verdict; on the gestures flavour (LLO, normal
    rate repetition 1) each end polished by a joint fit with ftol = xtol = gtol = 1e-12 (600
    evaluations), and start 0's; on the German EMA (JO of 0024, target and θ free, per phoneme, as
    tests/python/test_fit_multistart.py's start-independence test) from θ = 100 (seed 1) and 15 (seed 0)."""
    import numpy as np

    from coartic.estimation.problem import build_problem
    from coartic.fit.staged import fit_staged

    out: list[str] = []

    def say(line: str) -> None:
        out.append(line)
        print(line, flush=True)

    def study(label: str, prob: Any, engine: str, options: dict[str, Any], stages: Any, seed: int, n: int,
              polish: bool) -> None:
        full = prob.packing

        def fresh(x: Any) -> Any:
            p = prob.with_packing(full if x is None else full.with_free(full.free, full.beta_free, *full.unpack(x)))
            p.nfev = p.njev = 0
            return p

        tight = {"ftol": 1e-12, "xtol": 1e-12, "gtol": 1e-12, "max_nfev": 600}
        nv, m = prob.data.n_valid, full.n_free
        f0, r0, st0 = fit_staged(fresh(None), engine, options, stages)
        x0, s0 = f0.packing.pack(), st0[-1].sse_end
        s2 = s0 / (nv - m)
        say(f"{label}: {nv} samples, {m} free; start 0 objective {s0:.4f}, data RMSE {prob.data_rmse(x0):.4f} mm, "
            f"{f0.nfev} evals [{r0.status}]; s² = {s2:.4g}")
        if polish:
            fp, _, sp = fit_staged(fresh(x0), engine, tight, None)
            say(f"  start 0's end polished (tolerances 1e-12): objective {sp[-1].sse_end:.4f} ({fp.nfev} evals)")
        tr0 = multistart.trajectory(prob, x0)
        seg = prob.with_packing(full)
        seg.monitor = None
        rng = np.random.default_rng([seed, 0, 1])
        for k in range(n):
            f, r, st = fit_staged(fresh(multistart.hop(full, x0, rng)), engine, multistart._capped(engine, options, f0.nfev),
                                  None)
            xe, se = f.packing.pack(), st[-1].sse_end
            tre = multistart.trajectory(prob, xe)
            d2 = float(np.sum((tre - tr0) ** 2))
            top = max(float(seg.residuals(x0 + a * (xe - x0)) @ seg.residuals(x0 + a * (xe - x0)))
                      for a in np.linspace(0.1, 0.9, 9))
            verdict = multistart.restart_verdict(s0, se, tr0, tre, r.status, nv, m) or "not back"
            line = (f"  restart {k + 1}: objective {se:.4f}, Δχ² {(se - s0) / s2:+.3f}, curves {np.sqrt(d2 / nv) / np.sqrt(s0 / nv):.4f} "
                    f"of the RMSE ({d2 / s2:.2f} s²), segment's top {(top - max(s0, se)) / s2:+.2f} s² above the higher end, "
                    f"{f.nfev} evals [{r.status}]: {verdict}")
            if polish:
                fp, _, sp = fit_staged(fresh(xe), engine, tight, None)
                line += f"; polished (1e-12): {sp[-1].sse_end:.4f}, Δχ² {(sp[-1].sse_end - s0) / s2:+.3f}"
            say(line)

    spec, utts = gestures_data(rep1=True)
    study(f"gestures flavour LLO, normal rate repetition 1 ({len(utts)} trials; fit/gestures_rate_aware.toml), seed 0",
          build_problem(spec.estimation_settings(), utts, "LLO"), spec.engine.name, spec.engine.options,
          spec.staging.stages if spec.staging.enabled else None, 0, 3, True)
    sys.path.insert(0, str(ROOT / "tests" / "python"))
    import tempfile

    from coartic.fit.runner import start_values
    from test_fit_multistart import small_problem

    for theta, seed in ((100.0, 1), (15.0, 0)):
        gspec, gutts, _ = small_problem(Path(tempfile.mkdtemp()), theta, 32)
        settings = gspec.estimation_settings()
        prob = build_problem(settings, gutts, "JO")
        start = start_values(gspec, "JO", prob.phonemes)
        if start is not None:
            prob = build_problem(settings, gutts, "JO", start=start)
        study(f"German EMA JO, 0024, per-phoneme target and theta, from theta = {theta:g}, seed {seed}", prob,
              gspec.engine.name, gspec.engine.options, gspec.staging.stages if gspec.staging.enabled else None, seed, 2,
              False)
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
        elif part == "cost":
            spec, utts = defaults_data()
            lines += cost("cost, German EMA 0024 LA and JO, every default: dynamics pooled "
                          "(fit/ema_german_defaults_0024.toml); the shared default for the pooled fit's cost", spec,
                          utts, ["LA", "JO"], reference=("shared default", shared_default(spec)))
            save()
        elif part == "cost-per-phoneme":
            spec, utts = defaults_data(per_phoneme=True)
            lines += cost("cost, the same with per-phoneme dynamics (target, alpha, theta_bw, theta_fw free, nothing "
                          "shared or pooled)", spec, utts, ["LA", "JO"])
        elif part == "cost-gestures":  # the rule only: before it, the run takes CPU hours on the shared machine
            spec, utts = gestures_data()
            lines += cost(f"cost, gestures flavour, LLO, {len(utts)} trials (fit/gestures_rate_aware.toml)", spec, utts,
                          ["LLO"], before=False)
        elif part == "cost-gestures-rep1":  # the same on 63 trials: LLO and JO, minutes instead of an hour
            spec, utts = gestures_data(rep1=True)
            lines += cost(f"cost, gestures flavour, normal rate repetition 1, {len(utts)} trials "
                          "(fit/gestures_rate_aware.toml)", spec, utts, ["LLO", "JO"], before=False)
        elif part == "confirm-gestures":
            lines += confirm_gestures()
        elif part == "return-test":
            lines += return_test()
        elif part == "heldout":
            lines += heldout()
        elif part.startswith("heldout-"):  # one kind of fit only, e.g. heldout-default (the run is long)
            lines += heldout([part.removeprefix("heldout-").replace("-", " ")])
        else:
            raise SystemExit(f"unknown part {part!r} (synthetic, german, workers, heldout, cost, cost-per-phoneme, "
                             "cost-gestures, cost-gestures-rep1, confirm-gestures, return-test)")
        save()
    print(f"saved bench/results/{name}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["synthetic", "workers", "german", "heldout"])
