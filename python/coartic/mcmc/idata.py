"""A posterior's chains as ArviZ InferenceData, saved as netCDF beside its resumable chunks.

``posterior.nc`` in each posterior's directory (``CHANNEL/PHONEME/``) is what ``arviz.from_netcdf``
reads; the ``chains/`` chunks stay the record a run resumes from. Layout:

``posterior``
    ``theta`` (chain, draw, entry) in natural units (σ_n, not log σ_n): the post-burn-in, thinned
    draws the summaries are made of. A chain is one walker of one ensemble (ArviZ's convention for
    emcee, as the convergence check's ESS), in ensemble order. Along ``entry``: ``entry`` itself
    (``"p.k_r"``, ``"beta"``, ``"sigma_n"``, ``"speaker_offset:s02"``: the summaries' names), and
    the coordinates ``phoneme`` (``""`` where none), ``parameter`` (``"k_r"``, ``"beta"``,
    ``"sigma_n"``, ``"speaker_offset"``) and ``speaker`` (``""`` where none); ``channel`` is a
    scalar coordinate.
``sample_stats``
    ``lp`` (chain, draw): the log-posterior of each draw; ``ensemble`` along ``chain``.
``observed_data``
    ``y`` (sample): the channel's valid observed samples (mm), with ``utterance`` and ``time`` (s).

Attributes of ``posterior``: label, converged and interrupted (0/1), burn_in, thin, n_steps,
tau_max, acceptance per ensemble, the posterior's fingerprint.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coartic.extras import require
from coartic.outputs import atomic_path

if TYPE_CHECKING:
    from coartic.mcmc.posterior import LogPosterior
    from coartic.mcmc.sampler import SamplingResult

FILE = "posterior.nc"


def split_name(name: str) -> tuple[str, str, str]:
    """(phoneme, parameter, speaker) of a coordinate's natural name."""
    if ":" in name:  # speaker_offset:s02, speaker_scale:s02
        kind, _, speaker = name.partition(":")
        return "", kind, speaker
    if "." in name:
        phoneme, _, parameter = name.rpartition(".")
        return phoneme, parameter, ""
    return "", name, ""


def burn_and_thin(result: SamplingResult) -> tuple[int, int]:
    """The burn-in and thinning the summaries use (``SamplingResult.draws``)."""
    if result.report is not None:
        return result.report.burn_in, result.report.thin
    return len(result.chains[0]) // 2, 1


def to_inference_data(posterior: LogPosterior, result: SamplingResult, label: str = "") -> Any:
    """``arviz.InferenceData`` of one sampled posterior (layout in the module's docstring)."""
    require("mcmc", "an ArviZ InferenceData")
    import arviz as az
    import xarray as xr

    from coartic.mcmc.convergence import walker_chains

    burn, thin = burn_and_thin(result)
    n = min(len(c) for c in result.chains)  # ensembles may differ in length after an interruption
    if burn >= n:  # an interrupted run's last check asked for more burn-in than there are steps
        burn, thin = n // 2, 1
    # (steps, walkers, dim) per ensemble -> (chains = ensembles x walkers, draws, dim)
    draws = walker_chains(result.chains, burn, thin)
    lp = walker_chains([x[..., None] for x in result.log_probs], burn, thin)[..., 0]
    natural = posterior.to_natural(draws)
    names = list(posterior.names)
    parts = [split_name(n) for n in names]
    n_walkers = result.chains[0].shape[1] if result.chains else 0
    chain = np.arange(natural.shape[0])
    entry_coords = {"entry": names, "phoneme": ("entry", [p[0] for p in parts]),
                    "parameter": ("entry", [p[1] for p in parts]), "speaker": ("entry", [p[2] for p in parts])}
    rep = result.report
    attrs = {
        "label": label,
        "converged": int(result.converged),
        "interrupted": int(result.interrupted),
        "burn_in": int(burn),
        "thin": int(thin),
        "n_steps": int(n),
        "tau_max": float(rep.tau_max) if rep is not None else float("nan"),
        "acceptance": np.asarray(result.acceptance, dtype=np.float64),
        "fingerprint": posterior.fingerprint(),
        "inference_library": "emcee",
    }
    post = xr.Dataset(
        {"theta": (("chain", "draw", "entry"), natural)},
        coords={"chain": chain, "draw": np.arange(natural.shape[1]), "channel": posterior.channel, **entry_coords},
        attrs=attrs,
    )
    stats = xr.Dataset(
        {"lp": (("chain", "draw"), lp)},
        coords={"chain": chain, "draw": np.arange(natural.shape[1]),
                "ensemble": ("chain", chain // max(n_walkers, 1))},
    )
    data = posterior.data
    valid = data.weights > 0
    utterance = np.concatenate([np.full(len(u.times), u.name, dtype=object) for u in data.utterances])
    times = np.concatenate([np.asarray(u.times, dtype=np.float64) for u in data.utterances])
    observed = xr.Dataset(
        {"y": (("sample",), np.asarray(data.observed, dtype=np.float64)[valid])},
        coords={"sample": np.arange(int(valid.sum())), "utterance": ("sample", utterance[valid].astype(str)),
                "time": ("sample", times[valid]), "channel": posterior.channel},
    )
    return az.InferenceData(posterior=post, sample_stats=stats, observed_data=observed)


def write_inference_data(directory: Path, posterior: LogPosterior, result: SamplingResult, label: str = "") -> Path | None:
    """``directory/posterior.nc``, written whole (temporary name, then renamed) so that a reader
    never sees half a file; None (and nothing written) when no step has been sampled yet."""
    if not result.chains or min(len(c) for c in result.chains) < 2:
        return None
    idata = to_inference_data(posterior, result, label)
    path = Path(directory) / FILE
    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp))
    return path
