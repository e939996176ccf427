"""Which model to recommend for real recordings? Held-out error on every real recording we have
(issue 19 item 3; the evidence in docs/REAL_DATA.md).

The corpora (``--corpus``): ``german``, the EMU demo database's two German utterances (speaker
mo1, fit/ema_german.toml); ``s1em``, EMU-webApp's test database tinyDfg91 (another speaker and
sentence, one utterance; fit/ema_s1em.toml, a spec that sets nothing but the recordings) and
``speakers``, both together (fit/ema_speakers.toml: its manifest's ``speaker`` column, which the
product reads as ``[validate] group = "speaker"`` does, says whose each utterance is), two
recording sets the project never fitted or tuned on before these figures; ``synthetic`` and
``gestures``, the synthetic sessions. The base spec's settings that a cell does not set stay the
corpus's: fit/ema_german.toml's one pause label and θ start 40, the defaults (pause postures, θ
start 30) for the specs that set nothing but the recordings.

Each *cell* is a fit spec: a model variant (original, modified, rate-aware = plateau dominance +
handover, docs/VARIANTS.md), a *freedom* (which per-phoneme parameters are free; "t+shared": one
theta_bw and theta_fw per channel for every phoneme, ``[parameters] shared``) and a
*regularisation* (none; ``[[shrink]]`` of the free dynamics toward their phonetic class's mean, the
classes and scales of bench/generalisation.py; "tprior:SD", ``[parameters] target_prior = SD``;
"tprior-cv", that sd chosen by CV inside the training data). Every cell is fitted with the product's own
``coartic.fit.run`` (its global estimation included: the spec's default ``[fit] starts``) and
scored with ``coartic.evaluation.score`` next to the baselines of ``coartic.evaluation.baselines`` (constant =
training mean, step = each phoneme's training mean) on exactly the same samples:

- **leave one utterance out**: fit one utterance, predict the other. The two German utterances
  share only some phonemes, so the score is taken on the samples inside segments of phonemes the
  training utterance has (pauses excluded; as bench/generalisation.py). To *predict* the held-out
  utterance the model still needs every segment: a phoneme the training lacks takes its phonetic
  class's fallback (the label map's, as ``coartic score`` does); one with none the training has
  (0024's /u v/ from 0020) gets the step model's own fallback, the training mean (``--unseen
  constant``, the default), or is fitted on the held-out utterance with every trained phoneme fixed
  (``--unseen transfer``, bench/generalisation.py) -- its own segments are not scored;
- **split in time**: every utterance cut at its middle segment (bench/baselines_german.py's
  ``halves``); fit the first halves together, predict the second halves, scored likewise on the
  segments whose phonemes the first halves have;
- **another speaker** ("speaker", the ``speakers`` corpus): fit the utterances of the corpus's first
  speaker (mo1's two), predict each other speaker's (s1em's 0666), scored and with unseen phonemes
  as in leave one out. The sensors sit elsewhere on another face (and the recordings' origins
  differ: JO is about 23 mm on mo1, 87 mm on s1em), so the figure as measured mostly measures that
  origin; the one that matters here is the offset-removed one (as ``coartic score`` compares a
  speaker the training lacks: ``coartic.evaluation.baselines.other_session``).

In-sample RMSE is the training RMSE of the same fits. The raw RMSE is as measured; "-offset" removes
each test utterance's mean residual (a recording's rest reference is estimated once per utterance);
"nolast" is every figure again without each test utterance's last segment, and ``--losses`` prints
where each table loses to the step model, segment by segment (as measured: across speakers mostly
the offset).

Not part of `make test` (CPU minutes); its core, ``evaluate_cell``, is tested on a tiny case in
tests/python/test_bench_real_data.py. Output in bench/results/real_data.txt (the parts of the grid
that were run, and their commands: docs/REAL_DATA.md; the shared / pooled / per-phoneme cells per
corpus, merged with ``--merge``: bench/results/real_data_pooling_<corpus>.txt):

    nice -n 10 .venv/bin/python bench/real_data.py --variants rate-aware --freedom t+shared --reg tprior:0.3 --starts 1
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from baselines_german import halves  # noqa: E402
from generalisation import VARIANTS, shrink_options  # noqa: E402

from coartic.fit import load_spec, run  # noqa: E402
from coartic.evaluation.baselines import Baselines  # noqa: E402
from coartic.fit.data import load_utterances  # noqa: E402
from coartic.model import Utterance  # noqa: E402
from coartic.fit.result import FitResult  # noqa: E402
from coartic.evaluation.compare import heldout_se  # noqa: E402
from coartic.evaluation.score import score_utterances, with_fallbacks  # noqa: E402
from coartic.fit.spec import FitSpec, Override, parse_spec  # noqa: E402
from coartic.io.labelmap import resolve_label_map  # noqa: E402
from coartic.outputs import atomic_write_text  # noqa: E402
from coartic.pauses import is_pause  # noqa: E402
from coartic.table import PARAMETERS  # noqa: E402

# Which per-phoneme parameters are free (the others stay at their start values: c = 1, k_r = 0.5,
# sigma = 0, psi = 500, delta = 0).
TAT = ("target", "alpha", "theta_bw", "theta_fw")
FREEDOM: dict[str, tuple[str, ...]] = {
    "tat": TAT, "tat+k_r": (*TAT, "k_r"), "tat+k_r+c": (*TAT, "k_r", "c_bw", "c_fw"), "all": PARAMETERS,
    # targets per phoneme, one theta_bw and one theta_fw shared by every phoneme ([parameters] shared; alpha = 1)
    "t+shared": ("target", "theta_bw", "theta_fw"),
    # targets only (alpha = 1, theta at its start): the fewest parameters a coarticulation model has
    "t": ("target",),
    # per-phoneme target, alpha, theta_bw, theta_fw, the dynamics drawn toward one value per channel
    # with an sd estimated from the training data ([parameters] pooled, coartic.estimation.pooling)
    "pooled": TAT,
}
SHARED = {"t+shared": ("theta_bw", "theta_fw")}
POOLED = {"pooled": ("alpha", "theta_bw", "theta_fw")}
# "none"; "shrink" (the dynamics toward class means); "tprior:SD": every target toward the training
# data's own mean of its phoneme (the step model's value) with sd SD mm; "tprior-cv": that sd chosen
# by cross-validation inside the training data (TPRIOR_GRID; folds: the training utterances' halves in time);
# "tprior-eb": that sd estimated from the training data (target_prior = "estimated", empirical Bayes)
REGULARISATION = ("none", "shrink", "tprior-cv", "tprior-eb")
TPRIOR_GRID = (0.03, 0.1, 0.3, 1.0, 3.0)
# sd of every [[shrink]] (log units for alpha and theta, natural for c and k_r). Not chosen by
# [choose]: each training set here has one utterance (leave one out) or two halves, too few groups
# to cross-validate over (coartic.fit.guards says so); 0.3 is the middle of generalisation.py's grid.
SHRINK_SD = 0.3
VARIANT_NAMES = ("original", "modified", "rate-aware")


@dataclasses.dataclass(frozen=True)
class Corpus:
    """A real recording set: its fit spec (files, labels, label map, role map) and where it comes from."""

    name: str
    spec: Path
    source: str
    licence: str
    key: str = "german"
    # a spec that sets nothing but its corpus (the synthetic sessions): the spec file is not read
    manifest: Path | None = None
    channels: str = "LA,JO"
    splits: str = "loo,time"


CORPORA = (
    Corpus("German EMA, EMU demo (speaker mo1, 2 utterances)", ROOT / "fit" / "ema_german.toml",
           "tests/data/realdata/emu-ema-german: the EMU-webApp demo database ema (IPS Munich, DFG SPP prosody, speaker mo1)",
           "MIT (distributed in github.com/IPS-LMU/EMU-webApp; README.txt there)"),
    # a speaker and sentence the project never fitted or tuned on (EMU-webApp's test database), with a
    # spec that sets nothing but the recordings: one utterance, so held out in time only
    Corpus("German EMA, EMU-webApp tinyDfg91 (speaker s1em, 1 utterance)", ROOT / "fit" / "ema_s1em.toml",
           "tests/data/realdata/emu-tinydfg91: EMU-webApp's test database tinyDfg91 (speaker s1em, utterance 0666)",
           "MIT (distributed in github.com/IPS-LMU/EMU-webApp; README.txt there)", "s1em", splits="time"),
    # both German speakers in one spec that sets nothing but the recordings (a manifest with a speaker
    # column): fit mo1, predict s1em
    Corpus("German EMA, two speakers (mo1's 2 utterances, s1em's 1)", ROOT / "fit" / "ema_speakers.toml",
           "tests/data/realdata/emu-ema-german (mo1) and tests/data/realdata/emu-tinydfg91 (s1em), fit/ema_speakers.csv",
           "MIT (distributed in github.com/IPS-LMU/EMU-webApp; README.txt in each)", "speakers", splits="speaker"),
    # the synthetic sessions (coartic corpus synth build/session; ... build/gestures --flavour gestures),
    # with a spec that sets nothing but the corpus: held out by rate, and data-starved
    Corpus("synthetic session (model flavour)", ROOT / "bench" / "synthetic_session.toml", "coartic corpus synth build/session",
           "ours", "synthetic", ROOT / "build" / "session" / "manifest.csv", "LLO,JO", "rate,starved1,starved2"),
    Corpus("synthetic session (gestures flavour)", ROOT / "bench" / "gestures_session.toml",
           "coartic corpus synth build/gestures --flavour gestures", "ours", "gestures",
           ROOT / "build" / "gestures" / "manifest.csv", "LLO,JO", "rate"),
)


def corpus_spec(corpus: Corpus) -> FitSpec:
    """The corpus's base spec: its spec file, or (a manifest) a spec that sets nothing else."""
    if corpus.manifest is None:
        return load_spec(corpus.spec)
    return parse_spec({"corpus": {"manifest": str(corpus.manifest)}}, corpus.spec)


def cell_spec(base: FitSpec, variant: str, freedom: Sequence[str] | str, reg: str, starts: int | None = None) -> FitSpec:
    """``base`` with the variant's model options, these free parameters (some shared by every
    phoneme: SHARED) and this regularisation; the product's own spec fields, so what is measured is
    what a spec with these settings fits. A "tprior:SD" sets [parameters] target_prior = SD; for
    "tprior-cv" ``evaluate_cell`` chooses SD per channel."""
    model = {"dominance": "centre", "handover": False, **VARIANTS[variant]}
    name = freedom_name(freedom)
    spec = base.with_options(**model, free=tuple(FREEDOM[name] if name in FREEDOM else freedom),
                             shared=SHARED.get(name, ()), pooled=POOLED.get(name, ()), target_prior=None)
    if starts is not None:
        spec = spec.with_options(starts=starts)
    sd = tprior_sd(reg)
    if reg == "shrink":
        spec = spec.with_options(**shrink_options(spec, SHRINK_SD, None))
    elif isinstance(sd, float) or sd == "estimated":
        spec = spec.with_options(target_prior=sd)
    elif reg != "none" and sd is None:
        raise ValueError(f"unknown regularisation {reg!r} (known: {', '.join(REGULARISATION)}, tprior:SD)")
    return spec


def tprior_sd(reg: str) -> float | str | None:
    """The sd (mm) of a "tprior:SD" regularisation, "cv" for "tprior-cv", None for any other."""
    if reg == "tprior-cv":
        return "cv"
    if reg == "tprior-eb":
        return "estimated"
    if reg.startswith("tprior:"):
        try:
            sd = float(reg.split(":", 1)[1])
        except ValueError:
            return None
        return sd if sd > 0 and math.isfinite(sd) else None
    return None


def choose_tprior_sd(spec: FitSpec, train: Sequence[Utterance], channel: str, label_map: Any,
                     unseen: str, grid: Sequence[float] = TPRIOR_GRID) -> tuple[float, list[tuple[float, float]]]:
    """The target prior's sd by cross-validation inside ``train``: two folds, every training
    utterance's first half in time -> its second half and the reverse; the sd of the lowest pooled
    held-out RMSE (ties: the smaller sd, the stronger prior). Returns (sd, [(sd, cv RMSE)])."""
    first, second = zip(*(halves(u) for u in train))
    curve = []
    for sd in grid:
        sse, n = 0.0, 0
        for a, b in ((list(first), list(second)), (list(second), list(first))):
            got = fit_and_score(spec.with_options(target_prior=sd), a, b, channel, label_map, unseen)
            sse += got["table"] ** 2 * got["samples"]
            n += got["samples"]
        curve.append((sd, math.sqrt(sse / n) if n else math.inf))
    best = min(curve, key=lambda c: (round(c[1], 9), c[0]))
    return best[0], curve


def fit_and_score(spec: FitSpec, train: Sequence[Utterance], test: Sequence[Utterance], channel: str,
                  label_map: Any, unseen: str, trained: FitResult | None = None) -> dict[str, Any]:
    """Fit ``spec`` (one channel) on ``train`` (or take its fit ``trained``), predict ``test``; the
    table's and baselines' RMSE on the samples of the phonemes ``train`` has (raw and offset
    removed), and how it went."""
    if trained is None:
        trained = run(spec, utterances=list(train), quiet=True)
    seen = {lab for u in train for lab in u.labels}
    fit = trained.channels[channel]
    table, mapped, notes = predict_channel(spec, trained, channel, test, label_map, unseen, train)
    scored = [masked(m, o, seen) for m, o in zip(mapped, test)]
    scored_all = [masked(m, o, seen | {"#"}, pauses=True) for m, o in zip(mapped, test)]
    out: dict[str, Any] = {"in_sample": fit.rmse, "status": fit.status, "notes": notes,
                           "pooling": None if fit.pooling is None else fit.pooling.as_dict()}
    # every figure twice: on all scored samples, and without each test utterance's last segment
    # (on the German EMA a final /n/ that runs 1.3-1.8 s to the end of the file: mostly rest)
    # and on every sample of those phonemes' segments, pauses included ("_all"; the rest: speech only)
    for suffix, test_set in (("", scored), ("_nolast", [drop_last(u) for u in scored]), ("_all", scored_all)):
        sc = score_utterances(table, test_set, (channel,), train=train)
        fig = {r["model"]: r for r in sc.baseline_rows()}
        out[f"samples{suffix}"] = int(fig["table"]["samples"])
        out.update({f"{m}{off}{suffix}": float(fig[m][key]) for m in ("table", "constant", "step")
                    for off, key in (("", "rmse_mm"), ("_off", "rmse_offset_removed_mm"))})
        if not suffix:
            out["segments"] = segment_losses(sc, channel, test)
    return out


def segment_losses(sc: Any, channel: str, test: Sequence[Utterance]) -> list[list[Any]]:
    """Per scored test segment: [utterance, segment index, phoneme, samples, table RMSE, step RMSE,
    table SSE - step SSE (mm^2)]: where the table loses to (> 0) or beats the step model."""
    out = []
    for k, u in enumerate(test):
        rt = sc.residuals(channel, k)
        rs = sc.residuals(channel, k, predicted=sc.baselines["step"][channel])
        seg = u.sample_segments()
        for i, lab in enumerate(u.labels):
            m = (seg == i) & np.isfinite(rt)
            if m.any():
                out.append([short_name(u.name), i, lab, int(m.sum()),
                            float(np.sqrt(np.mean(rt[m] ** 2))), float(np.sqrt(np.mean(rs[m] ** 2))),
                            float(np.sum(rt[m] ** 2) - np.sum(rs[m] ** 2))])
    return out


def loss_lines(rows: Sequence[dict[str, Any]], worst: int = 3) -> list[str]:
    """Where each cell loses to the step model: its share of the scored samples and of the table's
    excess squared error in each test utterance's last segment, and the ``worst`` segments."""
    out = [f"{'variant':11s} {'freedom':9s} {'reg':10s} {'split':11s} {'ch':3s} {'dSSE':>8s} {'last seg':>9s} "
           f"{'of n':>6s}  worst segments (utterance #index /phoneme/ samples: table vs step RMSE, dSSE)"]
    for r in rows:
        segs = r.get("segments")
        if not segs:
            continue
        total = sum(x[6] for x in segs)
        last = {}
        for x in segs:
            last[x[0]] = x if x[1] >= last.get(x[0], x)[1] else last[x[0]]
        d_last = sum(x[6] for x in last.values())
        n_last = sum(x[3] for x in last.values())
        top = sorted(segs, key=lambda x: -x[6])[:worst]
        out.append(f"{r['variant']:11s} {r['freedom']:9s} {r['reg']:10s} {r['split']:11s} {r['channel']:3s} "
                   f"{total:8.0f} {d_last:9.0f} {n_last / r['samples']:6.0%}  "
                   + "; ".join(f"{x[0]} #{x[1]} /{x[2]}/ {x[3]}: {x[4]:.2f} vs {x[5]:.2f}, {x[6]:+.0f}" for x in top))
    return out


def short_name(name: str) -> str:
    """An utterance's name in the tables: the German EMA's and tinyDfg91's file names without what
    every file of their corpus repeats (dfgspp_mo1_prosody_0020_ema -> 0020, dfg91_s1em_0666_annot -> 0666)."""
    for common in ("dfgspp_mo1_prosody_", "_ema", "dfg91_s1em_", "_annot"):
        name = name.replace(common, "")
    return name


def drop_last(u: Utterance) -> Utterance:
    """``u`` with the samples of its last non-pause segment not scored."""
    last = max(i for i, lab in enumerate(u.labels) if not is_pause(lab))
    keep = u.sample_segments() != last
    return Utterance(u.labels, u.starts, u.ends, u.times, u.name, u.observed,
                     {c: v & keep for c, v in u.valid.items()}, u.meta)


def splits(utts: Sequence[Utterance], which: Sequence[str] = ("loo", "time")) -> list[tuple[str, list[Utterance], list[Utterance]]]:
    """(name, train, test) of each held-out split: leave one utterance out, and split in time; for a
    session with rates ("rate"): fit the normal rate, predict the fast one, and data-starved
    ("starvedK"): fit only repetitions 1..K of the normal rate (K utterances per vowel-consonant
    pair), predict the fast rate; "ratefast" the other way round (fit the fast rate, predict the
    normal one); across speakers ("speaker"; every utterance's meta ``speaker``,
    a manifest column): fit the first speaker's utterances (in corpus order), predict each other
    speaker's, one split per other speaker."""
    out = []
    if "speaker" in which:
        unnamed = [u.name for u in utts if "speaker" not in u.meta]
        if unnamed:
            raise ValueError(f"split 'speaker': no speaker for {', '.join(unnamed)} (give the manifest a 'speaker' column)")
        speakers = list(dict.fromkeys(u.meta["speaker"] for u in utts))
        for other in speakers[1:]:
            out.append((f"speaker {other}", [u for u in utts if u.meta["speaker"] == speakers[0]],
                        [u for u in utts if u.meta["speaker"] == other]))
    fast = [u for u in utts if u.meta.get("rate") == "fast"]
    if "rate" in which:
        out.append(("rate", [u for u in utts if u.meta.get("rate") == "normal"], fast))
    if "ratefast" in which:  # the other direction: fit the fast rate, predict the normal one
        out.append(("rate fast", fast, [u for u in utts if u.meta.get("rate") == "normal"]))
    for k in (1, 2):
        if f"starved{k}" in which:
            out.append((f"starved {k}", [u for u in utts if u.meta.get("rate") == "normal"
                                         and int(u.meta.get("repetition", 0)) <= k], fast))
    if "loo" in which and len(utts) > 1:
        for k, held in enumerate(utts):
            out.append((f"LOO {short_name(held.name)}",
                        [u for j, u in enumerate(utts) if j != k], [held]))
    if "time" in which:
        first, second = zip(*(halves(u) for u in utts))
        out.append(("time split", list(first), list(second)))
    return out


def masked(test: Utterance, original: Utterance, keep_labels: set[str], pauses: bool = False) -> Utterance:
    """``test`` (labels possibly mapped to fallbacks) with every sample outside a segment whose
    *original* phoneme is in ``keep_labels`` marked invalid: not scored. Pauses (of any posture,
    coartic.pauses) are scored only with ``pauses`` (and the pause in ``keep_labels``)."""
    keep = np.array([lab in keep_labels and (pauses or not is_pause(lab)) for lab in original.labels]
                    + [False])[original.sample_segments()]
    return Utterance(test.labels, test.starts, test.ends, test.times, test.name, test.observed,
                     {c: v & keep for c, v in test.valid.items()}, test.meta)


def predict_channel(spec: FitSpec, trained: FitResult, channel: str, test: Sequence[Utterance],
                    label_map: Any, unseen: str = "transfer",
                    train: Sequence[Utterance] = ()) -> tuple[Any, list[Utterance], list[str]]:
    """The table that predicts ``test`` on ``channel``, the test utterances as it reads them, and
    notes: trained phonemes as fitted, unseen ones by class fallback; those with no fallback trained
    either fitted on the test data with every trained phoneme fixed (``unseen="transfer"``), or
    given the step model's fallback (``"constant"``: target = the training mean of the channel,
    dynamics = the median over the trained phonemes; nothing is taken from the test data)."""
    fit = trained.channels[channel]
    table = trained.table()
    mapped, note = with_fallbacks(test, table, (channel,), label_map)
    notes = [note] if note else []
    known = set(fit.phonemes)
    missing = sorted({lab for u in mapped for lab in u.labels} - known)
    if not missing:
        return table, mapped, notes
    if unseen == "constant":
        table = copy.deepcopy(table)
        mean = Baselines.fit(train, (channel,)).constant[channel]
        typical = {par: float(np.median(fit.params[:, j])) for j, par in enumerate(PARAMETERS)}
        for p in missing:
            table.values.setdefault(p, {})[channel] = {**typical, "target": mean}
        notes.append(f"{channel}: /{' '.join(missing)}/ (no fallback trained) predicted at the training mean "
                     "with the median dynamics, not scored")
        return table, mapped, notes
    row = {p: i for i, p in enumerate(fit.phonemes)}
    fixes = tuple(Override(phonemes=(p,), channels=(channel,),
                           fixed={par: float(fit.params[row[p], j]) for j, par in enumerate(PARAMETERS)})
                  for p in sorted(known))
    # a parameter tied across phonemes ("t+shared") keeps its trained shared value for the unseen too
    tied = {par: float(fit.params[0, PARAMETERS.index(par)]) for par in spec.parameters.shared}
    if tied:
        fixes += (Override(phonemes=tuple(missing), channels=(channel,), fixed=tied),)
    # the target box must hold the trained targets, which a box from the test data alone may not
    y = np.concatenate([u.observed[channel][u.valid[channel]] for u in mapped])
    targets = fit.params[:, PARAMETERS.index("target")]
    box = (min(float(targets.min()), float(np.nanmin(y)) - spec.parameters.target_margin),
           max(float(targets.max()), float(np.nanmax(y)) + spec.parameters.target_margin))
    bounds = {**spec.parameters.channel_bounds, channel: {**spec.parameters.channel_bounds.get(channel, {}), "target": box}}
    tspec = spec.with_options(channels=(channel,), overrides=spec.parameters.overrides + fixes, beta=fit.beta, channel_bounds=bounds,
                              shrinks=tuple(g for g in spec.priors.shrinks if set(g.phonemes) & set(missing)),
                              shared=(), pooled=(), target_prior=None)
    tspec = tspec.with_options(starts=1)  # a handful of free parameters: one local fit
    notes.append(f"{channel}: /{' '.join(missing)}/ fitted on the test data (no fallback trained), not scored")
    return run(tspec, utterances=list(mapped), quiet=True).table(), mapped, notes


def evaluate_cell(base: FitSpec, utts: Sequence[Utterance], variant: str, freedom: Sequence[str] | str, reg: str,
                  which: Sequence[str] = ("loo", "time"), starts: int | None = None,
                  unseen: str = "constant") -> list[dict[str, Any]]:
    """One cell on every split: a row per (split, channel) with the table's held-out RMSE (raw and
    offset removed), the constant's and step model's on the same samples, and the in-sample RMSE.
    Each channel is fitted on its own (as ``coartic fit`` does), so a target prior can be per channel."""
    spec = cell_spec(base, variant, freedom, reg, starts)
    label_map = resolve_label_map(base.corpus.label_map) if base.corpus.label_map else None
    sd = tprior_sd(reg)
    rows = []
    for name, train, test in splits(utts, which):
        t0 = time.process_time()
        for ch in spec.channels:
            one = spec.with_options(channels=(ch,))
            extra: dict[str, Any] = {}
            if sd == "cv":
                chosen, curve = choose_tprior_sd(one, train, ch, label_map, unseen)
                one = one.with_options(target_prior=chosen)
                extra = {"tprior_sd": chosen, "cv": curve}
            got = fit_and_score(one, train, test, ch, label_map, unseen)
            rows.append({"variant": variant, "freedom": freedom_name(freedom), "reg": reg, "split": name,
                         "channel": ch, "unseen": unseen, "starts": spec.fit.starts, "theta0": spec.parameters.start_of("theta_bw"),
                         **got, **extra})
        rows[-1]["cpu"] = time.process_time() - t0
    return rows


def freedom_name(freedom: Sequence[str] | str) -> str:
    """A freedom's name: itself when given by name (two freedoms may free the same parameters, e.g.
    "tat" and "pooled"), else the first FREEDOM with these parameters."""
    if isinstance(freedom, str):
        return freedom
    return next((k for k, v in FREEDOM.items() if tuple(v) == tuple(freedom)), "+".join(freedom))


def pooled(rows: Sequence[dict[str, Any]], key: str, suffix: str = "") -> float:
    """RMSE over every scored sample of ``rows`` (each row's RMSE weighted by its samples);
    ``suffix`` "_nolast": the figures without each test utterance's last segment."""
    rows = [r for r in rows if f"{key}{suffix}" in r]
    n = sum(r[f"samples{suffix}"] for r in rows)
    return math.sqrt(sum(r[f"{key}{suffix}"] ** 2 * r[f"samples{suffix}"] for r in rows) / n) if n else float("nan")


def cell_key(r: dict[str, Any]) -> tuple[str, str, str, str]:
    """What makes a cell: variant, freedom, regularisation, and how it was fitted (fallback of unseen
    phonemes, starts, theta start: rows of earlier runs lack the last two, which were 1 and 40)."""
    fitted = f"{r.get('unseen', 'transfer')} {r.get('starts', 1)}/{r.get('theta0', 40.0):g}"
    return r["variant"], r["freedom"], r["reg"], fitted


def summary_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Per cell, pooled over splits and channels: held-out raw and -offset RMSE of the table and the
    baselines, in-sample RMSE, how many (split, channel) pairs beat the step model, and the table's
    and step model's RMSE without each test utterance's last segment; best first."""
    cells: dict[tuple[str, str, str, str], list[dict[str, Any]]] = {}
    for r in rows:
        cells.setdefault(cell_key(r), []).append(r)
    ranked = sorted(cells.items(), key=lambda kv: pooled(kv[1], "table"))
    out = [f"{'variant':11s} {'freedom':9s} {'reg':10s} {'unseen starts/θ0':17s} {'held-out':>8s} {'-offset':>8s} {'const':>7s} "
           f"{'-off':>6s} {'step':>6s} {'-off':>6s} {'in-smp':>6s} beats step (raw/-off) {'nolast':>7s} {'step':>6s}"
           f" {'all':>6s} {'step':>6s}  CPU s  held-out per channel (raw)"]
    for (v, f, g, un), rs in ranked:
        beat = sum(r["table"] < r["step"] for r in rs), sum(r["table_off"] < r["step_off"] for r in rs)
        insample = math.sqrt(np.mean([r["in_sample"] ** 2 for r in rs]))
        out.append(f"{v:11s} {f:9s} {g:10s} {un:17s} {pooled(rs, 'table'):8.3f} {pooled(rs, 'table_off'):8.3f} "
                   f"{pooled(rs, 'constant'):7.3f} {pooled(rs, 'constant_off'):6.3f} {pooled(rs, 'step'):6.3f} "
                   f"{pooled(rs, 'step_off'):6.3f} {insample:6.3f} {beat[0]}/{len(rs)} {beat[1]}/{len(rs)}"
                   f"{pooled(rs, 'table', '_nolast'):17.3f} {pooled(rs, 'step', '_nolast'):6.3f}"
                   f" {pooled(rs, 'table', '_all'):6.3f} {pooled(rs, 'step', '_all'):6.3f}"
                   f"{sum(r.get('cpu', 0.0) for r in rs):7.0f}  "
                   + " ".join(f"{ch} {pooled([r for r in rs if r['channel'] == ch], 'table'):.3f}"
                              for ch in dict.fromkeys(r["channel"] for r in rs)))
    if len(ranked) > 1:
        (best, b), (second, s2) = ranked[0], ranked[1]
        key = lambda r: (r["split"], r["channel"])  # noqa: E731
        diff = {key(r): r["table"] for r in b}
        d = [diff[key(r)] - r["table"] for r in s2 if key(r) in diff]
        out.append(f"best {' '.join(best)} vs next {' '.join(second)}: pooled {pooled(b, 'table'):.3f} vs "
                   f"{pooled(s2, 'table'):.3f} mm; per (split, channel) differences {min(d):+.3f} .. {max(d):+.3f} mm, "
                   f"{sum(x < 0 for x in d)} of {len(d)} in favour of the best")
    return out


def utterance_units(rows: Sequence[dict[str, Any]], channel: str | None = None,
                    model: str = "table") -> dict[tuple[str, str], tuple[float, int]]:
    """Each held-out test utterance of ``rows`` (speech only, as measured: the rows' scored
    segments) as a unit (split, utterance) -> (SSE of ``model``, "table" or "step", samples),
    summed over the channels (or ``channel``'s only): the units of ``heldout_se``."""
    units: dict[tuple[str, str], tuple[float, int]] = {}
    for r in rows:
        if channel is not None and r["channel"] != channel:
            continue
        for utt, _, _, n, table, step, _ in r.get("segments") or ():
            rmse = table if model == "table" else step
            e, k = units.get((r["split"], utt), (0.0, 0))
            units[(r["split"], utt)] = (e + rmse**2 * n, k + n)
    return units


def unit_se(units: dict[tuple[str, str], tuple[float, int]]) -> float:
    """The standard error of the pooled RMSE over these units, as ``coartic compare`` takes it
    (coartic.evaluation.compare.heldout_se: each test utterance a unit, the delta method)."""
    return heldout_se([SimpleNamespace(channel="", utterance_sse=units)], "")


def paired_se(a: dict[tuple[str, str], tuple[float, int]], b: dict[tuple[str, str], tuple[float, int]]) -> float:
    """The standard error of RMSE(a) - RMSE(b) over the units both score (the same samples): each
    unit's influence on either pooled RMSE by the delta method of ``heldout_se``, differenced, so
    what the two models share (a hard utterance) cancels. NaN with fewer than two units."""
    keys = [k for k in a if k in b and a[k][1] > 0]
    if len(keys) < 2:
        return math.nan
    n = float(sum(a[k][1] for k in keys))
    ma, mb = sum(a[k][0] for k in keys) / n, sum(b[k][0] for k in keys) / n
    if ma <= 0 or mb <= 0:
        return math.nan
    d = [(a[k][0] - ma * a[k][1]) / (2 * math.sqrt(ma) * n) - (b[k][0] - mb * b[k][1]) / (2 * math.sqrt(mb) * n)
         for k in keys]
    return math.sqrt(len(keys) / (len(keys) - 1) * sum(x * x for x in d))


def noise_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Held-out RMSE (speech only, as measured) ± its SE over the test utterances per cell, per
    channel and pooled over the channels; then every other cell against the pooled default
    ("pooled", "tprior-eb"; else the best): the difference and its paired SE, and whether it
    exceeds one SE (the margin ``coartic compare``'s one-SE rule treats as noise)."""
    cells: dict[tuple[str, str, str, str], list[dict[str, Any]]] = {}
    for r in rows:
        cells.setdefault(cell_key(r), []).append(r)
    if not any(r.get("segments") for r in rows):
        return []
    channels = list(dict.fromkeys(r["channel"] for r in rows))
    out = [f"{'variant':11s} {'freedom':9s} {'reg':10s} {'held-out ± SE':>15s}  "
           + "  ".join(f"{ch + ' ± SE':>15s}" for ch in channels) + "  units"]
    for (v, f, g, _), rs in sorted(cells.items(), key=lambda kv: pooled(kv[1], "table")):
        per = "  ".join(f"{pooled([r for r in rs if r['channel'] == ch], 'table'):7.3f} ± {unit_se(utterance_units(rs, ch)):5.3f}"
                        for ch in channels)
        out.append(f"{v:11s} {f:9s} {g:10s} {pooled(rs, 'table'):7.3f} ± {unit_se(utterance_units(rs)):5.3f}  {per}  "
                   f"{len(utterance_units(rs))}")
    ref = next((k for k in cells if k[1] == "pooled" and k[2] == "tprior-eb"),
               min(cells, key=lambda k: pooled(cells[k], "table")))
    base = cells[ref]
    out.append(f"against {' '.join(ref[:3])}: its RMSE minus the other's (< 0: it is lower), ± the paired SE; "
               "'noise' when within one SE")
    for key, rs in [*((k, v) for k, v in cells.items() if k != ref), (("", "step", "model", ""), base)]:
        other = "step" if key[1] == "step" else "table"
        parts = []
        for ch in [None, *channels]:
            a, b = utterance_units(base, ch), utterance_units(rs, ch, other)
            sel = [r for r in base if ch is None or r["channel"] == ch], [r for r in rs if ch is None or r["channel"] == ch]
            d, se = pooled(sel[0], "table") - pooled(sel[1], other), paired_se(a, b)
            # one test utterance (a corpus of one, or one other speaker) gives no SE: say so, not a verdict
            word = "no SE" if math.isnan(se) else "noise" if abs(d) <= se else ("lower" if d < 0 else "HIGHER")
            parts.append(f"{ch or 'all'} {d:+.3f} ± {se:.3f} {word}")
        out.append(f"  vs {' '.join(key[:3]).strip()}: " + "; ".join(parts))
    return out


# docs/REAL_DATA.md's names of the cells it compares (freedom, regularisation)
NAMED_CELLS = {("t+shared", "tprior:0.3"): "shared", ("pooled", "tprior-eb"): "pooled (default)",
               ("tat", "tprior:0.3"): "per-phoneme", ("pooled", "tprior:0.3"): "pooled, target sd 0.3"}


def markdown_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """docs/REAL_DATA.md's tables: per (split, channel) and pooled over them, each named cell's
    held-out RMSE as "speech as measured / speech offset removed / all samples" (mm), then the step
    model's and the constant's on the same samples (the first named cell's rows: every cell scores
    the same samples), and the pooled figures' SE over the test utterances (speech, as measured)."""
    cells = {NAMED_CELLS[(r["freedom"], r["reg"])]: [] for r in rows if (r["freedom"], r["reg"]) in NAMED_CELLS}
    for r in rows:
        if (r["freedom"], r["reg"]) in NAMED_CELLS:
            cells[NAMED_CELLS[(r["freedom"], r["reg"])]].append(r)
    if not cells:
        return []
    names = [n for n in NAMED_CELLS.values() if n in cells]
    ref = cells[names[0]]

    def fig(rs: Sequence[dict[str, Any]], m: str) -> str:
        return f"{pooled(rs, m):.3f} / {pooled(rs, m + '_off'):.3f} / {pooled(rs, m, '_all'):.3f}"

    out = ["| split | ch | " + " | ".join(names) + " | step | constant |",
           "|---" * (len(names) + 4) + "|"]
    groups = [(f"{r['split']}", r["channel"]) for r in ref]
    for split, ch in dict.fromkeys(groups):
        sel = {n: [r for r in cells[n] if r["split"] == split and r["channel"] == ch] for n in names}
        out.append(f"| {split} | {ch} | " + " | ".join(fig(sel[n], "table") for n in names)
                   + f" | {fig(sel[names[0]], 'step')} | {fig(sel[names[0]], 'constant')} |")
    out.append(f"| **pooled** | all | " + " | ".join(fig(cells[n], "table") for n in names)
               + f" | {fig(ref, 'step')} | {fig(ref, 'constant')} |")
    out.append(f"| SE (speech, as measured) | all | " + " | ".join(f"± {unit_se(utterance_units(cells[n])):.3f}" for n in names)
               + f" | ± {unit_se(utterance_units(ref, model='step')):.3f} | |")
    return out


def speaker_note(rows: Sequence[dict[str, Any]]) -> list[str]:
    """A warning above the tables of a split across speakers: there the figures as measured (and
    what ranks by them: the summary, the noise section) mostly measure where each speaker's sensors
    sit; the offset-removed figures are the ones to compare."""
    if not any(str(r["split"]).startswith("speaker") for r in rows):
        return []
    return ["note: across speakers the recordings' origins differ (the sensors sit elsewhere on another face): "
            "the figures as measured, the summary's ranking and the noise section (both by them) mostly measure "
            "that origin; compare the offset-removed figures ('-offset', '-off', the second of each table cell)"]


def row_line(r: dict[str, Any]) -> str:
    sd = f"  sd {r['tprior_sd']:g}" if "tprior_sd" in r else ""
    if r.get("pooling"):
        sd += "  " + "; ".join(f"{f} sd {v['sd']:.3g} ({v['effective_parameters']:.1f}/{v['rank']})"
                               for f, v in r["pooling"]["families"].items())
    if "table_all" in r:
        sd = f"  all: {r['table_all']:.3f} step {r['step_all']:.3f} n {r['samples_all']}" + sd
    last = (f"{r['table_nolast']:8.3f}{r['step_nolast']:7.3f}{r['samples_nolast']:6d}" if "table_nolast" in r
            else f"{'':21s}")
    return (f"{r['variant']:11s} {r['freedom']:9s} {r['reg']:10s} {r.get('unseen', 'transfer'):8s} {r['split']:11s} "
            f"{r['channel']:4s}{r['table']:7.3f}{r['table_off']:8.3f}{r['constant']:7.3f}{r['constant_off']:7.3f}"
            f"{r['step']:7.3f}{r['step_off']:7.3f}{r['in_sample']:8.3f}{r['samples']:6d}{last}  {r['status']}{sd}")


ROW_HEADER = (f"{'variant':11s} {'freedom':9s} {'reg':10s} {'unseen':8s} {'split':11s} {'ch':4s}{'table':>7s}{'-off':>8s}"
              f"{'const':>7s}{'-off':>7s}{'step':>7s}{'-off':>7s}{'in-smp':>8s}{'n':>6s}{'nolast':>8s}{'step':>7s}"
              f"{'n':>6s}  status")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variants", default=",".join(VARIANT_NAMES))
    ap.add_argument("--freedom", default=",".join(FREEDOM), help=f"among {', '.join(FREEDOM)}")
    ap.add_argument("--reg", default=",".join(REGULARISATION))
    ap.add_argument("--corpus", default="german", help=f"among {', '.join(c.key for c in CORPORA)} (comma-separated)")
    ap.add_argument("--channels", default=None, help="default: the corpus's (German, s1em, speakers LA,JO; "
                    "synthetic LLO,JO)")
    ap.add_argument("--splits", default=None, help="default: the corpus's (german loo,time; s1em time; speakers "
                    "speaker; synthetic rate,starved1,starved2; gestures rate; ratefast: fit fast, predict normal)")
    ap.add_argument("--starts", type=int, default=None, help="[fit] starts of every fit (default: the spec default)")
    ap.add_argument("--theta-start", type=float, default=None,
                    help="start of theta_bw and theta_fw (default: the corpus spec's): is the fit start-independent?")
    ap.add_argument("--pauses", default=None, choices=("postures", "one"),
                    help="[model] pauses of every fit (default: the corpus spec's; a spec that sets nothing: postures)")
    ap.add_argument("--losses", action="store_true", help="also print where each cell loses to the step model")
    ap.add_argument("--unseen", default="constant", choices=("transfer", "constant"),
                    help="test phonemes with no class fallback trained: fitted on the test data (transfer) or "
                         "predicted at the training mean, as the step model does (constant)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "real_data.txt")
    ap.add_argument("--merge", type=Path, nargs="+", metavar="TXT",
                    help="only merge earlier runs' outputs (parts of the grid run side by side) into --out")
    a = ap.parse_args()
    if a.merge:
        return merge(a.merge, a.out)
    variants, freedoms, regs = a.variants.split(","), a.freedom.split(","), a.reg.split(",")
    for what, got, known in (("variants", variants, VARIANT_NAMES), ("freedom", freedoms, tuple(FREEDOM)),
                             ("reg", regs, REGULARISATION)):
        if what == "reg":
            got = [g for g in got if tprior_sd(g) is None]
        if set(got) - set(known):
            ap.error(f"--{what}: unknown {sorted(set(got) - set(known))} (known: {', '.join(known)})")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    t0, c0 = time.perf_counter(), time.process_time()
    lines = ["# bench/real_data.py: held-out RMSE (mm) of model variants x freedom x regularisation on real recordings",
             f"# command: nice -n 10 .venv/bin/python bench/real_data.py {' '.join(sys.argv[1:])}".rstrip()]
    all_rows: list[dict[str, Any]] = []
    wanted = a.corpus.split(",")
    if set(wanted) - {c.key for c in CORPORA}:
        ap.error(f"--corpus: unknown {sorted(set(wanted) - {c.key for c in CORPORA})}")
    for corpus in [c for c in CORPORA if c.key in wanted]:
        channels = a.channels or corpus.channels
        which = (a.splits or corpus.splits).split(",")
        base = corpus_spec(corpus).with_options(channels=tuple(channels.split(",")))
        if a.pauses is not None:
            base = base.with_options(pauses=a.pauses)
        if a.theta_start is not None:
            base = base.with_options(start={**base.parameters.start, "theta_bw": a.theta_start, "theta_fw": a.theta_start})
        starts = a.starts if a.starts is not None else base.fit.starts
        utts = load_utterances(base)
        lines += [f"## {corpus.name}: {corpus.spec.relative_to(ROOT) if corpus.manifest is None else 'a spec that sets nothing but ' + str(corpus.manifest.relative_to(ROOT))}, channels {channels}, splits {','.join(which)}; source {corpus.source}; "
                  f"licence {corpus.licence}", f"fits: [fit] starts = {starts}; theta start {base.parameters.start_of('theta_bw'):g}; pauses {base.model.pauses}; shrink sd = {SHRINK_SD} when on; nolast: without each test "
                  "utterance's last segment",
                  ROW_HEADER]
        print("\n".join(lines), flush=True)
        rows: list[dict[str, Any]] = []
        for v in variants:
            for f in freedoms:
                for g in regs:
                    got = evaluate_cell(base, utts, v, f, g, which, a.starts, a.unseen)
                    for r in got:
                        lines.append(row_line(r))
                        print(lines[-1], flush=True)
                    rows += got
                    # after every cell, so an interrupted run keeps what it finished
                    atomic_write_text(a.out.with_suffix(".json"), json.dumps(all_rows + rows))
                    atomic_write_text(a.out, "\n".join(lines) + "\n")
        all_rows += rows
        notes = sorted({n for r in rows for n in r["notes"]})
        lines += [f"note: {n}" for n in notes]
        if a.losses:
            lines += ["", "## where the tables lose to the step model: dSSE = table SSE - step SSE (mm^2) over the "
                      "scored samples; 'last seg': the part of it in each test utterance's last segment, 'of n' "
                      "that segment's share of the samples", *loss_lines(rows)]
        lines += ["", f"## summary, {corpus.name}: pooled over splits and channels, best held-out (raw) first",
                  *speaker_note(rows), *summary_lines(rows), ""]
    lines.append(f"({time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU of this process)")
    print("\n".join(lines[-12:]))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(a.out.with_suffix(".json"), json.dumps(all_rows))
    atomic_write_text(a.out, "\n".join(lines) + "\n")
    print(f"wrote {a.out}")
    return 0


def merge(parts: Sequence[Path], out: Path) -> int:
    """One output from runs of parts of the grid: their texts, then the summary of all their rows."""
    rows, seen = [], set()
    for p in parts:  # a cell run in two parts counts once (the first part's rows)
        for r in json.loads(p.with_suffix(".json").read_text(encoding="utf-8")):
            if (cell_key(r), r["split"], r["channel"]) not in seen:
                seen.add((cell_key(r), r["split"], r["channel"]))
                rows.append(r)
    lines = [line for p in parts for line in p.read_text(encoding="utf-8").splitlines()]
    lines += ["", "## summary of all the parts above: pooled over splits and channels, best held-out (raw) first",
              *speaker_note(rows), *summary_lines(rows)]
    table = markdown_lines(rows)
    if table:
        lines += ["", "## docs/REAL_DATA.md: held-out RMSE (mm), speech as measured / speech offset removed / all samples",
                  *table]
    noise = noise_lines(rows)
    if noise:
        lines += ["", "## noise: held-out RMSE (speech only, as measured) ± its standard error over the test utterances "
                  "(coartic compare's heldout_se), per cell; the default against each other cell, paired", *noise]
    atomic_write_text(out.with_suffix(".json"), json.dumps(rows))
    atomic_write_text(out, "\n".join(lines) + "\n")
    print("\n".join(lines[-len(summary_lines(rows)) - 1:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
