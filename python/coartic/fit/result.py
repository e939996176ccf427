"""What a fit produced: fitted values, parameter statistics, RMSE breakdowns, the parameter table.

Statistics follow the usual least-squares recipe (as lmfit reports them): with J the Jacobian of
the weighted residuals in the fitted (internal) coordinates at the optimum and s² = SSE/(n − m),
cov = s² (JᵀJ)⁺. Directions of JᵀJ with eigenvalues below ``rtol`` × the largest are not
identified by the data: the pseudo-inverse drops them and every parameter that loads on them is
flagged. Standard errors are carried to natural units by the transform's derivative (delta method).
Every free parameter at a bound gets a computed explanation (``coartic.estimation.bounds``): which bound,
where it comes from, whether the data pull past it, and what that means for the model.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic._version import __version__
from coartic.extras import require
from coartic.estimation.bounds import explain_bounds, summary_counts
from coartic.estimation.emotions import asymmetry_metadata, channel_metadata
from coartic.estimation.parameters import CATEGORY_TITLES, BoundNote, ParameterSet, psd_pseudo_inverse
from coartic.estimation.packing import Packing, shared_words
from coartic.estimation.pooling import PoolEstimate
from coartic.estimation.problem import ChannelProblem
from coartic.errors import UsageError
from coartic.fit.spec import FitSpec
from coartic.fit.multistart import MultiStart
from coartic.fit.staged import StageResult
from coartic.io.labelmap import resolve_label_map
from coartic.model import Utterance
from coartic.pauses import POSTURES_RECORD, RECORD_KEY as PAUSES_RECORD_KEY, speech_samples
from coartic.io.roles import ROLE_RECORD_KEY, resolve_role_map
from coartic.outputs import atomic_path, atomic_write_text
from coartic.table import PARAMETERS, ChannelSettings, ParameterTable

BAR_MM = 0.3  # the paper's bar: RMSE below 0.3 mm
GROUP_KEYS = ("vowel", "consonant", "repetition", "rate")
FloatArray = NDArray[np.float64]


@dataclass
class ParameterStats:
    names: list[str]  # 'phoneme.parameter' per free entry
    values: FloatArray  # natural units
    stderr: FloatArray  # natural units (NaN where not identified)
    corr: FloatArray  # [m, m]
    at_bound: list[str]  # names of free parameters sitting on a bound
    unidentified: list[str]  # names loading on directions the data do not determine
    s2: float  # residual variance (mm²)
    dof: int
    # why each parameter in at_bound is there, computed from the fit (coartic.estimation.bounds)
    bounds: dict[str, BoundNote] = field(default_factory=dict)
    # why each parameter in unidentified is not identified, and what to do (unidentified_reasons)
    unidentified_why: dict[str, str] = field(default_factory=dict)


def parameter_stats(problem: ChannelProblem, x: FloatArray, rtol: float = 1e-10) -> ParameterStats:
    pk = problem.packing
    names = pk.names()
    m = pk.n_free
    values = pk.natural(x)
    r = problem.residuals(x)
    n = problem.data.n_valid
    dof = max(n - m - problem.n_profiled, 1)  # the speakers' profiled a_s, b_s are fitted too
    s2 = float(r @ r) / dof
    if m == 0:
        e = np.zeros(0)
        return ParameterStats(names, values, e, np.zeros((0, 0)), [], [], s2, dof)
    jac = problem.jacobian(x)
    jtj = np.asarray((jac.T @ jac).toarray())
    inv, v, keep = psd_pseudo_inverse(jtj, rtol)
    cov = s2 * inv
    null_load = (v[:, ~keep] ** 2).sum(axis=1)
    unident = null_load > 0.5
    sd_x = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sd_x[unident] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd_x, sd_x)
    stderr = sd_x * pk.dvalue_dx(x)
    lo, hi = pk.bounds()
    width = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    near = (np.abs(x - lo) <= 1e-6 * width) | (np.abs(hi - x) <= 1e-6 * width)
    at_bound = [nm for nm, b in zip(names, near) if b]
    notes = explain_bounds(problem, x, at_bound, jac, r, s2, corr)
    why = unidentified_reasons(names, jtj, v[:, ~keep], unident)
    return ParameterStats(names, values, stderr, corr, at_bound, [nm for nm, b in zip(names, unident) if b], s2, dof,
                          notes, why)


# A Jacobian column whose norm is below this fraction of the largest one: the fit does not depend on it.
ZERO_COLUMN = 1e-8
UNIDENTIFIED_ADVICE = ("fix it (leave it out of [parameters] free, or an [[override]] with a fixed value), tie it to "
                       "a like phoneme's ([[tie]]), pull it towards one ([[shrink]] or a prior), or add recordings "
                       "that carry it")


def unidentified_reasons(names: Sequence[str], jtj: FloatArray, null: FloatArray,
                         unident: NDArray[np.bool_]) -> dict[str, str]:
    """Why each parameter the data leave undetermined is so, in the terms a user can act on: the
    data do not depend on it at all (a zero Jacobian column; every parameter of its phoneme so: no
    measured sample within the phoneme's reach), or only a combination with others is determined
    (the null direction it loads on names the partner); each with the alternatives."""
    col = np.sqrt(np.clip(np.diag(jtj), 0.0, None))
    zero = col <= ZERO_COLUMN * max(float(col.max(initial=0.0)), 1e-300)
    phoneme = [nm.rpartition(".")[0] for nm in names]
    out: dict[str, str] = {}
    for i in np.flatnonzero(unident):
        nm = names[int(i)]
        if zero[i]:
            all_zero = all(zero[j] for j in range(len(names)) if phoneme[j] == phoneme[i])
            what = (f"no measured sample lies within /{phoneme[i]}/'s reach (every one of its parameters has a zero "
                    "Jacobian column)" if all_zero and phoneme[i] else
                    "the fitted trajectories do not depend on it (a zero Jacobian column)")
        else:
            load = null @ null[i]  # how the others move with it along the undetermined directions
            load[i] = 0.0
            k = int(np.argmax(np.abs(load)))
            partner = names[k] if abs(load[k]) > 1e-6 else None
            what = ("only a combination with " + partner + " is determined by the data (they trade off exactly)"
                    if partner else "only a combination with other parameters is determined by the data")
        out[nm] = f"{what}: {UNIDENTIFIED_ADVICE}"
    return out


@dataclass
class ChannelFit:
    """The fit of one channel."""

    channel: str
    problem: ChannelProblem  # data, packing (with the optimum as base) and model options
    x: FloatArray
    params: FloatArray  # [n_phonemes, 10] natural units
    beta: float
    status: str
    message: str
    nfev: int
    wall_time: float
    stages: list[StageResult] = field(default_factory=list)
    stats: ParameterStats | None = None
    fitted: FloatArray | None = None  # model on every sample of the channel's corpus
    multistart: MultiStart | None = None  # the optima a multi-start found ([fit] starts > 1)
    pooling: PoolEstimate | None = None  # the pool's estimated sd and effective parameters ([parameters] pooled)

    @property
    def phonemes(self) -> tuple[str, ...]:
        return self.problem.data.phonemes

    @property
    def polished(self) -> list[str]:
        """Each stage, and each partial-pooling re-solve, that another local method finished
        (nlopt's failed L-BFGS polished by scipy), as "stage i: the engine's message" and "pooling
        re-solve k: …"; the console, fit report and summary.json say so."""
        return ([f"stage {i + 1}: {sr.engine.message}" for i, sr in enumerate(self.stages)
                 if sr.engine.polished and not sr.probe]
                + [f"pooling {note}" for note in (self.pooling.polished if self.pooling is not None else ())])

    @property
    def packing(self) -> Packing:
        return self.problem.packing

    @property
    def parameters(self) -> ParameterSet:
        """The fitted parameter set: values, free, bounds and standard errors (lmfit-style)."""
        st = self.stats
        pri = self.problem.priors
        if st is None:
            return ParameterSet.from_packing(self.channel, self.packing, priors=pri)
        return ParameterSet.from_packing(self.channel, self.packing, st.names, st.stderr, st.at_bound, st.unidentified,
                                         priors=pri, bound_notes=st.bounds)

    def residuals(self) -> FloatArray:
        """Model − measured on every sample (NaN where masked)."""
        d = self.problem.data
        assert self.fitted is not None
        return np.where(d.weights > 0, self.fitted - d.observed, np.nan)

    @property
    def rmse(self) -> float:
        r = self.residuals()
        return float(np.sqrt(np.nanmean(r**2)))

    def multistart_line(self) -> str:
        """The multi-start's one line (console, fit_report.txt). With partial pooling its optima are
        those of the search, at the pooling's starting sd; the empirical Bayes moves the sd after it
        and can end far from them (a stronger pool fits the training data less closely): said, with
        the figure it ended at, so the two data RMSEs printed are not read as one."""
        assert self.multistart is not None
        line = self.multistart.summary_line(self.problem.data.n_valid)
        if self.pooling is not None:
            line += (f"; these optima are the search's, at the pooling's starting sd: the empirical Bayes that "
                     f"followed ended at data RMSE {self.rmse:.4f} mm")
        return line

    def speech_rmse(self) -> tuple[float, int] | None:
        """RMSE and samples inside speech segments, every pause posture left out (as ``score`` and
        ``--validate`` give it beside all samples): on real recordings a long pause before or after
        the sentence, where lips move for breath, can outweigh the speech. None where no sample is
        in a pause."""
        d = self.problem.data
        speech = np.concatenate([speech_samples(u.labels, u.sample_segments()) for u in d.utterances])
        if speech.all():
            return None
        r2 = np.nan_to_num(self.residuals() ** 2)
        n = float(d.weights[speech].sum())
        return (float(np.sqrt(r2[speech].sum() / n)) if n else float("nan")), int(n)

    def utterance_sse(self) -> tuple[FloatArray, FloatArray]:
        """Per utterance: sum of squared residuals and number of valid samples."""
        d = self.problem.data
        r2 = np.nan_to_num(self.residuals() ** 2)
        starts = d.sample_offsets[:-1]
        return np.add.reduceat(r2, starts), np.add.reduceat(d.weights, starts)

    def rmse_by(self, keys: Sequence[str]) -> dict[tuple[str, ...], tuple[float, int]]:
        """RMSE over the utterances grouped by their meta values for ``keys``."""
        sse, cnt = self.utterance_sse()
        acc: dict[tuple[str, ...], list[float]] = {}
        for u, utt in enumerate(self.problem.data.utterances):
            k = tuple(str(utt.meta.get(key, "?")) for key in keys)
            a = acc.setdefault(k, [0.0, 0.0])
            a[0] += sse[u]
            a[1] += cnt[u]
        return {k: (float(np.sqrt(s / n)) if n else float("nan"), int(n)) for k, (s, n) in acc.items()}


def finish_channel(problem: ChannelProblem, x: FloatArray, status: str, message: str, wall: float,
                   stages: list[StageResult]) -> ChannelFit:
    params, beta = problem.packing.unpack(x)
    problem.packing.base, problem.packing.base_beta = params, beta
    fitted = problem.fitted(x)  # with speakers, each one's a_s + b_s·F: what its mapped table gives
    stats = parameter_stats(problem, x)
    return ChannelFit(problem.data.channel, problem, x, params, beta, status, message, problem.nfev, wall,
                      stages, stats, fitted)


class HeldOut(Protocol):
    """What the fit's files say of a held-out validation made above the fit (evaluation:
    ``coartic.evaluation.heldout.Validation``): the fit does not import what scores it."""

    def text_lines(self) -> list[str]:
        """fit_report.txt's last section (none: no split scored)."""
        ...

    def summary(self) -> dict[str, object] | None:
        """summary.json's ``"validation"`` (None: no split scored)."""
        ...


class Chosen(Protocol):
    """A ``[choose]`` setting chosen by cross-validation above the fit (evaluation:
    ``coartic.evaluation.choose.Choice``): what the fit's table, report and files need of it."""

    notes: list[str]

    def spec_for(self, spec: FitSpec, channel: str) -> FitSpec:
        """The spec the final fit of ``channel`` uses: the chosen value, no ``[choose]``."""
        ...

    def metadata(self) -> dict[str, Any]:
        """The table's ``"choice"`` metadata."""
        ...

    def text_lines(self) -> list[str]:
        """fit_report.txt's ``[[Choice]]`` section."""
        ...

    def save(self, out: str | Path) -> dict[str, Path]:
        """Its own files beside the fit's (choose.csv, choose.png)."""
        ...


@dataclass
class FitResult:
    """Every channel's fit, and what was asked for."""

    spec: FitSpec
    channels: dict[str, ChannelFit]
    started: str
    interrupted: bool = False
    notes: list[str] = field(default_factory=list)
    validation: HeldOut | None = None  # the held-out scores (coartic.evaluation.heldout.Validation)
    report: Path | None = None  # the HTML report, once written
    choice: Chosen | None = None  # the [choose] setting's CV curve and chosen values (coartic.evaluation.choose)
    # the utterances fitted (loaded, or as given with the spec's pauses): what a validation splits
    utterances: list[Utterance] = field(default_factory=list)

    # ---------------------------------------------------------------- tables
    def rmse_rows(self) -> list[dict[str, Any]]:
        """One row per channel and group (all, speech where the data hold pauses, each vowel,
        consonant, repetition, rate)."""
        rows: list[dict[str, Any]] = []
        for ch, fit in self.channels.items():
            n = int(fit.problem.data.n_valid)
            rows.append({"channel": ch, "group": "all", "value": "all", "rmse_mm": fit.rmse, "samples": n,
                         "below_bar": fit.rmse < BAR_MM})
            speech = fit.speech_rmse()
            if speech is not None:
                rows.append({"channel": ch, "group": "speech", "value": "pauses left out", "rmse_mm": speech[0],
                             "samples": speech[1], "below_bar": speech[0] < BAR_MM})
            for key in GROUP_KEYS:
                rows.extend(_group_rows(ch, fit, key))
        return rows

    def speech_rmse(self) -> dict[str, float]:
        """Per channel, the RMSE on speech alone (``ChannelFit.speech_rmse``); channels whose data
        hold no pause are left out."""
        return {ch: sp[0] for ch, fit in self.channels.items() if (sp := fit.speech_rmse()) is not None}

    def worst(self, group: str) -> dict[str, tuple[str, float]]:
        """Per channel, the group value with the largest RMSE."""
        out: dict[str, tuple[str, float]] = {}
        for ch, fit in self.channels.items():
            rows = _group_rows(ch, fit, group)
            if rows:
                r = max(rows, key=lambda r: r["rmse_mm"])
                out[ch] = (r["value"], r["rmse_mm"])
        return out

    def channel_settings(self, channel: str) -> ChannelSettings:
        """The settings ``channel`` was fitted with: the spec's, a ``[choose]``n model option
        (plateau_fraction) the chosen value, β the fitted one (what the table and report show)."""
        fitted_with = self.spec if self.choice is None else self.choice.spec_for(self.spec, channel)
        return fitted_with.channel_settings(channel, self.channels[channel].beta, self.channels[channel].problem.phonemes)

    def table(self) -> ParameterTable:
        """The fitted parameter table (coartic.table/1) with the fit's metadata."""
        s = self.spec
        t = ParameterTable(variant=s.model.variant, source=f"fit of {s.path}")
        for ch, fit in self.channels.items():
            t.channels[ch] = self.channel_settings(ch)
            lo, hi = fit.packing.lower[:, 0].min(), fit.packing.upper[:, 0].max()
            t.bounds[ch] = {"target": (float(lo), float(hi))}
            # (with per-speaker targets, the shared values and the population targets: ChannelProblem)
            t.set_from_matrix(ch, list(fit.problem.phonemes), fit.problem.table_matrix(fit.params), fit.beta)
        t.metadata = {
            "method": f"least squares ({s.engine.name}{', staged' if s.staging.enabled else ''})",
            "corpus": ("trials given in Python" if s.corpus is None
                       else str(s.corpus.manifest or [str(f) for f in s.corpus.files])),
            "spec": str(s.path),
            "date": self.started,
            "software": f"coartic {__version__}",
            "rmse": {ch: f.rmse for ch, f in self.channels.items()},
            "status": {ch: f.status for ch, f in self.channels.items()},
            "interrupted": self.interrupted,
        }
        if s.groups.speakers != "none":
            # speaker s is a + b·F, F with the reference speaker's targets, or with "targets" its own
            # targets (metadata) and the table's the mean over the speakers (docs/FITTING.md)
            per = {ch: f.problem.speaker_metadata(f.x) for ch, f in self.channels.items()}
            t.metadata["speakers"] = {"mode": s.groups.speakers, "column": s.groups.speaker_column,
                                      **{key: {ch: m[key] for ch, m in per.items()} for key in ("coefficients", "targets")
                                         if any(key in m for m in per.values())}}
        if s.groups.emotions != "none":
            # each emotion's own targets, its deviations from the neutral ones (the table's) with their
            # Laplace sd, and the deviations' prior scale τ the data gave (coartic.estimation.emotions)
            t.metadata["emotions"] = {"mode": s.groups.emotions, "column": s.groups.emotion_column,
                                      "neutral": s.groups.neutral_emotion,
                                      "channels": {ch: channel_metadata(f.problem, f.x)
                                                   for ch, f in self.channels.items()}}
            if self.channels:  # the corner asymmetries, measured on the markers (not a channel of the model)
                utts = next(iter(self.channels.values())).problem.data.utterances
                asym = asymmetry_metadata(utts, s.groups.emotion_column, s.groups.neutral_emotion)
                if asym:
                    t.metadata["emotions"]["asymmetry"] = asym
        if s.priors.shrinks:  # the shrinkage the fit had (sd as the spec gives it; a [choose]n one in "choice")
            # the members it was applied to: those present in a fitted channel's data
            applied = {(grp.key, m) for f in self.channels.values() for grp in f.problem.shrink_groups
                       for m in grp.phonemes}
            t.metadata["shrinkage"] = [{"key": g.key, "phonemes": [p for p in g.phonemes if (g.key, p) in applied],
                                        "parameters": list(g.parameters),
                                        "sd": g.sd, "scale": "log" if g.log else "natural",
                                        "prior_noise": s.priors.prior_noise,
                                        "channels": list(g.channels) if g.channels else "all"} for g in s.priors.shrinks]
        pooling = {ch: f.pooling.as_dict() for ch, f in self.channels.items() if f.pooling is not None}
        if pooling:  # the pool's estimated sd per family, σ and the effective parameters (build_problem reads it back)
            t.metadata["pooling"] = pooling
        if self.choice is not None:
            t.metadata["choice"] = self.choice.metadata()
        if s.model.pauses == "postures":  # whoever evaluates the table gives pauses the same postures
            t.metadata[PAUSES_RECORD_KEY] = dict(POSTURES_RECORD)
        # the map the corpus labels went through, so trajectories/animate/score read labels alike
        resolve_label_map(None if s.corpus is None else s.corpus.label_map).record_in(t)
        # and the sensors' roles and axes, so that score reads alike
        if s.corpus is not None and s.corpus.role_map is not None:
            t.metadata[ROLE_RECORD_KEY] = resolve_role_map(s.corpus.role_map).to_record()
        return t

    def parameter_rows(self) -> list[dict[str, Any]]:
        """``parameters.csv``: every channel's parameter set (value, stderr, free, bounds, flags)."""
        rows = []
        for fit in self.channels.values():
            ms = fit.multistart
            for row in fit.parameters.rows():
                if ms is not None:  # how far the other optima put it: a large spread, a weakly determined value
                    name = "beta" if row["parameter"] == "beta" else f"{row['phoneme']}.{row['parameter']}"
                    row["spread_between_optima"] = ms.spread.get(name, 0.0 if name in ms.names else "")
                    # its range inside the best optimum: the data leave it free (same fit within the noise)
                    row["not_identified_range"] = ms.best.unidentified.get(name, 0.0 if name in ms.names else "")
                rows.append(row)
            if fit.pooling is not None and rows:
                rows += pooling_rows(fit.channel, fit.pooling, list(rows[0]))
        return rows

    def to_dataframe(self, what: str = "parameters") -> Any:
        """pandas DataFrame of ``parameters.csv`` (``what="parameters"``: one row per channel,
        phoneme and parameter with value, standard error, free, tie, bounds and flags; NaN where a
        number does not apply) or of ``rmse.csv`` (``"rmse"``: per channel and group)."""
        require("dataframe", "to_dataframe()")
        import pandas as pd

        if what == "rmse":
            return pd.DataFrame(self.rmse_rows(), columns=["channel", "group", "value", "rmse_mm", "samples",
                                                           "below_bar"])
        if what != "parameters":
            raise UsageError(f"to_dataframe({what!r}): expected 'parameters' or 'rmse'")
        df = pd.DataFrame(self.parameter_rows())
        for col in ("value", "stderr", "lower", "upper", "prior_mean", "prior_sd"):
            if col in df:  # "" (no standard error, no prior) is a missing number
                df[col] = pd.to_numeric(df[col].replace("", float("nan")), errors="raise").astype("float64")
        return df

    def report_text(self, max_corr: int = 10) -> str:
        """An lmfit-like fit report: statistics, warnings, strongest correlations, per channel."""
        lines = [f"[[Fit]] {self.spec.name} ({self.spec.path})", f"    engine: {self.spec.engine.name}, "
                 f"staged: {self.spec.staging.enabled}, variant: {self.spec.model.variant}, started {self.started}"]
        if self.interrupted:
            lines.append("    INTERRUPTED by the user: the results below are the best points reached")
        lines += [f"    note: {n}" for n in self.notes]
        if self.choice is not None:
            lines += self.choice.text_lines()
        for ch, fit in self.channels.items():
            st = fit.stats
            assert st is not None
            lines += ["", f"[[Channel {ch}]]", f"    status: {fit.status} ({fit.message})",
                      f"    evaluations: {fit.nfev}, wall time {fit.wall_time:.1f} s",
                      f"    samples: {fit.problem.data.n_valid}, free parameters: {len(st.names)}, dof {st.dof}",
                      f"    RMSE: {fit.rmse:.4f} mm ({'below' if fit.rmse < BAR_MM else 'ABOVE'} the {BAR_MM} mm bar)"]
            if fit.problem.offsets is not None:
                b = fit.problem.utterance_offsets(fit.x)
                with_b = float(np.sqrt(np.nanmean((fit.residuals() + b[fit.problem.offsets.utt]) ** 2)))
                lines.append(f"    per-utterance offsets ([model] offsets = {self.spec.groups.offsets!r}): sd {b.std():.4f} mm, "
                             f"range {b.min():+.3f} to {b.max():+.3f} mm; RMSE with them {with_b:.4f} mm")
            for spk, (a_s, b_s) in fit.problem.speaker_coefficients(fit.x).items():
                lines.append(f"    speaker {spk} ([model] speakers = {self.spec.groups.speakers!r}): "
                             f"offset a = {a_s:+.4f} mm, scale b = {b_s:.4f}")
            if fit.multistart is not None:
                lines += multistart_lines(fit.multistart, fit.multistart_line())
            objective = "penalised objective" if fit.problem.penalised else "SSE"
            for s_i, sr in enumerate(fit.stages):
                what = "probe stage" if sr.probe else "stage"
                lines.append(f"    {what} {s_i + 1}: {sr.n_free} free ({', '.join(sr.parameters)}): "
                             f"{objective} {sr.sse_start:.4g} -> {sr.sse_end:.4g} [{sr.engine.status}]"
                             # a stage that did not converge says why, in the engine's own words
                             + ("" if (sr.engine.status == "converged" and not sr.engine.polished) or sr.probe
                                else f": {sr.engine.message}"))
            lines += shrinkage_lines(fit.problem, fit.x)
            if fit.pooling is not None:
                lines += pooling_lines(fit.pooling)
            if st.at_bound:
                lines.append(f"    warning: {len(st.at_bound)} parameter(s) at a bound: {', '.join(st.at_bound)}")
                lines.append(f"        why (computed from the fit, [[At a bound]] below): {summary_counts(st.bounds)}")
            if st.unidentified:
                lines.append(f"    warning: {len(st.unidentified)} parameter(s) not identified by the data "
                             f"(no standard error): {', '.join(st.unidentified)}")
                lines += [f"        {nm}: {st.unidentified_why[nm]}" for nm in st.unidentified if nm in st.unidentified_why]
            lines.append("    [[Variables]]")
            for prm in fit.parameters.values():
                if not prm.free:
                    continue
                bn = prm.bound_note
                flag = (f" (at {bn.side} bound: {bn.category})" if bn else " (at bound)") if prm.at_bound else ""
                err = f"+/- {prm.stderr:.4g}" if np.isfinite(prm.stderr) else "+/- (not identified)"
                prior = "" if prm.prior is None else (
                    f"  prior {'log-' if prm.prior.log else ''}N({prm.prior.mean:.4g}, {prm.prior.sd:.4g})")
                shared = (f"  ({shared_words(prm.shared_by, fit.phonemes, prm.parameter)}: {prm.name} names its "
                          "carrier)" if prm.shared_by else "")
                lines.append(f"        {prm.name:<16} {prm.value:>12.5g} {err}{flag}"
                             f"  [{prm.lower:.4g}, {prm.upper:.4g}]{prior}{shared}")
            if st.bounds:
                lines.append("    [[At a bound]] (each free parameter at a bound: which bound, where it comes from, why)")
                for bn in st.bounds.values():
                    who = (f", the value of {shared_words(bn.shared_by, fit.phonemes, bn.parameter)}"
                           if bn.shared_by else "")
                    lines += [f"        {bn.name} = {bn.value:.5g} at its {bn.side} bound {bn.bound:.5g} ({bn.source}{who})",
                              f"            {CATEGORY_TITLES[bn.category]}: {bn.explanation}",
                              f"            reading: {bn.reading}"]
            c = np.triu(np.nan_to_num(st.corr), 1)
            order = np.argsort(-np.abs(c), axis=None)[:max_corr]
            strong = [(st.names[i], st.names[j], c[i, j]) for i, j in zip(*np.unravel_index(order, c.shape))
                      if abs(c[i, j]) > 0.5]
            if strong:
                lines.append("    [[Correlations]] (|r| > 0.5, strongest first)")
                lines += [f"        C({a}, {b}) = {r:+.3f}" for a, b, r in strong]
        if self.validation is not None:
            lines += self.validation.text_lines()
        return "\n".join(lines) + "\n"

    # ---------------------------------------------------------------- output
    def save(self, out: str | Path) -> dict[str, Path]:
        """Write table.json, table.csv, rmse.csv, parameters.csv, fit_report.txt, fitted.npz."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"table": out / "table.json", "table_csv": out / "table.csv", "rmse": out / "rmse.csv",
                 "parameters": out / "parameters.csv", "report_text": out / "fit_report.txt",
                 "fitted": out / "fitted.npz", "summary": out / "summary.json"}
        # each file whole (written aside, fsync, renamed); the directory as a whole: coartic.outputs.OutputDir
        if not self.channels:
            atomic_write_text(out / "fit_report.txt", self.report_text())
            return {"report_text": out / "fit_report.txt"}
        table = self.table()
        table.save(paths["table"])
        atomic_write_text(paths["table_csv"], table.to_csv())
        _write_csv(paths["rmse"], self.rmse_rows())
        _write_csv(paths["parameters"], self.parameter_rows())
        atomic_write_text(paths["report_text"], self.report_text())
        arrays: dict[str, Any] = {f"{ch}_fitted": f.fitted for ch, f in self.channels.items()}
        arrays |= {f"{ch}_observed": np.where(f.problem.data.weights > 0, f.problem.data.observed, np.nan)
                   for ch, f in self.channels.items()}
        with atomic_path(paths["fitted"]) as tmp:
            np.savez_compressed(tmp, **arrays)
        summary: dict[str, Any] = {"spec": str(self.spec.path), "interrupted": self.interrupted, "started": self.started,
                   "notes": list(self.notes),  # the small-data warnings among them (coartic.fit.guards)
                   "channels": {ch: {"rmse_mm": f.rmse,
                                     # every pause posture left out (None: no sample in a pause)
                                     "rmse_speech_mm": None if (sp := f.speech_rmse()) is None else sp[0],
                                     "status": f.status, "message": f.message, "nfev": f.nfev,
                                     "wall_time_s": f.wall_time, "at_bound": f.stats.at_bound if f.stats else [],
                                     # why each is at its bound (coartic.estimation.bounds.BoundNote fields)
                                     "at_bound_explained": [b.as_dict() for b in f.stats.bounds.values()]
                                     if f.stats else [],
                                     "unidentified": f.stats.unidentified if f.stats else [],
                                     "unidentified_explained": f.stats.unidentified_why if f.stats else {},
                                     # the objective the engine minimised: the SSE plus the penalty rows when
                                     # "penalised" (sse_start/sse_end: its old names, kept for old readers)
                                     "penalised": f.problem.penalised,
                                     "stages": [{"parameters": list(sr.parameters), "n_free": sr.n_free,
                                                 "objective_start": sr.sse_start, "objective_end": sr.sse_end,
                                                 "sse_start": sr.sse_start, "sse_end": sr.sse_end,
                                                 "status": sr.engine.status, "probe": sr.probe,
                                                 "message": sr.engine.message,
                                                 "polished": sr.engine.polished} for sr in f.stages],
                                     "multistart": None if f.multistart is None
                                     # a pooled fit's optima are the search's, at the pooling's starting sd
                                     else f.multistart.as_dict(f.problem.data.n_valid)
                                     | {"optima_before_pooling": f.pooling is not None},
                                     "pooling": None if f.pooling is None else f.pooling.as_dict()}
                                for ch, f in self.channels.items()}}
        if self.validation is not None and (held := self.validation.summary()) is not None:
            summary["validation"] = held
        atomic_write_text(paths["summary"], json.dumps(summary, indent=2))
        if self.choice is not None:
            paths |= self.choice.save(out)
        return paths


def multistart_lines(ms: MultiStart, summary: str) -> list[str]:
    """fit_report.txt: the multi-start's optima (SSE, RMSE, the starts that reached each, held-out
    RMSE where validation scored them), the parameters the data leave free inside an optimum, and
    those that differ most between the optima."""
    hops = f", then {ms.hops} polishing restarts from the best of starts {ms.chains}" if ms.hops else ""
    how = (f"probe: {ms.probe} evaluations per stage from {ms.probed} starts, continued: starts {ms.continued}{hops}"
           if ms.probed else f"starts {ms.continued} fitted in full, no probe needed")
    objective = f"penalised objective (SSE + {ms.penalty})" if ms.penalty else "objective (SSE)"
    lines = [f"    multi-start: {summary}",
             f"        {ms.nfev} evaluations in {ms.wall_time:.1f} s ({ms.workers} worker(s)); {how}; optima ranked "
             f"by the {objective}, data RMSE as measured"]
    for k, o in enumerate(ms.optima):
        held = "".join(f"; held out {sp}: {v:.4f} mm" for sp, v in o.heldout_rmse.items())
        lines.append(f"        optimum {k + 1}: data RMSE {o.rmse:.4f} mm, {'penalised ' if ms.penalty else ''}"
                     f"objective {o.objective:.6g}, "
                     f"reached from {o.hits} start(s) {sorted(set(o.starts))} ({len(o.members)} end point(s)) "
                     f"[{o.status}]{held}")
        if o.unidentified:
            top = sorted(o.unidentified.items(), key=lambda kv: -kv[1])
            lines.append(f"            not identified (same fit within the noise, these parameters differ; range): "
                         + ", ".join(f"{nm} {d:.4g}" for nm, d in top))
    if ms.best_found_once:
        lines.append("        warning: the best optimum was reached from one start only: more starts may find a better one")
    if ms.worse_than_start0:
        lines.append(f"        note: {ms.worse_than_start0}")
    if ms.spread:
        top = sorted(ms.spread.items(), key=lambda kv: -kv[1])[:5]
        lines.append("        largest differences from the best among the distinct optima: "
                     + ", ".join(f"{nm} {d:.4g}" for nm, d in top))
    return lines


def shrinkage_lines(problem: ChannelProblem, x: FloatArray) -> list[str]:
    """fit_report.txt: per [[shrink]] group, the class mean and each member's deviation in sd."""
    sh = problem.shrinkage
    if not sh.size:
        return []
    params, _ = problem.packing.unpack(x)
    z = sh.z(params)
    lines = [f"    [[Shrinkage]] (prior_noise {sh.noise:g} mm; deviation from the class mean in sd)"]
    i = 0
    for g in sh.groups:
        v = params[list(g.rows), g.column]
        mean = float(np.exp(np.mean(np.log(v)))) if g.log else float(np.mean(v))
        devs = " ".join(f"{p} {d:+.2f}" for p, d in zip(g.phonemes, z[i:i + len(g.rows)]))
        lines.append(f"        {g.key} {g.parameter}: sd {g.sd:g}{' (log)' if g.log else ''}, class "
                     f"{'geometric ' if g.log else ''}mean {mean:.4g}: {devs}")
        i += len(g.rows)
    return lines


def pooling_lines(est: PoolEstimate) -> list[str]:
    """fit_report.txt: each pooled family's estimated sd and what it amounts to."""
    lines = [f"    [[Pooling]] (sd estimated from the data: Laplace evidence, empirical Bayes; noise sd "
             f"{est.sigma:.4g} mm; {est.rounds} re-solve(s){'' if est.settled else ', NOT settled'}"
             f"{f': it went round a cycle of {est.cycle} rounds, the highest evidence kept' if est.cycle else ''})",
             f"        data weighed as {est.temper:.3g} x the samples (1 / the residuals' autocorrelation time: "
             f"n_eff = {est.temper * est.n_valid:.0f} of {est.n_valid})",
             f"        effective parameters: {est.effective:.2f} of {est.n_free} free (trace of the hat matrix)"]
    lines += [f"        {est.line(f)}" for f in est.tau]
    lines += [f"        polished: {note}" for note in est.polished]  # another local method finished a re-solve
    if len(est.candidates) > 1:  # empirical Bayes from several of the multi-start's optima (fit_pooled_best)
        lines.append(f"        estimated from each of {len(est.candidates)} optima of the multi-start, the highest evidence "
                     f"kept (optimum {est.chosen + 1}; data weight {est.temper:.3g} for all):")
        lines += [f"          {'*' if k == est.chosen else ' '} optimum {k + 1}: objective {c['objective_start']:.6g} at the "
                  f"starting sd -> log evidence {c['log_evidence']:.3f}, RMSE {c['rmse_mm']:.4f} mm, "
                  f"{c['effective_parameters']:.2f} effective parameters" for k, c in enumerate(est.candidates)]
    return lines


def pooling_rows(channel: str, est: PoolEstimate, columns: list[str]) -> list[dict[str, Any]]:
    """parameters.csv: a row per pooled family (parameter \"sd(family)\", its estimated sd; lower
    and upper the search box) and one \"effective_parameters\" row (value: the trace of the hat
    matrix, upper: the free parameters)."""
    from coartic.estimation.pooling import TAU_BOUNDS

    blank = dict.fromkeys(columns, "")
    out = [{**blank, "channel": channel, "phoneme": "*", "parameter": f"sd({f})", "value": t, "free": True,
            "tied_to": "", "lower": TAU_BOUNDS[0], "upper": TAU_BOUNDS[1], "at_bound": f in est.at_bound,
            "unidentified": False, "bound_side": est.at_bound.get(f, ""),
            "bound_explanation": est.line(f) if f in est.at_bound else ""} for f, t in est.tau.items()]
    out.append({**blank, "channel": channel, "phoneme": "*", "parameter": "effective_parameters",
                "value": est.effective, "free": False, "tied_to": "", "lower": 0.0, "upper": float(est.n_free),
                "at_bound": False, "unidentified": False})
    return out


def now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _group_rows(channel: str, fit: ChannelFit, key: str) -> list[dict[str, Any]]:
    """``rmse_rows``' rows of one group (vowel, consonant, ...), in natural order; none where the
    utterances do not carry that key."""
    if not any(key in u.meta for u in fit.problem.data.utterances):
        return []
    return [{"channel": channel, "group": key, "value": val, "rmse_mm": rm, "samples": cnt, "below_bar": rm < BAR_MM}
            for (val,), (rm, cnt) in sorted(fit.rmse_by((key,)).items(), key=lambda kv: _natural(kv[0][0]))]


def _natural(v: str) -> tuple[int, float | str]:
    try:
        return (0, float(v))
    except ValueError:
        return (1, v)


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    f = io.StringIO(newline="")
    if rows:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write_text(path, f.getvalue())
