"""The least-squares problem of one channel (``ChannelProblem``) and its one constructor
(``build_problem``).

This is the contract that the engines, the staged fit, the result statistics and the MCMC sampler
(``coartic.mcmc``) share. ``ChannelProblem`` puts together the pieces of this package:

- the data (``coartic.estimation.data.ChannelData``: the channel's utterances as the core's corpus);
- the packing (``coartic.estimation.packing.Packing``): which entries of ``params[n_phonemes, 10]``
  (and ``beta``) are free, their bounds, and the transform to the internal vector ``x`` the engines
  see (``log`` for alpha, theta_bw, theta_fw, psi and beta, identity for the others, whose boxes go
  to the engine as bounds, so k_R = 1 is reachable);
- per-utterance offsets (``offsets.Offsets``) and speakers (``speakers.Speakers``,
  ``speakers.SpeakerRows``), profiled out or expanded into rows;
- priors and shrinkage as extra residual rows (``penalties.Penalty``, ``penalties.Shrinkage``).

It gives the residuals ``r = sqrt(w) (F(x) - y)``, their sparse Jacobian with respect to ``x`` (the
Rust core's exact derivatives, free columns only, chain rule through the transform), the SSE and its
gradient, and a tracker of the best point seen (so Ctrl-C can keep it).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from coartic import _core
from coartic.estimation.data import ChannelData
from coartic.estimation.emotions import EmotionPrior, emotion_names, own_parameters, table_emotion_meta
from coartic.estimation.emotions import dynamics_groups as emotion_dynamics_groups
from coartic.estimation.emotions import shrink_groups as emotion_shrink_groups
from coartic.estimation.offsets import Offsets
from coartic.estimation.packing import Packing, Prior, moving
from coartic.estimation.parameters import ParameterSet
from coartic.estimation.penalties import Penalty, PenaltyRows, ShrinkGroup, Shrinkage, shrink_groups
from coartic.estimation.pooling import TAU_START, Pool, pool_from_settings, with_groups
from coartic.estimation.settings import EstimationSettings
from coartic.estimation.speakers import SpeakerRows, Speakers, expand_speaker_targets, table_speaker_meta
from coartic.estimation.target_prior import segment_stats, target_priors
from coartic.errors import SpecError
from coartic.jacobian import JacobianBuffer
from coartic.model import Utterance, channel_options, core_error, model_options
from coartic.table import PARAMETERS, ParameterTable, TableError

FloatArray = NDArray[np.float64]


def stack_rows(blocks: Sequence[sp.csr_matrix]) -> sp.csr_matrix:
    """CSR matrices of one width stacked row-wise: the arrays ``sp.vstack(blocks, format="csr")``
    gives (data, indices and row pointers concatenated in order, entry for entry), without its checks
    and index-type choices at every step, which took as long as the stacking (a pooled fit stacks its
    data's, priors' and pool's rows at each of its thousands of Jacobians)."""
    indptr = [np.zeros(1, dtype=np.int64)]
    n = 0
    for b in blocks:
        indptr.append(b.indptr[1:].astype(np.int64) + n)
        n += int(b.indptr[-1])
    shape = (sum(b.shape[0] for b in blocks), blocks[0].shape[1])
    return sp.csr_matrix((np.concatenate([b.data for b in blocks]), np.concatenate([b.indices for b in blocks]),
                          np.concatenate(indptr)), shape=shape)


class ChannelProblem:
    """Residuals, Jacobian and SSE of one channel as functions of the internal vector x.

    Every evaluation updates ``best_x`` / ``best_sse`` (the lowest finite SSE seen), so an
    interrupted or failed engine can still return the best point. Invalid parameters (the core
    raises ValueError) give non-finite residuals, which the engines treat as a rejected step.
    """

    def __init__(self, data: ChannelData, packing: Packing, options: _core.ModelOptions,
                 priors: Mapping[str, Prior] | None = None, prior_noise: float = 1.0,
                 offset_sd: float | None = None, speakers: str = "none",
                 speaker_column: str = "speaker", shrink: Sequence[ShrinkGroup] = (),
                 speaker_rows: SpeakerRows | None = None, emotion_prior: EmotionPrior | None = None,
                 pool: Pool | None = None) -> None:
        self.data = data
        # Speaker-specific target offset/scale (spec [model] speakers), profiled out like offsets.
        self.speaker_mode, self.speaker_column = speakers, speaker_column
        self.speakers = None if speakers in ("none", "targets") else Speakers(data, speakers, speaker_column)
        # [model] speakers = "targets": the rows of the (expanded) matrix per speaker (expand_speaker_targets)
        self.speaker_rows = speaker_rows
        emotive = speaker_rows is not None and speaker_rows.factor == "emotions"
        if (speakers == "targets" or emotive) != (speaker_rows is not None):
            raise SpecError("[model] speakers = \"targets\" needs the per-speaker rows (build_problem makes them)")
        if emotion_prior is not None and not emotive:
            raise SpecError("an emotion prior needs the per-emotion rows ([model] emotions = \"targets\")")
        if self.speakers is not None and offset_sd is not None:
            raise SpecError("[model] speakers and [model] offsets cannot be combined yet: choose one")
        self.packing = packing
        self.options = options
        # Per-utterance offsets (spec [model] offsets): None none, inf free, else their sd τ (mm).
        self.offset_sd = offset_sd
        self.offsets = None if offset_sd is None else Offsets(
            data, 0.0 if np.isinf(offset_sd) else (prior_noise / offset_sd) ** 2)
        # Gaussian priors (spec [parameters.prior]) on free entries, as extra residual rows.
        self.priors: dict[str, Prior] = dict(priors or {})
        self.prior_noise = float(prior_noise)
        self.penalty = Penalty(packing, self.priors, self.prior_noise)
        # Shrinkage toward class means (spec [[shrink]]), likewise extra rows after the priors', and the
        # emotions' deviations toward the neutral targets (None: not yet estimated, or no emotions).
        self.spec_shrink_groups = list(shrink)
        self.emotion_prior = emotion_prior
        self.shrink_groups = self.spec_shrink_groups + (
            [] if emotion_prior is None or speaker_rows is None
            else emotion_shrink_groups(speaker_rows, emotion_prior, prior_noise))
        self.shrinkage = Shrinkage(packing, self.shrink_groups, self.prior_noise)
        # Families of rows whose sd is estimated ([parameters] pooled, target_prior = "estimated";
        # coartic.estimation.pooling), weighed against the estimated noise: rows after the shrinkage's.
        self.pool = pool
        self.pool_rows: list[PenaltyRows] = [] if pool is None else pool.rows(packing)
        self.penalties: list[PenaltyRows] = [self.penalty, self.shrinkage, *self.pool_rows]
        self.sqrt_w = np.sqrt(data.weights)
        self.nfev = 0
        self.njev = 0
        self.best_x: FloatArray = packing.pack()
        self.best_sse = np.inf
        self.last_error: str | None = None
        self.monitor: Callable[[int, float], None] | None = None  # (evaluations, best SSE) hook
        # One set of Jacobian arrays, refilled at every step: a fit allocates nothing per step.
        self._jacobian = JacobianBuffer(data.corpus)
        # The free columns' part of the core's Jacobian pattern (``_free_pattern``), built at the first step.
        self._pattern: tuple[Packing, NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], FloatArray] | None = None

    # --- natural-unit evaluation -------------------------------------------------------------
    def evaluate(self, params: FloatArray, beta: float) -> FloatArray:
        return np.asarray(_core.evaluate(self.data.corpus, params, beta, self.options))

    def full_jacobian(self, params: FloatArray, beta: float) -> tuple[FloatArray, sp.csr_matrix]:
        """Model values and the core's CSR Jacobian over every column (n_phonemes*10 + 1); both are
        overwritten by the next call, so copy what you keep."""
        return self._jacobian.compute(params, beta, self.options)

    def explain(self, err: ValueError, params: FloatArray) -> str:
        """A model error at ``params`` for people: the phoneme by name and, when the refused value
        is the one the spec gave (not an engine's step), the spec key it came from, e.g.
        ``[parameters.start] alpha = nan for phoneme 'a' on channel LLO: the value is not finite``."""
        e = core_error(err, self.data.channel, self.packing.phonemes)
        pk = self.packing
        if (pk.origins is None or not isinstance(e.phoneme, str) or e.parameter not in PARAMETERS
                or e.phoneme not in pk.phonemes):
            return str(e)
        i, k = pk.phonemes.index(e.phoneme), PARAMETERS.index(str(e.parameter))
        v, b = float(params[i, k]), float(pk.base[i, k])
        if not pk.origins[i, k] or not (v == b or (np.isnan(v) and np.isnan(b))):
            return str(e)
        section, _, name = str(pk.origins[i, k]).rpartition(".")
        return (f"[{section}] {name} = {v!r} for phoneme {e.phoneme!r} on channel {self.data.channel}: "
                f"the value {e.reason}")

    # --- internal-x interface for engines ----------------------------------------------------
    def _track(self, x: FloatArray, sse: float) -> None:
        if np.isfinite(sse) and sse < self.best_sse:
            self.best_sse = float(sse)
            self.best_x = np.array(x, dtype=np.float64)
        if self.monitor is not None:
            self.monitor(self.nfev, self.best_sse)

    def residuals(self, x: FloatArray) -> FloatArray:
        self.nfev += 1
        params, beta = self.packing.unpack(x)
        try:
            f = self.evaluate(params, beta)
        except ValueError as e:
            self.last_error = self.explain(e, params)
            return np.full(self.n_residuals, np.nan)
        r = (self.sqrt_w * (f - self.data.observed) if self.speakers is None
             else self.speakers.residuals(f))
        if self.offsets is not None:
            r = self.offsets.residuals(r)
        for pen in self.penalties:
            if pen.size:
                r = np.concatenate([r, pen.residuals(x)])
        self._track(x, float(r @ r))
        return r

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """d r / d x: the core's Jacobian, free columns only, scaled by the transform and sqrt(w)."""
        self.njev += 1
        params, beta = self.packing.unpack(x)
        try:
            f, jac = self.full_jacobian(params, beta)
        except ValueError as e:
            self.last_error = self.explain(e, params)
            return sp.csr_matrix((self.n_residuals, self.packing.n_free))
        tmap = self.packing.column_map()
        if tmap is None:
            # The entries of the free columns, in the core's order (what jac[:, free_columns] gives), each
            # times its row scale sqrt(w) and its column's d(value)/dx
            sel, indices, indptr, row_scale = self._free_pattern(jac)
            j = sp.csr_matrix((jac.data[sel] * (row_scale * self.packing.dvalue_dx(x)[indices]), indices.copy(),
                               indptr.copy()), shape=(jac.shape[0], self.packing.n_free))
        else:
            j = sp.csr_matrix(jac @ tmap)
            # Row scale sqrt(w) and column scale d(value)/dx applied to the stored entries in place.
            rows = np.repeat(np.arange(j.shape[0]), np.diff(j.indptr))
            j.data *= self.sqrt_w[rows] * self.packing.dvalue_dx(x)[j.indices]
        if self.speakers is not None:
            j = self.speakers.jacobian(np.asarray(f, dtype=np.float64), j)
        if self.offsets is not None:
            j = self.offsets.jacobian(j)
        blocks = [pen.jacobian(x) for pen in self.penalties if pen.size]
        return stack_rows([j, *blocks]) if blocks else j

    def _free_pattern(self, jac: sp.csr_matrix) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                                                         FloatArray]:
        """Which stored entries of the core's Jacobian fall in a free column (their positions, in the
        order SciPy's ``jac[:, free_columns]`` keeps them), their columns among the free ones, the rows'
        pointers and each entry's sqrt(w): the pattern is the corpus's, fixed for a packing, so it is
        worked out at its first step and not at every one: SciPy's column indexing and the row index
        at every step took 4.7 of the 29 CPU-s of fit/ema_german.toml's fit, twice the core's Jacobian.
        The matrix is the one ``jac[:, free_columns]`` gave, entry for entry and bit for bit."""
        if self._pattern is None or self._pattern[0] is not self.packing:
            position = np.full(jac.shape[1], -1, dtype=np.int64)
            position[self.packing.free_columns] = np.arange(self.packing.n_free)
            column = position[jac.indices]
            sel = np.flatnonzero(column >= 0)
            rows = np.repeat(np.arange(jac.shape[0]), np.diff(jac.indptr))[sel]
            indptr = np.zeros(jac.shape[0] + 1, dtype=np.int64)
            np.cumsum(np.bincount(rows, minlength=jac.shape[0]), out=indptr[1:])
            self._pattern = (self.packing, sel, column[sel], indptr, self.sqrt_w[rows])
        return self._pattern[1:]

    def sse(self, x: FloatArray) -> float:
        r = self.residuals(x)
        return float(r @ r) if np.all(np.isfinite(r)) else np.inf

    @property
    def n_residuals(self) -> int:
        """Rows of the residual vector: samples, then offset rows (random effects), then priors, then
        shrinkage, then the pool's rows."""
        return (self.data.corpus.n_samples + (self.offsets.extra_rows if self.offsets else 0)
                + sum(pen.size for pen in self.penalties))

    @property
    def pool_size(self) -> int:
        """The last rows of the residual vector: the pool's (its families' priors)."""
        return sum(pen.size for pen in self.pool_rows)

    def fitted(self, x: FloatArray) -> FloatArray:
        """The model on every sample at ``x`` as the fit reports it (with [model] speakers each
        speaker's a_s + b_s·F): what the data RMSE is measured on. Not counted as an evaluation."""
        params, beta = self.packing.unpack(x)
        f = self.evaluate(params, beta)
        if self.speakers is not None:
            a, b = self.speakers.coefficients(f)
            f = a[self.speakers.spk] + b[self.speakers.spk] * f
        return f

    def data_rmse(self, x: FloatArray) -> float:
        """The data RMSE at ``x`` (mm): model − measured over the valid samples, as measured (no
        penalty rows, no per-utterance offsets). The objective the engines minimise adds the
        penalty rows (priors, shrinkage, offsets' random effects): ``penalised`` says whether."""
        r = (self.fitted(x) - self.data.observed)[self.data.weights > 0]
        return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")

    @property
    def penalised(self) -> bool:
        """The objective has rows besides the data's (priors, shrinkage, offsets): it is not the SSE."""
        return self.n_residuals > self.data.corpus.n_samples

    def utterance_offsets(self, x: FloatArray) -> FloatArray:
        """The fitted per-utterance offsets b_u (mm) at x (zeros without offsets)."""
        if self.offsets is None:
            return np.zeros(len(self.data.utterances))
        params, beta = self.packing.unpack(x)
        return self.offsets.offsets(self.sqrt_w * (self.evaluate(params, beta) - self.data.observed))

    @property
    def n_profiled(self) -> int:
        """Parameters profiled out of x that still cost degrees of freedom: each non-reference
        speaker's a_s (and b_s with offset_scale). AIC/BIC and the residual dof count them."""
        if self.speakers is None:
            return 0
        return (len(self.speakers.names) - 1) * (2 if self.speakers.mode == "offset_scale" else 1)

    @property
    def phonemes(self) -> tuple[str, ...]:
        """The channel's phonemes as the table has them (the data's rows, or with per-speaker
        targets the phonemes those rows expand)."""
        return self.data.phonemes if self.speaker_rows is None else self.speaker_rows.base

    def table_matrix(self, params: FloatArray) -> FloatArray:
        """The table's matrix (rows ``phonemes``) for a matrix of the problem's rows: itself, or with
        per-speaker targets the shared values and the population targets (mean over the speakers)."""
        return params if self.speaker_rows is None else self.speaker_rows.collapse(params)

    def speaker_metadata(self, x: FloatArray) -> dict[str, Any]:
        """This channel's part of a table's ``metadata.speakers``: each speaker's (a_s, b_s) and, with
        per-speaker targets, its own targets ({} without [model] speakers)."""
        if self.speaker_mode == "none":
            return {}
        if self.speaker_rows is None:
            return {"coefficients": {n: {"offset_mm": a, "scale": b} for n, (a, b) in self.speaker_coefficients(x).items()}}
        params, _ = self.packing.unpack(x)
        return {"coefficients": {n: {"offset_mm": 0.0, "scale": 1.0} for n in self.speaker_rows.names},
                "targets": self.speaker_rows.targets(params)}

    def speaker_coefficients(self, x: FloatArray) -> dict[str, tuple[float, float]]:
        """The fitted (a_s offset mm, b_s scale) per speaker at x ({} without [model] speakers or with
        per-speaker targets)."""
        if self.speakers is None:
            return {}
        params, beta = self.packing.unpack(x)
        a, b = self.speakers.coefficients(self.evaluate(params, beta))
        return {n: (float(a[i]), float(b[i])) for i, n in enumerate(self.speakers.names)}

    def sse_gradient(self, x: FloatArray) -> tuple[float, FloatArray]:
        """SSE and its gradient in x, from the core's fused SSE+gradient (no Jacobian formed); with
        offsets or speakers, 2 Jᵀr from the profiled residuals and their exact Jacobian."""
        if self.offsets is not None or self.speakers is not None:
            r = self.residuals(x)
            if not np.all(np.isfinite(r)):
                return np.inf, np.zeros(self.packing.n_free)
            return float(r @ r), 2.0 * np.asarray(self.jacobian(x).T @ r).ravel()
        self.nfev += 1
        params, beta = self.packing.unpack(x)
        try:
            sse, grad, dbeta = _core.sse_gradient(self.data.corpus, params, beta, self.options,
                                                  self.data.observed, self.data.weights)
        except ValueError as e:
            self.last_error = self.explain(e, params)
            return np.inf, np.zeros(self.packing.n_free)
        full = np.append(np.asarray(grad), dbeta)
        tmap = self.packing.column_map()
        g = (full[self.packing.free_columns] if tmap is None else tmap.T @ full) * self.packing.dvalue_dx(x)
        for pen in self.penalties:
            if pen.size:
                ps, pg = pen.gradient(x)
                sse, g = sse + ps, g + pg
        if np.isfinite(sse):
            self._track(x, float(sse))
        return float(sse), g

    def sse_batch(self, xs: FloatArray) -> FloatArray:
        """SSE for many x at once (rows), through the core's parallel batch path; +inf if invalid."""
        if self.speakers is not None:  # profiled per speaker: through the residuals, point by point
            return np.array([self.sse(x) for x in np.atleast_2d(xs)])
        params, betas = self.packing.unpack_batch(xs)
        if self.offsets is not None:
            sse, sums = _core.residual_sums_batch(self.data.corpus, params, betas, self.options,
                                                  self.data.observed, self.data.weights)
            out = self.offsets.profiled_sse(np.asarray(sse), np.asarray(sums))
        else:
            out = np.asarray(_core.sse_batch(self.data.corpus, params, betas, self.options,
                                             self.data.observed, self.data.weights))
        for pen in self.penalties:
            if pen.size:
                out = out + pen.squares_batch(xs, params)
        return out

    def with_packing(self, packing: Packing) -> ChannelProblem:
        """A problem on the same data with another free set (staged fits); best point carried."""
        p = ChannelProblem(self.data, packing, self.options, self.priors, self.prior_noise, self.offset_sd,
                           self.speaker_mode, self.speaker_column, self.spec_shrink_groups, self.speaker_rows,
                           self.emotion_prior, self.pool)
        p.nfev, p.njev, p.monitor = self.nfev, self.njev, self.monitor
        return p

    def with_pool(self, pool: Pool) -> ChannelProblem:
        """The same problem with the pool's families at other τ and σ (the same packing, its base
        values as they are)."""
        p = ChannelProblem(self.data, self.packing, self.options, self.priors, self.prior_noise, self.offset_sd,
                           self.speaker_mode, self.speaker_column, self.spec_shrink_groups, self.speaker_rows,
                           self.emotion_prior, pool)
        p.nfev, p.njev, p.monitor = self.nfev, self.njev, self.monitor
        return p

    def with_emotion_prior(self, prior: EmotionPrior) -> ChannelProblem:
        """The same problem with the emotions' deviation prior (``[model] emotions``), best point reset
        (its pool kept: an emotion's own dynamics, [parameters] pooled)."""
        p = ChannelProblem(self.data, self.packing, self.options, self.priors, self.prior_noise, self.offset_sd,
                           self.speaker_mode, self.speaker_column, self.spec_shrink_groups, self.speaker_rows, prior,
                           self.pool)
        p.monitor = self.monitor
        return p


def build_problem(settings: EstimationSettings, utterances: Sequence[Utterance], channel: str,
                  table: ParameterTable | None = None, *, start: tuple[FloatArray, float] | None = None,
                  phonemes: Sequence[str] | None = None) -> ChannelProblem:
    """The channel's problem from the settings (``coartic.estimation.settings``: a fit spec's,
    ``FitSpec.estimation_settings()``, or built in Python) and loaded utterances: the one constructor
    that least squares (and through it validation, ``[choose]``, compare and batch) and MCMC use.

    Without ``table`` it is the problem a fit solves: the model options from the settings the fitted
    table will record (``ModelSettings.channel_settings``), values from ``start`` (a matrix and β,
    e.g. a ``[parameters] start_table``'s) or the settings' starts and the data's targets. With
    ``table`` (a fitted table) it is that table's problem, as MCMC samples around it: the options
    from the table's own channel settings (the model it was fitted with), its values as the start,
    with ``[model] speakers = "targets"`` each speaker's own targets from its metadata; a table of
    another variant than the settings', or fitted with other speakers, is refused (``TableError``
    naming the table). The free set, bounds, ties, priors and shrinkage are the settings' either way
    (the ``[choose]``-able values as given: apply a table's chosen value to the settings first).
    """
    model, groups, source = settings.model, settings.groups, settings.source
    where = table.source if table is not None and table.source else "the table"
    if table is not None:
        if channel not in table.channels:
            raise TableError(f"{where}: the table has no channel {channel!r} (channels: {', '.join(table.channels)})")
        if table.variant != model.variant:
            raise TableError(f"{where}: a table of the {table.variant!r} model, but {settings.where} [model] variant = "
                             f"{model.variant!r}: use the spec the table was fitted with")
    data = ChannelData.build(utterances, channel, phonemes)
    if table is None:
        # Options from the settings the fitted table will record (channel_settings): one source.
        options = channel_options(model.variant, model.channel_settings(channel, phonemes=data.phonemes))
    else:
        options = model_options(table, channel)
        start = table.to_matrix(channel, data.phonemes)
    ps = ParameterSet.from_settings(settings, data, start)
    offset_sd = groups.offset_sd
    shrink = shrink_groups(settings.priors.shrinks, source, channel, data.phonemes, moving(ps.free, ps.ties))
    rows = None
    meta = None if table is None else table_speaker_meta(groups, settings.where, table)
    data_start = start is None and "target" not in settings.parameters.given
    if groups.speakers == "targets":
        if meta is None:
            data, ps, rows = expand_speaker_targets(settings, data, ps, data_start=data_start)
        else:
            own = (meta.get("targets") or {}).get(channel)
            if not own:
                raise TableError(f"{where}: metadata.speakers has no targets for channel {channel}")
            data, ps, rows = expand_speaker_targets(settings, data, ps, data_start=False, names=tuple(own),
                                                    start_targets=own)
        shrink = rows.shrink_groups(source, shrink)
    prior = None
    dynamics: list[ShrinkGroup] = []
    if groups.emotions != "none":
        own = own_parameters(groups.emotions)
        if table is None:
            names = emotion_names(data.utterances, groups.emotion_column, groups.neutral_emotion)
            data, ps, rows = expand_speaker_targets(settings, data, ps, data_start=data_start, names=names,
                                                    factor="emotions", own=own)
        else:
            emo = table_emotion_meta(groups, settings.where, table).get("channels", {}).get(channel)
            if not emo:
                raise TableError(f"{where}: metadata.emotions has no channel {channel}")
            data, ps, rows = expand_speaker_targets(
                settings, data, ps, data_start=False, names=tuple(emo["targets"]), start_targets=emo["targets"],
                factor="emotions", own=own, start_own={q: d["values"] for q, d in (emo.get("dynamics") or {}).items()})
            prior = EmotionPrior.from_dict(emo) if "tau" in emo else None
        shrink = rows.shrink_groups(source, shrink)
        dynamics = emotion_dynamics_groups(rows, ps.free, TAU_START)
    elif table is not None:
        # a table fitted with emotions needs the settings that have them
        table_emotion_meta(groups, settings.where, table)
    pool = None
    pri = settings.priors
    start_pool = None if table is None else table_pool(table, channel)
    if pri.pooled or pri.target_prior == "estimated":
        # (with per-speaker or per-emotion rows: every row's target toward its own segment mean, the
        # dynamics tied across a phoneme's rows counted once, an emotion's own dynamics not at all:
        # they are pooled toward neutral below)
        free_now = moving(ps.free, ps.ties)
        means = target_priors(1.0, data.utterances, channel, data.phonemes, ps.free, ps.priors)
        stats = segment_stats(data.utterances, channel)
        pool = pool_from_settings(settings, channel, data.phonemes, free_now, means, start_pool,
                                  frozenset(f for f, _ in ps.ties)
                                  | {g.rows[1] * len(PARAMETERS) + g.column for g in dynamics},
                                  {k: stats[k.rpartition(".")[0]][1] for k in means})
    if dynamics:
        # [model] emotions = "targets+dynamics": each emotion's dynamics pooled toward neutral, the
        # strength per parameter and emotion estimated (the same empirical Bayes as [parameters] pooled)
        pool = with_groups(pool, dynamics, pri.prior_noise, start_pool)
    return ChannelProblem(data, ps.packing(), options, ps.priors, pri.prior_noise, offset_sd, groups.speakers,
                          groups.speaker_column, shrink, rows, prior, pool)


def table_pool(table: ParameterTable, channel: str) -> Pool | None:
    """The τ and σ a fitted table records for ``channel`` (``metadata.pooling``) as a Pool holding
    only those scales (``pool_from_settings`` starts from them), or None."""
    rec = (table.metadata.get("pooling") or {}).get(channel)
    if not isinstance(rec, dict):
        return None
    fams = rec.get("families") or {}
    return Pool(tau={f: float(v["sd"]) for f, v in fams.items()}, sigma=float(rec["sigma_mm"]),
                temper=float(rec.get("data_weight", 1.0)))
