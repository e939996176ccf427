"""The log-posterior of one channel's free parameters, evaluated for all walkers in one Rust call.

Sampling coordinates are the least-squares problem's own internal vector x
(``coartic.fit.problem.Packing``: log for α, θ_bw, θ_fw, ψ and β, natural units for T, c, k_R, σ,
δ), plus ``log_sigma_n`` when the noise level is sampled. The prior (docs/MCMC.md):

* uniform in x inside the packing's bounds, so log-uniform for the scale parameters; a side left
  open by the bounds (α, θ, ψ have (0, ∞) by default) is closed with ``PRIOR_RANGE`` so that the
  prior is proper;
* times optional Gaussian priors on natural values, keyed ``"phoneme.parameter"`` (or ``"beta"``);
* times the fit spec's shrinkage toward class means (``[[shrink]]``: ``coartic.fit.problem.Shrinkage``,
  the least-squares rows divided by prior_noise, so −½ Σ z²);
* ``-inf`` outside the support (those walkers are not even sent to the core).

The likelihood is Gaussian with noise level σ_n per valid sample: either fixed (a number, e.g. the
least-squares residual RMS) or sampled as ``log_sigma_n`` with a uniform prior on
``LOG_SIGMA_RANGE`` (a Jeffreys prior on σ_n). Optionally each utterance also carries its own
constant offset b_u ~ N(0, τ²), integrated out in closed form: a recorded channel is measured
from a rest reference estimated once per utterance, so its error is shared by all of that
utterance's samples. τ (``offset_sd``) is fixed, or sampled with a uniform prior on
``OFFSET_RANGE`` (uniform on a group-level standard deviation, as Gelman 2006 recommends).
With S_u = Σ w r and W_u = Σ w over utterance u, and the SSE Σ w r²:

    log L = −½ (SSE − Σ_u τ² S_u² / (σ² + τ² W_u)) / σ² − ½ Σ_u log(1 + τ² W_u / σ²) − N log σ − (N/2) log 2π
"""

from __future__ import annotations

import hashlib
import math
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from coartic.fit.problem import ChannelData, Packing, ShrinkGroup

FloatArray = NDArray[np.float64]
BatchFn = Callable[..., FloatArray]

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
        options: Any,
        noise: float | None = None,
        priors: Mapping[str, tuple[float, float]] | None = None,
        sse_batch: BatchFn | None = None,
        evaluate_batch: BatchFn | None = None,
        offset_sd: float | None = 0.0,
        residual_sums_batch: Callable[..., tuple[FloatArray, FloatArray]] | None = None,
        shrinkage: Sequence[ShrinkGroup] = (),
    ) -> None:
        from coartic import _core
        from coartic.fit.problem import Shrinkage

        self.sse_batch = sse_batch or _core.sse_batch
        self.evaluate_batch = evaluate_batch or _core.evaluate_batch
        self.residual_sums_batch = residual_sums_batch or _core.residual_sums_batch
        self.data = data
        self.packing = packing
        self.options = options
        self.channel = data.channel
        self.n_data = int(np.count_nonzero(data.weights > 0))
        if self.n_data == 0:
            raise ValueError(f"channel {data.channel}: no valid sample to sample a posterior from")
        if packing.n_free == 0:
            raise ValueError(f"channel {data.channel}: no free parameter to sample")
        self.noise = None if noise is None else float(noise)
        if self.noise is not None and not (self.noise > 0 and math.isfinite(self.noise)):
            raise ValueError(f"channel {data.channel}: a fixed noise level sigma_n must be positive and finite, got {noise}")
        self.offset_sd = None if offset_sd is None else float(offset_sd)
        if self.offset_sd is not None and not (self.offset_sd >= 0 and math.isfinite(self.offset_sd)):
            raise ValueError(f"channel {data.channel}: a fixed offset_sd must be >= 0 and finite, got {offset_sd}")
        self.utterance_weight = np.array([data.weights[data.utterance_samples(k)].sum() for k in range(len(data.utterances))])

        free_names = packing.names()
        # (mean, sd) on the natural value, or (mean, sd, True) on its logarithm (mean: the median),
        # as the fit spec's [parameters.prior] with scale = "log" gives them
        self.priors: dict[str, tuple[Any, ...]] = {
            k: (float(v[0]), float(v[1])) + ((True,) if len(v) > 2 and v[2] else ()) for k, v in (priors or {}).items()}
        for key, (mu, sd, *_) in self.priors.items():
            if key not in free_names:
                raise ValueError(
                    f"Gaussian prior on {key!r}: not a free parameter of this {data.channel} posterior "
                    f"(free: {', '.join(free_names)})"
                )
            if not (sd > 0 and math.isfinite(sd) and math.isfinite(mu)):
                raise ValueError(f"Gaussian prior on {key!r}: needs a finite mean and a positive sd, got ({mu}, {sd})")
        self._prior_index = np.array([free_names.index(k) for k in self.priors], dtype=np.int64)
        self._prior_log = np.array([len(v) > 2 for v in self.priors.values()], dtype=bool)
        for key, v in self.priors.items():
            if len(v) > 2 and not v[0] > 0:
                raise ValueError(f"Gaussian prior on log {key!r}: needs a positive median, got {v[0]}")
        self._prior_mu = np.array([math.log(v[0]) if len(v) > 2 else v[0] for v in self.priors.values()],
                                  dtype=np.float64)
        self._prior_sd = np.array([v[1] for v in self.priors.values()], dtype=np.float64)
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
                raise ValueError(f"{where}: the prior needs finite bounds, got [{lo[j]}, {hi[j]}]")
            if not lo[j] < hi[j]:
                raise ValueError(f"{where}: empty prior support [{lo[j]}, {hi[j]}]")
        # sampled noise terms after the model's coordinates: (coordinate, natural name, range, is log)
        self._extras = [(NOISE_NAME, "sigma_n", LOG_SIGMA_RANGE, True)] if self.noise is None else []
        if self.offset_sd is None:
            self._extras.append((OFFSET_NAME, OFFSET_NAME, OFFSET_RANGE, False))
        self.lower = np.append(lo, [e[2][0] for e in self._extras])
        self.upper = np.append(hi, [e[2][1] for e in self._extras])
        # coordinates that are logarithms of their natural value
        self._exp = np.append(np.asarray(log, dtype=bool), [e[3] for e in self._extras]).astype(bool)
        extra_names = [e[0] for e in self._extras]
        self._sigma_col = packing.n_free + extra_names.index(NOISE_NAME) if NOISE_NAME in extra_names else None
        self._offset_col = packing.n_free + extra_names.index(OFFSET_NAME) if OFFSET_NAME in extra_names else None
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
        """Natural-unit name of every coordinate ('p.k_r', 'beta', and 'sigma_n', 'offset_sd' when sampled)."""
        return self.packing.names() + [e[1] for e in self._extras]

    @property
    def coordinates(self) -> list[str]:
        """Name of every sampling coordinate ('log p.theta_bw' for log-sampled ones)."""
        out = [f"log {n}" if lg else n for n, lg in zip(self.packing.names(), self.packing.log_mask)]
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
        return np.all((x >= self.lower) & (x <= self.upper), axis=1)

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
        return lp

    def sse(self, x: FloatArray) -> FloatArray:
        """Weighted sum of squared residuals per walker (+inf where the core rejects the parameters)."""
        params, betas = self.matrices(x)
        self.n_calls += 1
        d = self.data
        return np.asarray(self.sse_batch(d.corpus, params, betas, self.options, d.observed, d.weights), dtype=np.float64)

    def residual_sums(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """SSE per walker and Σ w r per walker and utterance (+inf / NaN where the core rejects)."""
        params, betas = self.matrices(x)
        self.n_calls += 1
        d = self.data
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
                lp[ok] += self.log_likelihood(self.sse(xs), self.sigma_n(xs))
            else:
                sse, sums = self.residual_sums(xs)
                lp[ok] += self.log_likelihood(sse, self.sigma_n(xs), sums, self.offsets(xs))
        return lp

    # --- starting point, predictions, identity -------------------------------------------------
    def start_point(self) -> FloatArray:
        """The packing's base values (the least-squares optimum) in sampling coordinates; log σ_n
        from the residual RMS there, τ from the spread of the utterances' mean residuals beyond
        what σ_n explains."""
        x = np.asarray(self.packing.pack(), dtype=np.float64)
        if not self._extras:
            return x
        sse_a, sums_a = self.residual_sums(x[None])
        sse, sums = float(sse_a[0]), sums_a[0]
        if not np.isfinite(sse):
            raise ValueError(f"channel {self.channel}: the starting point (least-squares optimum) is rejected by the model core")
        sigma = max(math.sqrt(sse / self.n_data), math.exp(LOG_SIGMA_RANGE[0] + 1.0))
        extra = []
        if self._sigma_col is not None:
            extra.append(math.log(sigma))
        if self._offset_col is not None:
            w = self.utterance_weight
            used = w > 0
            between = float(np.mean((sums[used] / w[used]) ** 2 - (self.noise or sigma) ** 2 / w[used]))
            extra.append(min(max(math.sqrt(max(between, 0.0)), 0.01 * sigma), OFFSET_RANGE[1] / 2))
        return np.append(x, extra)

    def initial_ball(self, center: FloatArray, n: int, rng: np.random.Generator, scale: float = 1e-3) -> FloatArray:
        """``n`` walkers around ``center``, clipped just inside the support.

        The radius is ``scale`` times the prior width of each coordinate: small, never degenerate.
        """
        center = np.asarray(center, dtype=np.float64)
        if center.shape != (self.dim,):
            raise ValueError(f"initial point has shape {center.shape}, expected ({self.dim},)")
        width = self.upper - self.lower
        lo, hi = self.lower + 1e-6 * width, self.upper - 1e-6 * width
        pos = np.clip(center, lo, hi) + scale * width * rng.standard_normal((n, self.dim))
        return np.clip(pos, lo, hi)

    def predict(self, x: FloatArray) -> FloatArray:
        """Model trajectories (draws, n_samples) for parameter draws, through ``evaluate_batch``."""
        params, betas = self.matrices(x)
        return np.asarray(self.evaluate_batch(self.data.corpus, params, betas, self.options), dtype=np.float64)

    def fingerprint(self) -> str:
        """A hash of everything that defines this posterior, so chains are never resumed on another."""
        h = hashlib.sha256()
        p = self.packing
        for a in (self.data.observed, self.data.weights, p.base, p.free, self.lower, self.upper):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr((p.base_beta, self.noise, self.offset_sd, sorted(self.priors.items()), self.coordinates, self.channel,
                       self.shrinkage.groups)).encode())
        for u in self.data.utterances:
            h.update(repr((u.name, u.labels)).encode())
            h.update(np.ascontiguousarray(u.starts).tobytes() + np.ascontiguousarray(u.ends).tobytes())
        return h.hexdigest()[:16]


def phoneme_posterior(
    data: ChannelData,
    packing: Packing,
    options: Any,
    phoneme: str,
    noise: float | None = None,
    priors: Mapping[str, tuple[float, float]] | None = None,
    offset_sd: float | None = 0.0,
    shrinkage: Sequence[ShrinkGroup] = (),
    **evaluators: Callable[..., Any],
) -> LogPosterior:
    """The posterior of one phoneme's free parameters on one channel (about 10 dimensions).

    Every other phoneme stays at ``packing.base`` (the least-squares optimum), β is fixed, and only
    the utterances that contain the phoneme are evaluated (the others do not depend on it).
    """
    from coartic.fit.problem import ChannelData as _ChannelData

    if phoneme not in data.phonemes:
        raise ValueError(f"channel {data.channel}: phoneme {phoneme!r} does not occur (phonemes: {' '.join(data.phonemes)})")
    row = data.phonemes.index(phoneme)
    free = np.zeros_like(packing.free)
    free[row] = packing.free[row]
    if not free.any():
        raise ValueError(f"channel {data.channel}: phoneme {phoneme!r} has no free parameter (all fixed by the spec)")
    sub = _ChannelData.build([u for u in data.utterances if phoneme in u.labels], data.channel, data.phonemes)
    names = set(packing.with_free(free, False).names())
    mine = {k: v for k, v in (priors or {}).items() if k in names}
    return LogPosterior(sub, packing.with_free(free, False), options, noise, mine, offset_sd=offset_sd,
                        shrinkage=shrinkage, **evaluators)


def channel_posterior(
    data: ChannelData,
    packing: Packing,
    options: Any,
    noise: float | None = None,
    priors: Mapping[str, tuple[float, float]] | None = None,
    offset_sd: float | None = 0.0,
    shrinkage: Sequence[ShrinkGroup] = (),
    **evaluators: Callable[..., Any],
) -> LogPosterior:
    """The joint posterior of every free parameter of the channel (hundreds of dimensions: slow
    for emcee, which is why per-phoneme posteriors are the default)."""
    return LogPosterior(data, packing, options, noise, priors, offset_sd=offset_sd, shrinkage=shrinkage, **evaluators)
