"""The answers analysed (statsmodels): mixed models with participant and item effects, confusion
matrices, participant-level bootstrap intervals.

- Exclusions, stated in the report: a participant who passed fewer than ATTENTION_MIN of their
  attention checks; in MUSHRA, one who rated the hidden reference below 90 on more than 15 % of the
  items (ITU-R BS.1534-3's post-screening).
- intelligibility and emotion: right (1) or wrong (0) per answer (a typed answer counts each word of
  the item as one such answer) modelled by a Bayesian binomial GLMM on the logit scale
  (statsmodels' BinomialBayesMixedGLM, variational Bayes; intervals by a
  jackknife over groups of participants, see binomial_glmm): fixed effects of condition (against the
  study's first condition) and SNR (against its lowest), random intercepts of participant and item;
  proportions right per condition and SNR with 95 % intervals from resampling participants;
  confusion matrices (right answer x given answer) per condition, and by viseme (Meta's classes,
  coartic.runtime.rigs) where every answer is a phoneme.
- preference: a Bradley-Terry GLMM: P(the face shown first is chosen) = logistic(position + s_first
  - s_second), s of the first condition 0, random intercepts of participant and item; the share of
  choices per pair with bootstrap intervals.
- MUSHRA: ratings by a linear mixed model (statsmodels' MixedLM, REML): condition fixed (against
  the first condition that is not the reference), participant random intercept, item variance
  component; mean ratings with bootstrap intervals.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from statsmodels.tools.sm_exceptions import ConvergenceWarning

ATTENTION_MIN = 0.75
MUSHRA_REFERENCE_MIN = 90
MUSHRA_REFERENCE_SHARE = 0.15
BOOTSTRAP = 2000
JACKKNIFE_GROUPS = 10
Z95 = 1.959963984540054


@dataclass
class Effect:
    """A fixed effect: posterior mean and sd (GLMM, logit scale) or estimate and standard error (LMM)."""

    name: str
    estimate: float
    se: float
    low: float
    high: float

    @property
    def credible(self) -> bool:
        """The 95 % interval excludes 0."""
        return self.low > 0 or self.high < 0


@dataclass
class Analysis:
    design: str
    n_participants: int
    n_simulated: int
    n_answers: int
    excluded: dict[str, str]
    effects: list[Effect]
    variance: dict[str, float]
    cells: pd.DataFrame
    confusions: dict[str, pd.DataFrame] = field(default_factory=dict)
    model: str = ""
    notes: list[str] = field(default_factory=list)

    def effect(self, name: str) -> Effect:
        return next(e for e in self.effects if e.name == name)

    def summary(self) -> dict[str, Any]:
        """What summary.json holds."""
        return {
            "design": self.design, "participants": self.n_participants, "simulated": self.n_simulated,
            "answers": self.n_answers, "excluded": self.excluded, "model": self.model,
            "effects": [{"name": e.name, "estimate": e.estimate, "se": e.se, "low": e.low, "high": e.high,
                         "credible": e.credible} for e in self.effects],
            "variance": self.variance,
            "cells": self.cells.astype(object).where(self.cells.notna(), None).to_dict(orient="records"),
            "confusions": {k: {"rows": [str(i) for i in v.index], "columns": [str(c) for c in v.columns],
                               "counts": v.to_numpy().tolist()} for k, v in self.confusions.items()},
            "notes": self.notes,
        }


def exclusions(manifest: dict[str, Any], tidy: pd.DataFrame) -> dict[str, str]:
    """participant -> why their answers are left out."""
    out: dict[str, str] = {}
    att = tidy[tidy["kind"] == "attention"]
    for pid, rows in att.groupby("participant"):
        rate = float(rows["correct"].mean())
        if rate < ATTENTION_MIN:
            out[str(pid)] = f"passed {int(rows['correct'].sum())} of {len(rows)} attention checks"
    if manifest["design"] == "mushra":
        ref = tidy[(tidy["kind"] == "stimulus") & (tidy["reference"] == 1)]
        for pid, rows in ref.groupby("participant"):
            low = float((rows["response"].astype(float) < MUSHRA_REFERENCE_MIN).mean())
            if low > MUSHRA_REFERENCE_SHARE and str(pid) not in out:
                out[str(pid)] = (f"rated the hidden reference below {MUSHRA_REFERENCE_MIN} on {100 * low:.0f} % of "
                                 "the items (BS.1534-3 post-screening)")
    return out


def _codes(values: pd.Series) -> np.ndarray:
    return np.asarray(pd.Categorical(values).codes, dtype=np.int64)


def _convergence_notes(caught: list[warnings.WarningMessage], converged: bool) -> list[str]:
    """The optimiser's convergence warnings, said in the report rather than lost on stderr."""
    said = list(dict.fromkeys(str(w.message).splitlines()[0] for w in caught if issubclass(w.category, ConvergenceWarning)))
    if not converged:
        said.insert(0, "the mixed model's optimiser did not converge: read its estimates with care")
    return [f"statsmodels: {m}" for m in said]


def binomial_glmm(y: np.ndarray, exog: pd.DataFrame, groups: dict[str, pd.Series],
                  notes: list[str]) -> tuple[list[Effect], dict[str, float]]:
    """A logit GLMM with random intercepts per group (statsmodels BinomialBayesMixedGLM, variational
    Bayes): the fixed effects' posterior means and each group's random-intercept sd. Their intervals
    come from a jackknife over the first group (participants): over simulated studies
    (studies/check_calibration.py) mean-field variational Bayes gave posterior sds a quarter narrower
    than the spread of its estimates (0.14 vs 0.18 logit; its 95 % intervals missed twice as often as
    they should), the jackknife's a fifth to a third wider (0.21-0.25: conservative). The
    participants are dealt into JACKKNIFE_GROUPS groups (one each when fewer), each left out in turn
    (the grouped jackknife: as many fits as groups, however many participants). Each fit keeps every
    random-effect column (the left-out participants' follow their prior) and starts from the full
    fit; the full fit starts from fixed values, so that an analysis is reproducible. The fits are
    statsmodels' to the bit, computed faster (coartic.perceive.vb). The optimiser's warnings are
    appended to `notes`."""
    from scipy import sparse, stats

    blocks, ident, names = [], [], []
    for k, (name, g) in enumerate(groups.items()):
        codes = _codes(g)
        n = int(codes.max()) + 1
        blocks.append(sparse.csr_matrix((np.ones(codes.size), (np.arange(codes.size), codes)), shape=(codes.size, n)))
        ident += [k] * n
        names.append(name)
    exog_vc = sparse.hstack(blocks).tocsr()
    x = exog.to_numpy(dtype=float)
    y = np.asarray(y, dtype=float)
    full = _fit_vb(y, x, exog_vc, np.asarray(ident), list(exog.columns), names, notes)
    n_fe = x.shape[1]
    people = next(iter(groups.values())).to_numpy()
    keys = sorted(pd.unique(people))
    n = min(len(keys), JACKKNIFE_GROUPS)
    group = np.array([{k: i % n for i, k in enumerate(keys)}[p] for p in people])
    start = (full.params, np.sqrt(np.asarray(full.cov_params()).diagonal() if np.ndim(full.cov_params()) == 2
                                  else np.asarray(full.cov_params())))
    leave = np.array([_fit_vb(y[group != g], x[group != g], exog_vc[group != g], np.asarray(ident),
                              list(exog.columns), names, notes, start).params[:n_fe] for g in range(n)])
    se = np.sqrt((n - 1) / n * ((leave - leave.mean(axis=0)) ** 2).sum(axis=0))
    t = float(stats.t.ppf(0.975, n - 1))
    effects = [Effect(name, float(m), float(s), float(m - t * s), float(m + t * s))
               for name, m, s in zip(exog.columns, full.fe_mean, se)]
    return effects, {f"{g} sd (logit)": float(np.exp(v)) for g, v in zip(names, full.vcp_mean)}


def _fit_vb(y: np.ndarray, x: np.ndarray, exog_vc: Any, ident: np.ndarray, fe_names: list[str], vc_names: list[str],
            notes: list[str], start: tuple[np.ndarray, np.ndarray] | None = None) -> Any:
    from coartic.perceive.vb import InterceptsBinomialGLMM

    model = InterceptsBinomialGLMM(y, x, exog_vc, ident, fep_names=fe_names, vcp_names=vc_names)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        if start is None:  # the centre of statsmodels' own start, which adds fresh random noise to the
            # sds: its estimates differed by about 1e-6 from one run of an analysis to the next
            n = model.k_fep + model.k_vcp + model.k_vc
            start = np.zeros(n), np.full(n, np.exp(-0.5))
        res = model.fit_vb(mean=start[0], sd=start[1])
    for note in _convergence_notes(caught, True):
        if note not in notes:
            notes.append(note)
    return res


def bootstrap_means(frame: pd.DataFrame, keys: list[str], value: str, seed: int) -> pd.DataFrame:
    """Mean of `value` per cell of `keys`, with a 95 % percentile interval from resampling participants."""
    cells = frame.groupby(keys, dropna=False)[value].agg(["sum", "count"])
    per = frame.groupby(["participant", *keys], dropna=False)[value].agg(["sum", "count"])
    people = sorted(frame["participant"].unique())
    sums = np.zeros((len(people), len(cells)))
    counts = np.zeros((len(people), len(cells)))
    where = {k: i for i, k in enumerate(cells.index)}
    pindex = {p: i for i, p in enumerate(people)}
    for (p, *rest), row in per.iterrows():
        key = rest[0] if len(rest) == 1 else tuple(rest)
        sums[pindex[p], where[key]] = row["sum"]
        counts[pindex[p], where[key]] = row["count"]
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(people), size=(BOOTSTRAP, len(people)))
    s, c = sums[draws].sum(axis=1), counts[draws].sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        boot = s / c
    out = cells.reset_index()
    out["mean"] = cells["sum"].to_numpy() / cells["count"].to_numpy()
    out["low"] = np.nanpercentile(boot, 2.5, axis=0)
    out["high"] = np.nanpercentile(boot, 97.5, axis=0)
    out["participants"] = (counts > 0).sum(axis=0)
    return out.rename(columns={"count": "n"}).drop(columns=["sum"])


def _dummies(values: pd.Series, levels: list[Any], prefix: str) -> pd.DataFrame:
    return pd.DataFrame({f"{prefix}[{lvl}]": (values == lvl).astype(float).to_numpy() for lvl in levels[1:]})


def confusion(frame: pd.DataFrame, labels: list[str]) -> pd.DataFrame:
    """Counts of given answers (columns) per right answer (rows), in `labels` order."""
    table = pd.crosstab(frame["expected"].astype(str), frame["response"].astype(str))
    return table.reindex(index=labels, columns=labels, fill_value=0)


def _identification(manifest: dict[str, Any], data: pd.DataFrame, seed: int) -> Analysis:
    conds = [c["name"] for c in manifest["conditions"]]
    snrs = sorted({s for s in data["snr_db"].dropna().unique()})
    rows = data
    if manifest["response"] == "text":  # each word of the item one Bernoulli answer: k right of n
        n_words = rows["expected"].map(lambda t: max(1, len(str(t).split())))
        k = np.rint(rows["correct"].to_numpy() * n_words.to_numpy()).astype(int)
        rows = rows.loc[rows.index.repeat(n_words)].copy()
        rank = rows.groupby(level=0).cumcount().to_numpy()
        rows["correct"] = (rank < np.repeat(k, n_words.to_numpy())).astype(float)
        rows = rows.reset_index(drop=True)
    exog = pd.concat([pd.DataFrame({"intercept": np.ones(len(rows))}),
                      _dummies(rows["condition"].reset_index(drop=True), conds, "condition"),
                      _dummies(rows["snr_db"].reset_index(drop=True), snrs, "snr_db") if len(snrs) > 1 else None],
                     axis=1)
    notes: list[str] = []
    effects, variance = binomial_glmm(rows["correct"].to_numpy(), exog,
                                      {"participant": rows["participant"], "item": rows["item"]}, notes)
    keys = ["condition", "snr_db"] if snrs else ["condition"]
    cells = bootstrap_means(data, keys, "correct", seed)
    confusions: dict[str, pd.DataFrame] = {}
    if manifest["response"] == "choice":
        labels = [str(c) for c in manifest["choices"]]
        for c in conds:
            confusions[f"{c}"] = confusion(data[data["condition"] == c], labels)
        if manifest["design"] == "intelligibility":
            from coartic.runtime.rigs import PHONEME_VISEME

            if all(lab in PHONEME_VISEME for lab in labels):
                vis = data.assign(expected=data["expected"].map(PHONEME_VISEME), response=data["response"].map(PHONEME_VISEME))
                vlabels = list(dict.fromkeys(PHONEME_VISEME[lab] for lab in labels))
                for c in conds:
                    confusions[f"{c}, by viseme"] = confusion(vis[vis["condition"] == c], vlabels)
    model = ("right ~ condition" + (" + SNR" if len(snrs) > 1 else "") + " + (1 | participant) + (1 | item), "
             "binomial, logit link (statsmodels BinomialBayesMixedGLM, variational Bayes; effects are posterior means "
             f"with 95 % intervals from a jackknife over groups of participants, against condition {conds[0]}" + (f" and SNR {snrs[0]:g} dB" if len(snrs) > 1 else "") + ")")
    return Analysis(manifest["design"], 0, 0, len(data), {}, effects, variance, cells, confusions, model, notes)


def _preference(manifest: dict[str, Any], data: pd.DataFrame, seed: int) -> Analysis:
    conds = [c["name"] for c in manifest["conditions"]]
    first, second = data["shown_first"].reset_index(drop=True), data["shown_second"].reset_index(drop=True)
    exog = pd.DataFrame({"shown first (position)": np.ones(len(data))})
    for c in conds[1:]:
        exog[f"strength[{c}]"] = (first == c).astype(float) - (second == c).astype(float)
    y = (data["chosen"].reset_index(drop=True) == first).astype(float).to_numpy()
    notes: list[str] = []
    effects, variance = binomial_glmm(y, exog, {"participant": data["participant"], "item": data["item"]}, notes)
    pairs = data.assign(pair=[" vs ".join(sorted((a, b), key=conds.index)) for a, b in zip(first, second)],
                        first_of_pair=[min((a, b), key=conds.index) for a, b in zip(first, second)])
    pairs = pairs.assign(chose_first_of_pair=(pairs["chosen"] == pairs["first_of_pair"]).astype(float))
    cells = bootstrap_means(pairs, ["pair"], "chose_first_of_pair", seed)
    model = ("chose the face shown first ~ position + strength(first) - strength(second) + (1 | participant) + "
             f"(1 | item), binomial, logit (Bradley-Terry; strength of {conds[0]} = 0; statsmodels "
             "BinomialBayesMixedGLM, variational Bayes, jackknife intervals). Cells: share of choices of the pair's first-named condition")
    return Analysis("preference", 0, 0, len(data), {}, effects, variance, cells, {}, model, notes)


def _mushra(manifest: dict[str, Any], data: pd.DataFrame, seed: int) -> Analysis:
    import statsmodels.formula.api as smf

    conds = [c["name"] for c in manifest["conditions"]]
    ref = next(c["name"] for c in manifest["conditions"] if c.get("reference"))
    base = next(c for c in conds if c != ref)
    code = {c: f"c{k}" for k, c in enumerate(conds)}
    frame = data.assign(rating=data["response"].astype(float), cond=data["condition"].map(code),
                        item=data["item"].astype(str))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        fit = smf.mixedlm(f"rating ~ C(cond, Treatment('{code[base]}'))", frame, groups=frame["participant"],
                          re_formula="1", vc_formula={"item": "0 + C(item)"}).fit(reml=True)
    names = {f"C(cond, Treatment('{code[base]}'))[T.{v}]": f"condition[{k}]" for k, v in code.items()}
    ci = fit.conf_int()
    effects = [Effect(names.get(str(n), "intercept" if n == "Intercept" else str(n)), float(fit.fe_params[n]),
                      float(fit.bse_fe[n]), float(ci.loc[n, 0]), float(ci.loc[n, 1])) for n in fit.fe_params.index]
    variance = {"participant sd (points)": float(np.sqrt(max(fit.cov_re.iloc[0, 0], 0.0))),
                "item sd (points)": float(np.sqrt(max(float(fit.vcomp[0]), 0.0))) if len(fit.vcomp) else 0.0,
                "residual sd (points)": float(np.sqrt(fit.scale))}
    cells = bootstrap_means(frame, ["condition"], "rating", seed)
    model = (f"rating ~ condition + (1 | participant) + item variance component, REML (statsmodels MixedLM; "
             f"against {base}; 95 % Wald intervals)")
    result = Analysis("mushra", 0, 0, len(data), {}, effects, variance, cells, {}, model)
    result.notes += _convergence_notes(caught, bool(fit.converged))
    return result


def analyse(manifest: dict[str, Any], tidy: pd.DataFrame, seed: int | None = None) -> Analysis:
    """The study's analysis (see the module docstring) of the tidy answers (coartic.perceive.tidy)."""
    from coartic.errors import UsageError

    seed = int(manifest["seed"]) if seed is None else seed
    excluded = exclusions(manifest, tidy)
    data = tidy[(tidy["kind"] == "stimulus") & ~tidy["participant"].isin(list(excluded))].reset_index(drop=True)
    if data.empty or data["participant"].nunique() < 2:
        raise UsageError(f"{data['participant'].nunique()} participant(s) with answers left after the exclusions: "
                         "the analysis needs at least two")
    design = manifest["design"]
    if design in ("intelligibility", "emotion"):
        result = _identification(manifest, data, seed)
    elif design == "preference":
        result = _preference(manifest, data, seed)
    else:
        result = _mushra(manifest, data, seed)
    people = tidy.drop_duplicates("participant")
    result.n_participants = int(data["participant"].nunique())
    result.n_simulated = int(people[people["participant"].isin(data["participant"])]["simulated"].sum())
    result.excluded = excluded
    if result.n_simulated:
        result.notes.append(f"{result.n_simulated} of the {result.n_participants} participants analysed are "
                            "simulated (coartic perceive simulate), not people")
    return result
