"""The whole MCMC job: per channel, per phoneme (or the channel jointly), sample, check, summarise, plot.

``run(spec_path, fit, out)`` is what ``coartic mcmc SPEC --fit DIR --out DIR`` calls. The fit spec
(the least-squares one, docs/FITTING.md) may carry an ``[mcmc]`` section (docs/MCMC.md); the
least-squares table gives the optimum the walkers start from and the values held fixed.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.estimation.data import ChannelData
from coartic.estimation.packing import Packing
from coartic.estimation.penalties import ShrinkGroup
from coartic.estimation.pooling import Pool
from coartic.estimation.problem import ChannelProblem, build_problem
from coartic.estimation.speakers import SPEAKER_SEP, table_speaker_meta
from coartic.mcmc import idata, plots, sampler, summary
from coartic.mcmc.posterior import BatchFn, LogPosterior, PriorTerm, SpeakerTerms, channel_posterior, phoneme_posterior
from coartic.mcmc.sampler import SamplerSettings, SamplingResult
from coartic.mcmc.summary import ParameterSummary
from coartic.outputs import atomic_write_text
from coartic.pauses import is_pause
from coartic.mcmc.errors import McmcConfigError, McmcError
from coartic.model import Utterance
from coartic.table import ParameterTable

if TYPE_CHECKING:  # the spec module loads pydantic: read_spec imports it when it runs
    from coartic import _core
    from coartic.fit.spec import FitSpec


@dataclass
class McmcConfig:
    scope: str = "phonemes"  # one posterior per phoneme per channel, or "channel": one joint posterior
    phonemes: tuple[str, ...] | None = None  # None: every phoneme with a free parameter except the pause
    channels: tuple[str, ...] | None = None  # None: the spec's channels
    noise: str | float = "free"  # "free": sample log sigma_n; "fit": fixed at the LS residual RMS; or mm
    offsets: str | float = "free"  # per-utterance offsets: "free": sample their sd; "none"; or a fixed sd (mm)
    priors: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)  # channel -> name -> (mu, sd)
    walkers: int = 0  # 0: max(32, 2 dim + 2)
    settings: SamplerSettings = field(default_factory=SamplerSettings)
    plots: bool = True


def parse_config(raw: Any, path: Path, fit_spec: FitSpec | None = None) -> McmcConfig:
    """Read the ``[mcmc]`` table of a spec (or an empty one); errors name the file and key. The
    least-squares fit's per-utterance offsets with a given sd (``[model] offsets = τ`` of
    ``fit_spec``) are the posterior's too unless ``[mcmc] offsets`` says otherwise."""
    cfg = _parse_config(raw, path)
    given = isinstance(raw, dict) and "offsets" in raw
    spec_sd = "none" if fit_spec is None else fit_spec.groups.offsets
    if not given and isinstance(spec_sd, (int, float)) and not isinstance(spec_sd, bool):
        cfg.offsets = float(spec_sd)
    return cfg


def _parse_config(raw: Any, path: Path) -> McmcConfig:
    # the keys checked by the schema (coartic.mcmc.config, the fit spec's machinery); what needs the
    # sampler (steps against each other, memory) checked here
    from coartic.mcmc.config import parse_section

    sec = parse_section(raw, path)

    def err(key: str, msg: str) -> McmcConfigError:
        return McmcConfigError(f"{path}: [mcmc] {key}: {msg}")

    cfg = McmcConfig(scope=sec.scope, phonemes=sec.phonemes, channels=sec.channels, noise=sec.noise,
                     priors=sec.priors, walkers=sec.walkers, plots=sec.plots)
    if sec.offsets is not None:
        cfg.offsets = sec.offsets
    s = cfg.settings
    s.n_ensembles = s.n_ensembles if sec.ensembles is None else sec.ensembles
    s.chunk_steps = s.chunk_steps if sec.chunk_steps is None else sec.chunk_steps
    s.min_steps = s.min_steps if sec.min_steps is None else sec.min_steps
    s.max_steps = s.max_steps if sec.max_steps is None else sec.max_steps
    s.seed = s.seed if sec.seed is None else sec.seed
    s.ball = s.ball if sec.ball is None else sec.ball
    s.moves = s.moves if sec.moves is None else sec.moves
    if s.min_steps > s.max_steps:
        raise err("min_steps", f"{s.min_steps} exceeds max_steps = {s.max_steps}")
    try:  # chains too large for memory: refused now (at one dimension, a lower bound), not hours later
        replace(s, n_walkers=walkers_for(1, cfg.walkers)).check_memory(1)
    except ValueError as exc:
        keys = [k for k in ("max_steps", "walkers", "ensembles", "chunk_steps") if k in (raw or {})]
        raise err(", ".join(keys) or "max_steps", str(exc)) from None
    return cfg


def read_spec(path: str | Path) -> tuple[FitSpec, McmcConfig]:
    """The fit spec and the MCMC configuration from its ``[mcmc]`` table."""
    from coartic.fit.spec import parse_spec, read_document

    path = Path(path)
    raw = read_document(path)
    spec = parse_spec(raw, path)
    return spec, parse_config(raw.get("mcmc"), path, spec)


def table_problem(fit_spec: FitSpec, table: ParameterTable, channel: str, utterances: Sequence[Utterance]) -> ChannelProblem:
    """The problem of one channel for sampling around a fitted table: the one constructor
    (``coartic.estimation.problem.build_problem`` with the table: its options, values and speakers'
    targets; the spec's free set, bounds, ties, priors and shrinkage), with the value ``[choose]``
    chose for the channel (the table's metadata "choice") put into the spec first, so that the
    posterior has the penalties the least-squares fit had."""
    from coartic.fit.choose import set_value

    choice = (table.metadata or {}).get("choice") or {}
    if choice.get("key") and channel in choice.get("chosen", {}):
        fit_spec = set_value(fit_spec, choice["key"], float(choice["chosen"][channel]))
    return build_problem(fit_spec.estimation_settings(), utterances, channel, table)


def table_speakers(fit_spec: FitSpec, table: ParameterTable, channel: str) -> SpeakerTerms | None:
    """The speakers ([model] speakers) the table was fitted with on ``channel``, for the posterior:
    mode and column must be the spec's (else refused: the posterior would not be the fit's model),
    the speakers and their least-squares (a_s, b_s) come from the table's metadata. None without
    speakers, and with per-speaker targets (sampled as the problem's own rows: ``table_problem``)."""
    meta = table_speaker_meta(fit_spec.estimation_settings().groups, str(fit_spec.path), table)
    if fit_spec.groups.speakers in ("none", "targets"):
        return None
    coefs = (meta.get("coefficients") or {}).get(channel)
    if not coefs:
        raise McmcError(f"{table.source}: metadata.speakers has no coefficients for channel {channel}")
    start = {str(s): (float(c["offset_mm"]), float(c["scale"])) for s, c in coefs.items()}
    return SpeakerTerms(fit_spec.groups.speakers, fit_spec.groups.speaker_column, tuple(start), start)


def problem_priors(problem: ChannelProblem) -> dict[str, PriorTerm]:
    """The problem's priors (the spec's ``[parameters.prior]`` on its free entries, per speaker row
    with per-speaker targets) as ``LogPosterior`` takes them: (mean, sd), or (mean, sd, True) on log
    values. ``[mcmc] priors`` add to and override them."""
    return {k: (p.mean, p.sd, True) if p.log else (p.mean, p.sd) for k, p in problem.priors.items()}


@dataclass(frozen=True)
class ChannelSampling:
    """What the MCMC samples on one channel, taken from the least-squares problem around a fitted
    table: the one typed seam between fitting (``coartic.estimation``, ``coartic.fit``) and this
    package. ``ChannelSampling.of(problem, speakers)`` makes it (``sample_table``); a caller with
    its own data and packing (tests, benchmarks) builds it field by field."""

    channel: str
    data: ChannelData  # the channel's utterances as the core's corpus, observations and weights
    packing: Packing  # free entries at the fit's values (the walkers' start), boxes, ties
    options: _core.ModelOptions  # the channel's model options (variant, a, Λ, dominance)
    # the spec's [parameters.prior] on free entries (``problem_priors``); [mcmc] priors add to them
    priors: Mapping[str, PriorTerm] = field(default_factory=dict)
    shrinkage: Sequence[ShrinkGroup] = ()  # the spec's [[shrink]] (and emotions') groups
    speakers: SpeakerTerms | None = None  # the table's speakers' (a_s, b_s) (``table_speakers``)
    pool: Pool | None = None  # the fit's partial pooling, its sds at the fit's estimate

    @classmethod
    def of(cls, problem: ChannelProblem, speakers: SpeakerTerms | None = None) -> ChannelSampling:
        return cls(problem.data.channel, problem.data, problem.packing, problem.options, problem_priors(problem),
                   tuple(problem.shrink_groups), speakers, problem.pool)


def walkers_for(dim: int, requested: int) -> int:
    """emcee needs more than 2 dim walkers; an even count, at least 32 unless more are requested."""
    n = requested if requested > 0 else max(32, 2 * dim + 2)
    return n + (n % 2)


@dataclass
class PosteriorRun:
    channel: str
    phoneme: str | None  # None for the joint channel posterior
    directory: Path
    posterior: LogPosterior
    result: SamplingResult
    start: NDArray[np.float64]
    summaries: list[ParameterSummary]
    images: list[Path]
    # what the fit estimated on this channel that no posterior of it samples (held at the fit's value)
    held_fixed: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        return f"{self.channel} /{self.phoneme}/" if self.phoneme is not None else f"{self.channel} (joint)"


def sample_posterior(
    posterior: LogPosterior,
    directory: Path,
    settings: SamplerSettings,
    label: str,
    phoneme: str | None = None,
    make_plots: bool = True,
    progress: bool = True,
    start: NDArray[np.float64] | None = None,
) -> PosteriorRun:
    """Sample one posterior into ``directory`` (resuming what is there), summarise and plot it."""
    directory.mkdir(parents=True, exist_ok=True)
    x0 = posterior.start_point() if start is None else np.asarray(start, dtype=np.float64)
    if not np.isfinite(posterior(x0[None])[0]):
        raise McmcError(f"{label}: the least-squares optimum has zero posterior density (outside the bounds or rejected by the core)")
    result = sampler.run(
        posterior,
        lambda rng, n: posterior.initial_ball(x0, n, rng, settings.ball),
        posterior.coordinates,
        directory / "chains",
        settings,
        fingerprint=posterior.fingerprint(),
        progress=progress,
        label=label,
        bounds=(posterior.lower, posterior.upper),
    )
    # ArviZ's form of the chains so far, for the ecosystem's tools; the chunks stay what resumes
    idata.write_inference_data(directory, posterior, result, label)
    # An interrupted posterior keeps its chains (to resume) but gives no intervals: a partial chain
    # would put unchecked numbers into the table.
    summaries = [] if result.interrupted else summary.summarize(posterior, result, x0)
    images: list[Path] = []
    if make_plots and not result.interrupted:
        images.append(plots.trace_plot(result, directory / "trace.png", label))
        images.append(plots.corner_plot(result, x0, directory / "corner.png", label))
        images.append(plots.predictive_plot(posterior, result, x0, directory / "predictive.png", label))
    doc = {
        "label": label,
        "converged": result.converged,
        "interrupted": result.interrupted,
        "convergence": result.report.to_dict() if result.report else None,
        "acceptance": result.acceptance,
        "n_data": posterior.n_data,
        "n_utterances": len(posterior.data.utterances),
        "parameters": summary.to_jsonable(summaries),
    }
    atomic_write_text(directory / "summary.json", json.dumps(doc, indent=1))
    return PosteriorRun(posterior.channel, phoneme, directory, posterior, result, x0, summaries, images)


def fixed_noise(data: ChannelData, packing: Packing, options: _core.ModelOptions, sse_batch: BatchFn | None = None,
                speakers: SpeakerTerms | None = None) -> float:
    """σ_n fixed at the least-squares residual RMS of the whole channel (each speaker's a_s + b_s·F
    with ``speakers``)."""
    if speakers is not None:
        post = channel_posterior(data, packing, options, noise=1.0, speakers=speakers)
        sse_s = float(post.sse(post.start_point()[None])[0])
        return math.sqrt(sse_s / max(int(np.count_nonzero(data.weights > 0)), 1))
    if sse_batch is None:
        from coartic import _core

        sse_batch = _core.sse_batch
    params, beta = packing.unpack_batch(packing.pack()[None])
    sse = float(np.asarray(sse_batch(data.corpus, params, beta, options, data.observed, data.weights))[0])
    return math.sqrt(sse / max(int(np.count_nonzero(data.weights > 0)), 1))


def channel_runs(sampling: ChannelSampling, cfg: McmcConfig, out: Path, progress: bool = True,
                 on_done: Callable[[PosteriorRun], None] | None = None) -> tuple[list[PosteriorRun], bool]:
    """Every posterior the config asks for on one channel; returns them and whether interrupted.
    Each run's ``held_fixed`` names what the fit estimated but no posterior of the channel samples
    (held at the least-squares value: e.g. the pause's parameters, a pool's sd in per-phoneme posteriors)."""
    channel, data, packing, options = sampling.channel, sampling.data, sampling.packing, sampling.options
    speakers, pool, spec_shrinkage = sampling.speakers, sampling.pool, sampling.shrinkage
    noise: float | None
    if cfg.noise == "free":
        noise = None
    elif cfg.noise == "fit":
        noise = fixed_noise(data, packing, options, speakers=speakers)
    else:
        noise = float(cfg.noise)
    offset_sd: float | None
    if cfg.offsets == "free":
        offset_sd = None
    elif cfg.offsets == "none":
        offset_sd = 0.0
    else:
        offset_sd = float(cfg.offsets)
    priors: dict[str, PriorTerm] = {**sampling.priors, **cfg.priors.get(channel, {})}
    known = set(packing.names())
    for name in priors:
        if name not in known:
            raise McmcConfigError(f"[mcmc] priors.{channel}.{name}: not a free parameter of {channel} (free: {', '.join(sorted(known))})")
    runs: list[PosteriorRun] = []
    if cfg.scope == "channel":
        jobs: list[tuple[str | None, Callable[[], LogPosterior]]] = [(None, lambda: channel_posterior(data, packing, options, noise, priors, offset_sd,
                                                                                       spec_shrinkage, speakers=speakers, pool=pool))]
    else:
        # (with per-speaker targets the rows are "p|s": a phoneme named in [mcmc] phonemes means all its rows)
        base = [p.rpartition(SPEAKER_SEP)[0] or p if SPEAKER_SEP in p else p for p in data.phonemes]
        wanted = cfg.phonemes or tuple(p for i, p in enumerate(data.phonemes) if not is_pause(base[i]) and packing.free[i].any())
        missing = [p for p in wanted if p not in data.phonemes and p not in base]
        wanted = tuple(r for p in wanted for r, b in zip(data.phonemes, base) if p in (r, b))
        if missing:
            raise McmcConfigError(f"[mcmc] phonemes: {', '.join(missing)} do not occur in the {channel} data (phonemes: {' '.join(data.phonemes)})")

        def job(p: str) -> Callable[[], LogPosterior]:
            return lambda: phoneme_posterior(data, packing, options, p, noise, priors, offset_sd, spec_shrinkage,
                                             speakers=speakers, pool=pool)

        jobs = [(p, job(p)) for p in wanted]
    estimated = list(packing.names()) + ([f"sd({f})" for f in pool.families] if pool is not None else [])
    posteriors = [(phoneme, make()) for phoneme, make in jobs]
    sampled = {n for _, post in posteriors for n in post.names}
    held = [n for n in estimated if n not in sampled]
    for phoneme, post in posteriors:
        settings = replace(cfg.settings, n_walkers=walkers_for(post.dim, cfg.walkers))
        label = f"{channel} /{phoneme}/" if phoneme is not None else f"{channel} (joint)"
        directory = out / channel / (phoneme_dir(phoneme) if phoneme is not None else "_joint")
        r = sample_posterior(post, directory, settings, label, phoneme, cfg.plots, progress)
        r.held_fixed = held
        runs.append(r)
        if on_done is not None:
            on_done(r)
        if r.result.interrupted:
            return runs, True
    return runs, False


def phoneme_dir(phoneme: str) -> str:
    """A directory name for a phoneme label (labels such as 'tS' are fine; '#' or '/' are not)."""
    safe = "".join(c if c.isalnum() or c in "-_" else f"x{ord(c):02x}" for c in phoneme)
    return safe or "empty"


def verdict_lines(runs: Sequence[PosteriorRun]) -> list[str]:
    """One line per posterior that did not converge (empty when every one did)."""
    out = []
    for r in runs:
        if not r.result.converged:
            rep = r.result.report
            why = "; ".join(rep.problems) if rep else "no convergence check could be made"
            state = "interrupted" if r.result.interrupted else "NOT CONVERGED"
            out.append(f"{r.label}: {state}: {why}")
    return out
