"""The log-posterior of one channel's free parameters, evaluated for all walkers in one Rust call.

Sampling coordinates are the least-squares problem's own internal vector x
(``coartic.estimation.packing.Packing``: log for α, θ_bw, θ_fw, ψ and β, natural units for T, c, k_R, σ,
δ), plus ``log_sigma_n`` when the noise level is sampled. The prior (docs/MCMC.md):

* uniform in x inside the packing's bounds, so log-uniform for the scale parameters; a side left
  open by the bounds (α, θ, ψ have (0, ∞) by default) is closed with ``PRIOR_RANGE`` so that the
  prior is proper;
* times optional Gaussian priors on natural values, keyed ``"phoneme.parameter"`` (or ``"beta"``);
* times the fit spec's shrinkage toward class means (``[[shrink]]``: ``coartic.estimation.penalties.Shrinkage``,
  the least-squares rows divided by prior_noise, so −½ Σ z²);
* ``-inf`` outside the support (those walkers are not even sent to the core);
* times the fit's partial pooling (``[parameters] pooled``, ``target_prior = "estimated"``:
  ``coartic.estimation.pooling``): each family's hierarchical prior −½ Σ dev²/τ_f² − rank_f log τ_f
  (the target prior: −½ Σ dev²/v − ½ Σ log v, v = τ² + each centre's variance),
  with τ_f sampled as ``log sd(family)`` (log-uniform on ``TAU_BOUNDS``) or held at the fit's
  estimate; the likelihood then counts the samples as the fit's evidence did, n_eff = w n (the
  log-likelihood times w, the data weight the fit recorded: autocorrelated residuals hold fewer
  independent samples than there are samples).

The likelihood is Gaussian with noise level σ_n per valid sample: either fixed (a number, e.g. the
least-squares residual RMS) or sampled as ``log_sigma_n`` with a uniform prior on
``LOG_SIGMA_RANGE`` (a Jeffreys prior on σ_n). Optionally each utterance also carries its own
constant offset b_u ~ N(0, τ²), integrated out in closed form: a recorded channel is measured
from a rest reference estimated once per utterance, so its error is shared by all of that
utterance's samples. τ (``offset_sd``) is fixed, or sampled with a uniform prior on
``OFFSET_RANGE`` (uniform on a group-level standard deviation, as Gelman 2006 recommends).
With S_u = Σ w r and W_u = Σ w over utterance u, and the SSE Σ w r²:

    log L = −½ (SSE − Σ_u τ² S_u² / (σ² + τ² W_u)) / σ² − ½ Σ_u log(1 + τ² W_u / σ²) − N log σ − (N/2) log 2π

With the fit spec's ``[model] speakers`` (``coartic.estimation.speakers.Speakers``), speaker s's samples
are predicted as a_s + b_s·F: every speaker but the reference (a = 0, b = 1, as in least squares)
adds the coordinates ``speaker_offset:s`` (a_s, mm; prior N(0, SPEAKER_OFFSET_SD²)) and, with
``offset_scale``, ``log speaker_scale:s`` (prior log b_s ~ N(0, SPEAKER_LOG_SCALE_SD²)). The
mapping is the least-squares problem's own (``Speakers.predict``): at the least-squares (a_s, b_s)
the SSE is the fit's cost.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from coartic.mcmc.errors import McmcError
from coartic.estimation.pooling import TARGET_FAMILY

if TYPE_CHECKING:
    from coartic import _core
    from coartic.estimation.data import ChannelData
    from coartic.estimation.packing import Packing
    from coartic.estimation.penalties import ShrinkGroup
    from coartic.estimation.pooling import Pool
    from coartic.estimation.speakers import Speakers

FloatArray = NDArray[np.float64]
BatchFn = Callable[..., FloatArray]
# A prior as LogPosterior takes it: (mean, sd) on the natural value, or (mean, sd, True) on its
# logarithm (mean: the median), as the fit spec's [parameters.prior] with scale = "log" gives it.
PriorTerm = tuple[float, float] | tuple[float, float, bool]

# Finite prior ranges (natural units) for sides the bounds leave open.
PRIOR_RANGE: dict[str, tuple[float, float]] = {
    "target": (-1e3, 1e3),
    "alpha": (1e-2, 1e2),
    "theta_bw": (1.0, 1e4),
    "theta_fw": (1.0, 1e4),
    "psi": (1.0, 1e5),
    "beta": (1e-3, 20.0),
}
LOG_SIGMA_RANGE = (math.log(1e-4), math.log(1e2))
NOISE_NAME = "log_sigma_n"
OFFSET_RANGE = (0.0, 5.0)  # mm
OFFSET_NAME = "offset_sd"
# Priors of the speakers' offset a_s (mm) and log scale log b_s; their sampling support is ±10 sd.
SPEAKER_OFFSET_SD = 10.0
SPEAKER_LOG_SCALE_SD = 0.5
SPEAKER_OFFSET = "speaker_offset:"
SPEAKER_SCALE = "speaker_scale:"


class LogPosterior:
    """Vectorised log-posterior: ``lp(x)`` with x shaped (walkers, dim) returns (walkers,).

    All in-support walkers go to one ``sse_batch`` call (``residual_sums_batch`` with per-utterance
    offsets; the Rust core: parallel, GIL released). The batch functions default to
    ``coartic._core``'s and may be replaced by functions of the same signature, which the speed
    benchmark does to compare evaluators on one posterior.

    ``noise``: σ_n fixed (mm), or None to sample it. ``offset_sd``: τ of the per-utterance offsets
    fixed (mm; 0 for none), or None to sample it.
    """

    def __init__(
        self,
        data: ChannelData,
        packing: Packing,
        options: _core.ModelOptions,
        noise: float | None = None,
        priors: Mapping[str, PriorTerm] | None = None,
        sse_batch: BatchFn | None = None,
        evaluate_batch: BatchFn | None = None,
        offset_sd: float | None = 0.0,
        residual_sums_batch: Callable[..., tuple[FloatArray, FloatArray]] | None = None,
        shrinkage: Sequence[ShrinkGroup] = (),
        speakers: Speakers | None = None,
        speaker_start: Mapping[str, tuple[float, float]] | None = None,
        pool: Pool | None = None,
        sample_pool: bool = True,
    ) -> None:
        from coartic import _core
        from coartic.estimation.penalties import Shrinkage

        self.sse_batch = sse_batch or _core.sse_batch
        self.evaluate_batch = evaluate_batch or _core.evaluate_batch
        self.residual_sums_batch = residual_sums_batch or _core.residual_sums_batch
        self.data = data
        self.packing = packing
        self.options = options
        self.channel = data.channel
        self.n_data = int(np.count_nonzero(data.weights > 0))
        if self.n_data == 0:
            raise McmcError(f"channel {data.channel}: no valid sample to sample a posterior from")
        if packing.n_free == 0:
            raise McmcError(f"channel {data.channel}: no free parameter to sample")
        self.noise = None if noise is None else float(noise)
        if self.noise is not None and not (self.noise > 0 and math.isfinite(self.noise)):
            raise McmcError(f"channel {data.channel}: a fixed noise level sigma_n must be positive and finite, got {noise}")
        self.offset_sd = None if offset_sd is None else float(offset_sd)
        if self.offset_sd is not None and not (self.offset_sd >= 0 and math.isfinite(self.offset_sd)):
            raise McmcError(f"channel {data.channel}: a fixed offset_sd must be >= 0 and finite, got {offset_sd}")
        self.utterance_weight = np.array([data.weights[data.utterance_samples(k)].sum() for k in range(len(data.utterances))])

        free_names = packing.names()
        # (mean, sd) on the natural value, or (mean, sd, True) on its logarithm (mean: the median),
        # as the fit spec's [parameters.prior] with scale = "log" gives them
        self.priors: dict[str, tuple[Any, ...]] = {
            k: (float(v[0]), float(v[1])) + ((True,) if len(v) > 2 and v[2] else ()) for k, v in (priors or {}).items()}
        for key, (mu, sd, *_) in self.priors.items():
            if key not in free_names:
                raise McmcError(
                    f"Gaussian prior on {key!r}: not a free parameter of this {data.channel} posterior "
                    f"(free: {', '.join(free_names)})"
                )
            if not (sd > 0 and math.isfinite(sd) and math.isfinite(mu)):
                raise McmcError(f"Gaussian prior on {key!r}: needs a finite mean and a positive sd, got ({mu}, {sd})")
        for key, v in self.priors.items():
            if len(v) > 2 and not v[0] > 0:
                raise McmcError(f"Gaussian prior on log {key!r}: needs a positive median, got {v[0]}")
        # the same penalty as least squares, on the unpacked matrix (members outside this packing's
        # free set count in the class mean at their fitted values)
        self.shrinkage = Shrinkage(packing, shrinkage, 1.0)

        lo, hi = (np.array(b, dtype=np.float64) for b in packing.bounds())
        log = packing.log_mask
        for j, (phoneme, parameter) in enumerate(packing.entries()):
            fallback = PRIOR_RANGE.get(parameter)
            where = f"{data.channel} {free_names[j]}"
            if fallback is not None:
                f_lo, f_hi = (math.log(v) for v in fallback) if log[j] else fallback
                lo[j] = lo[j] if np.isfinite(lo[j]) else f_lo
                hi[j] = hi[j] if np.isfinite(hi[j]) else f_hi
            if not (np.isfinite(lo[j]) and np.isfinite(hi[j])):
                raise McmcError(f"{where}: the prior needs finite bounds, got [{lo[j]}, {hi[j]}]")
            if not lo[j] < hi[j]:
                raise McmcError(f"{where}: empty prior support [{lo[j]}, {hi[j]}]")
        # speakers ([model] speakers): every non-reference speaker with data here gets a_s (and log b_s)
        self.speakers = speakers
        self._spk_a = np.zeros(0)
        self._spk_b = np.ones(0)
        spk_names: list[str] = []
        spk_log: list[bool] = []
        spk_lo: list[float] = []
        spk_hi: list[float] = []
        self._spk_a_cols: list[tuple[int, int]] = []  # (coordinate, speaker index)
        self._spk_b_cols: list[tuple[int, int]] = []
        if speakers is not None:
            k = len(speakers.names)
            start = dict(speaker_start or {})
            self._spk_a = np.array([float(start.get(n, (0.0, 1.0))[0]) for n in speakers.names])
            self._spk_b = np.array([float(start.get(n, (0.0, 1.0))[1]) for n in speakers.names])
            self._spk_a[0], self._spk_b[0] = 0.0, 1.0
            present = np.bincount(speakers.spk, weights=data.weights, minlength=k) > 0
            col = packing.n_free
            for i, n in enumerate(speakers.names):
                if i == 0 or not present[i]:
                    continue  # the reference is fixed; a speaker without data here has nothing to sample
                spk_names.append(SPEAKER_OFFSET + n)
                spk_log.append(False)
                spk_lo.append(-10 * SPEAKER_OFFSET_SD)
                spk_hi.append(10 * SPEAKER_OFFSET_SD)
                self._spk_a_cols.append((col, i))
                self.priors[SPEAKER_OFFSET + n] = (0.0, SPEAKER_OFFSET_SD)
                col += 1
                if speakers.mode == "offset_scale":
                    spk_names.append(SPEAKER_SCALE + n)
                    spk_log.append(True)
                    spk_lo.append(-10 * SPEAKER_LOG_SCALE_SD)
                    spk_hi.append(10 * SPEAKER_LOG_SCALE_SD)
                    self._spk_b_cols.append((col, i))
                    self.priors[SPEAKER_SCALE + n] = (1.0, SPEAKER_LOG_SCALE_SD, True)
                    col += 1
        self._spk_names = spk_names
        self._prior_index = np.array([(free_names + spk_names).index(k) for k in self.priors], dtype=np.int64)
        self._prior_log = np.array([len(v) > 2 for v in self.priors.values()], dtype=bool)
        self._prior_mu = np.array([math.log(v[0]) if len(v) > 2 else v[0] for v in self.priors.values()],
                                  dtype=np.float64)
        self._prior_sd = np.array([v[1] for v in self.priors.values()], dtype=np.float64)
        lo = np.append(lo, spk_lo)
        hi = np.append(hi, spk_hi)
        log = np.append(np.asarray(log, dtype=bool), spk_log).astype(bool)
        self._n_model = packing.n_free + len(spk_names)
        # sampled noise terms after the model's coordinates: (coordinate, natural name, range, is log)
        self._extras = [(NOISE_NAME, "sigma_n", LOG_SIGMA_RANGE, True)] if self.noise is None else []
        if self.offset_sd is None:
            self._extras.append((OFFSET_NAME, OFFSET_NAME, OFFSET_RANGE, False))
        # the pool's families: τ sampled (after the noise terms) or held at the fit's estimate
        from coartic.estimation.pooling import TAU_BOUNDS

        self.pool = pool
        self.temper = 1.0 if pool is None else float(pool.temper)
        # the target prior's centre variances, at the fit's noise (held, as the centres are)
        self._centre_var = np.zeros(0) if pool is None else np.array(list(pool.centre_variance(pool.noise**2).values()))
        self._pool_cols: list[int | None] = []
        for fam in () if pool is None else pool.families:
            if sample_pool:
                self._pool_cols.append(self._n_model + len(self._extras))
                self._extras.append((f"log sd({fam})", f"sd({fam})", (math.log(TAU_BOUNDS[0]), math.log(TAU_BOUNDS[1])), True))
            else:
                self._pool_cols.append(None)
        self.lower = np.append(lo, [e[2][0] for e in self._extras])
        self.upper = np.append(hi, [e[2][1] for e in self._extras])
        # coordinates that are logarithms of their natural value
        self._exp = np.append(np.asarray(log, dtype=bool), [e[3] for e in self._extras]).astype(bool)
        extra_names = [e[0] for e in self._extras]
        self._sigma_col = self._n_model + extra_names.index(NOISE_NAME) if NOISE_NAME in extra_names else None
        self._offset_col = self._n_model + extra_names.index(OFFSET_NAME) if OFFSET_NAME in extra_names else None
        self.n_calls = 0

    # --- coordinates ---------------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.lower.size)

    @property
    def n_free(self) -> int:
        return int(self.packing.n_free)

    @property
    def names(self) -> list[str]:
        """Natural-unit name of every coordinate ('p.k_r', 'beta', 'speaker_offset:s02', 'speaker_scale:s02',
        and 'sigma_n', 'offset_sd' when sampled)."""
        return self.packing.names() + self._spk_names + [e[1] for e in self._extras]

    @property
    def coordinates(self) -> list[str]:
        """Name of every sampling coordinate ('log p.theta_bw' for log-sampled ones)."""
        out = [f"log {n}" if lg else n for n, lg in zip(self.packing.names(), self.packing.log_mask)]
        out += [f"log {n}" if n.startswith(SPEAKER_SCALE) else n for n in self._spk_names]
        return out + [e[0] for e in self._extras]

    def to_natural(self, x: FloatArray) -> FloatArray:
        """Sampling coordinates → natural units (σ_n instead of log σ_n)."""
        x = np.asarray(x, dtype=np.float64)
        out = x.copy()
        out[..., self._exp] = np.exp(x[..., self._exp])
        return out

    def from_natural(self, values: FloatArray) -> FloatArray:
        values = np.asarray(values, dtype=np.float64)
        out = values.copy()
        with np.errstate(divide="ignore", invalid="ignore"):
            out[..., self._exp] = np.log(values[..., self._exp])
        return out

    def in_support(self, x: FloatArray) -> NDArray[np.bool_]:
        x = np.atleast_2d(x)
        return np.asarray(np.all((x >= self.lower) & (x <= self.upper), axis=1), dtype=np.bool_)

    def matrices(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Parameter matrices (walkers, n_phonemes, 10) and β values (walkers,) for x (walkers, dim)."""
        params, betas = self.packing.unpack_batch(np.atleast_2d(x)[:, : self.n_free])
        return np.ascontiguousarray(params), np.ascontiguousarray(betas)

    # --- the posterior -------------------------------------------------------------------------
    def sigma_n(self, x: FloatArray) -> FloatArray:
        x = np.atleast_2d(x)
        return np.full(x.shape[0], self.noise) if self._sigma_col is None else np.exp(x[:, self._sigma_col])

    def offsets(self, x: FloatArray) -> FloatArray:
        """τ, the standard deviation of the per-utterance offsets, per walker (mm)."""
        x = np.atleast_2d(x)
        return np.full(x.shape[0], self.offset_sd) if self._offset_col is None else x[:, self._offset_col].copy()

    def log_prior(self, x: FloatArray) -> FloatArray:
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        lp = np.where(self.in_support(x), 0.0, -np.inf)
        if self._prior_index.size:
            nat = self.to_natural(x)[:, self._prior_index]
            if self._prior_log.any():
                with np.errstate(divide="ignore", invalid="ignore"):
                    nat = np.where(self._prior_log, np.log(np.where(self._prior_log, nat, 1.0)), nat)
            lp = lp - 0.5 * np.sum(((nat - self._prior_mu) / self._prior_sd) ** 2, axis=1)
        if self.shrinkage.size:
            params, _ = self.matrices(x)
            with np.errstate(invalid="ignore"):
                z = self.shrinkage.z(params)
            lp = lp - 0.5 * np.sum(np.where(np.isfinite(z), z, np.inf) ** 2, axis=1)
        if self.pool is not None:
            params, _ = self.matrices(x)
            for fam, col, dev in zip(self.pool.families, self._pool_cols, self.pool.deviations(params, self.data.phonemes)):
                log_tau = np.full(x.shape[0], math.log(self.pool.tau[fam])) if col is None else x[:, col]
                dev = np.where(np.isfinite(dev), dev, np.inf)
                if fam == TARGET_FAMILY:  # each row's variance τ² + its centre's (``Pool.centre_variance``)
                    var = np.exp(2.0 * log_tau)[:, None] + self._centre_var[None, :]
                    with np.errstate(invalid="ignore"):
                        lp = lp - 0.5 * np.sum(dev**2 / var + np.log(var), axis=-1)
                    continue
                with np.errstate(invalid="ignore"):
                    q = np.sum(dev**2, axis=-1)
                lp = lp - 0.5 * q * np.exp(-2.0 * log_tau) - self.pool.rank(fam) * log_tau
        return lp

    def speaker_coefficients(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(a, b) per walker and speaker (walkers, n_speakers): sampled, or held at their start."""
        x = np.atleast_2d(x)
        a = np.broadcast_to(self._spk_a, (x.shape[0], self._spk_a.size)).copy()
        b = np.broadcast_to(self._spk_b, (x.shape[0], self._spk_b.size)).copy()
        for col, i in self._spk_a_cols:
            a[:, i] = x[:, col]
        for col, i in self._spk_b_cols:
            b[:, i] = np.exp(x[:, col])
        return a, b

    def _speaker_residuals(self, x: FloatArray) -> FloatArray:
        """y − (a_s + b_s·F) per walker and sample (NaN rows where the core rejects the walker)."""
        assert self.speakers is not None
        params, betas = self.matrices(x)
        self.n_calls += 1
        d = self.data
        try:
            f = np.asarray(self.evaluate_batch(d.corpus, params, betas, self.options), dtype=np.float64)
        except ValueError:  # some walker is invalid: find which, one by one
            f = np.full((params.shape[0], d.observed.size), np.nan)
            for w in range(params.shape[0]):
                try:
                    f[w] = np.asarray(self.evaluate_batch(d.corpus, params[w:w + 1], betas[w:w + 1], self.options))[0]
                except ValueError:
                    pass
        return d.observed - self.speakers.predict(f, *self.speaker_coefficients(x))

    def sse(self, x: FloatArray) -> FloatArray:
        """Weighted sum of squared residuals per walker (+inf where the core rejects the parameters)."""
        d = self.data
        if self.speakers is not None:
            r = self._speaker_residuals(x)
            out = np.sum(d.weights * np.where(d.weights > 0, r, 0.0) ** 2, axis=1)
            return np.where(np.isfinite(out), out, np.inf)
        params, betas = self.matrices(x)
        self.n_calls += 1
        return np.asarray(self.sse_batch(d.corpus, params, betas, self.options, d.observed, d.weights), dtype=np.float64)

    def residual_sums(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """SSE per walker and Σ w r per walker and utterance (+inf / NaN where the core rejects)."""
        d = self.data
        if self.speakers is not None:
            r = np.where(d.weights > 0, self._speaker_residuals(x), 0.0)
            sse = np.sum(d.weights * r**2, axis=1)
            sums = np.add.reduceat(d.weights * r, d.sample_offsets[:-1], axis=1) if r.shape[1] else r[:, :0]
            return np.where(np.isfinite(sse), sse, np.inf), sums
        params, betas = self.matrices(x)
        self.n_calls += 1
        sse, sums = self.residual_sums_batch(d.corpus, params, betas, self.options, d.observed, d.weights)
        return np.asarray(sse, dtype=np.float64), np.asarray(sums, dtype=np.float64)

    def log_likelihood(self, sse: FloatArray, sigma: FloatArray, sums: FloatArray | None = None,
                       tau: FloatArray | None = None) -> FloatArray:
        """Gaussian log-likelihood; with per-utterance residual sums and offset sd τ, the offsets
        integrated out (module docstring)."""
        quad = sse
        log_det = 0.0
        if sums is not None and tau is not None:
            s2, t2 = (sigma**2)[:, None], (tau**2)[:, None]
            w = self.utterance_weight[None, :]
            quad = sse - np.sum(t2 * sums**2 / (s2 + t2 * w), axis=1)
            log_det = np.sum(np.log1p(t2 * w / s2), axis=1)
        with np.errstate(invalid="ignore"):
            ll = -0.5 * quad / sigma**2 - 0.5 * log_det - self.n_data * (np.log(sigma) + 0.5 * math.log(2 * math.pi))
        return np.where(np.isfinite(ll), ll, -np.inf)

    def __call__(self, x: FloatArray) -> FloatArray:
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        lp = self.log_prior(x)
        ok = np.flatnonzero(np.isfinite(lp))
        if ok.size:
            xs = x[ok]
            if self.offset_sd == 0.0:
                lp[ok] += self.temper * self.log_likelihood(self.sse(xs), self.sigma_n(xs))
            else:
                sse, sums = self.residual_sums(xs)
                lp[ok] += self.temper * self.log_likelihood(sse, self.sigma_n(xs), sums, self.offsets(xs))
        return lp

    # --- starting point, predictions, identity -------------------------------------------------
    def start_point(self) -> FloatArray:
        """The packing's base values (the least-squares optimum) in sampling coordinates; log σ_n
        from the residual RMS there, τ from the spread of the utterances' mean residuals beyond
        what σ_n explains."""
        x = np.asarray(self.packing.pack(), dtype=np.float64)
        x = np.append(x, [self._spk_a[i] for _, i in self._spk_a_cols] if not self._spk_b_cols else
                      [v for (_, i) in self._spk_a_cols for v in (self._spk_a[i], math.log(self._spk_b[i]))])
        if not self._extras:
            return x
        sse_a, sums_a = self.residual_sums(x[None])
        sse, sums = float(sse_a[0]), sums_a[0]
        if not np.isfinite(sse):
            raise McmcError(f"channel {self.channel}: the starting point (least-squares optimum) is rejected by the model core")
        sigma = max(math.sqrt(sse / self.n_data), math.exp(LOG_SIGMA_RANGE[0] + 1.0))
        extra = []
        if self._sigma_col is not None:
            extra.append(math.log(sigma))
        if self._offset_col is not None:
            w = self.utterance_weight
            used = w > 0
            between = float(np.mean((sums[used] / w[used]) ** 2 - (self.noise or sigma) ** 2 / w[used]))
            extra.append(min(max(math.sqrt(max(between, 0.0)), 0.01 * sigma), OFFSET_RANGE[1] / 2))
        if self.pool is not None:  # the fit's estimate of each sampled τ
            extra += [math.log(self.pool.tau[f]) for f, c in zip(self.pool.families, self._pool_cols) if c is not None]
        return np.append(x, extra)

    def initial_ball(self, center: FloatArray, n: int, rng: np.random.Generator, scale: float = 1e-3) -> FloatArray:
        """``n`` walkers around ``center``, clipped just inside the support.

        The radius is ``scale`` times the prior width of each coordinate: small, never degenerate.
        """
        center = np.asarray(center, dtype=np.float64)
        if center.shape != (self.dim,):
            raise McmcError(f"initial point has shape {center.shape}, expected ({self.dim},)")
        width = self.upper - self.lower
        lo, hi = self.lower + 1e-6 * width, self.upper - 1e-6 * width
        pos = np.clip(center, lo, hi) + scale * width * rng.standard_normal((n, self.dim))
        return np.asarray(np.clip(pos, lo, hi), dtype=np.float64)

    def predict(self, x: FloatArray) -> FloatArray:
        """Model trajectories (draws, n_samples) for parameter draws, through ``evaluate_batch`` (each
        speaker's a_s + b_s·F with [model] speakers)."""
        params, betas = self.matrices(x)
        f = np.asarray(self.evaluate_batch(self.data.corpus, params, betas, self.options), dtype=np.float64)
        return f if self.speakers is None else self.speakers.predict(f, *self.speaker_coefficients(x))

    def fingerprint(self) -> str:
        """A hash of everything that defines this posterior, so chains are never resumed on another."""
        h = hashlib.sha256()
        p = self.packing
        for a in (self.data.observed, self.data.weights, p.base, p.free, self.lower, self.upper):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr((p.base_beta, self.noise, self.offset_sd, sorted(self.priors.items()), self.coordinates, self.channel,
                       self.shrinkage.groups)).encode())
        if self.speakers is not None:
            h.update(repr((self.speakers.mode, self.speakers.names, self._spk_a.tolist(), self._spk_b.tolist())).encode())
        if self.pool is not None:
            h.update(repr((sorted(self.pool.tau.items()), self.pool.temper, self._pool_cols, self.pool.groups,
                           sorted(self.pool.target_means.items()), sorted(self.pool.target_counts.items()))).encode())
        for u in self.data.utterances:
            h.update(repr((u.name, u.labels)).encode())
            h.update(np.ascontiguousarray(u.starts).tobytes() + np.ascontiguousarray(u.ends).tobytes())
        return h.hexdigest()[:16]


def phoneme_posterior(
    data: ChannelData,
    packing: Packing,
    options: _core.ModelOptions,
    phoneme: str,
    noise: float | None = None,
    priors: Mapping[str, PriorTerm] | None = None,
    offset_sd: float | None = 0.0,
    shrinkage: Sequence[ShrinkGroup] = (),
    speakers: SpeakerTerms | None = None,
    pool: Pool | None = None,
    **evaluators: Any,
) -> LogPosterior:
    """The posterior of one phoneme's free parameters on one channel (about 10 dimensions).

    Every other phoneme stays at ``packing.base`` (the least-squares optimum), β is fixed, and only
    the utterances that contain the phoneme are evaluated (the others do not depend on it). With
    ``speakers``, the offset/scale of every speaker with such utterances is sampled too (a nuisance
    for the phoneme; the reference speaker stays the fit's). With the fit's ``pool``, the phoneme's
    hierarchical prior terms with every τ held at the fit's estimate (the conditional posterior;
    the joint ``channel_posterior`` samples τ).
    """
    if phoneme not in data.phonemes:
        raise McmcError(f"channel {data.channel}: phoneme {phoneme!r} does not occur (phonemes: {' '.join(data.phonemes)})")
    row = data.phonemes.index(phoneme)
    free = np.zeros_like(packing.free)
    free[row] = packing.free[row]
    if not free.any():
        raise McmcError(f"channel {data.channel}: phoneme {phoneme!r} has no free parameter (all fixed by the spec)")
    # the utterances of the phoneme and of every phoneme whose entries follow its free ones
    # ([[tie]], or the speakers' rows of [model] speakers = "targets"): the others do not depend on it
    free_flat = packing.free.reshape(-1)
    n_par = packing.free.shape[1]
    labels = {phoneme} | {data.phonemes[f // n_par] for f, ld in packing.ties if ld // n_par == row and free_flat[ld]}
    sub = data.subset(labels)
    names = set(packing.with_free(free, False).names())
    mine = {k: v for k, v in (priors or {}).items() if k in names}
    return LogPosterior(sub, packing.with_free(free, False), options, noise, mine, offset_sd=offset_sd,
                        shrinkage=shrinkage, **_speaker_args(sub, speakers), pool=pool, sample_pool=False,
                        **evaluators)


def channel_posterior(
    data: ChannelData,
    packing: Packing,
    options: _core.ModelOptions,
    noise: float | None = None,
    priors: Mapping[str, PriorTerm] | None = None,
    offset_sd: float | None = 0.0,
    shrinkage: Sequence[ShrinkGroup] = (),
    speakers: SpeakerTerms | None = None,
    pool: Pool | None = None,
    **evaluators: Any,
) -> LogPosterior:
    """The joint posterior of every free parameter of the channel (hundreds of dimensions: slow
    for emcee, which is why per-phoneme posteriors are the default), with the fit's ``pool``
    each family's τ sampled too."""
    return LogPosterior(data, packing, options, noise, priors, offset_sd=offset_sd, shrinkage=shrinkage,
                        **_speaker_args(data, speakers), pool=pool, **evaluators)


@dataclass(frozen=True)
class SpeakerTerms:
    """A fitted table's speakers on one channel: the fit spec's mode and manifest column, the
    speakers in the fit's order (reference first) and their least-squares (a_s, b_s)."""

    mode: str
    column: str
    names: tuple[str, ...]
    start: Mapping[str, tuple[float, float]]

    def on(self, data: ChannelData) -> Speakers:
        """The least-squares problem's speaker mapping on ``data`` (all utterances or a subset)."""
        from coartic.estimation.speakers import Speakers

        return Speakers(data, self.mode, self.column, self.names)


def _speaker_args(data: ChannelData, speakers: SpeakerTerms | None) -> dict[str, Any]:
    return {} if speakers is None else {"speakers": speakers.on(data), "speaker_start": speakers.start}
