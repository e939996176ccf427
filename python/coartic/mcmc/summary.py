"""Posterior draws → quantiles per parameter, an "identified" verdict, and the table's uncertainty fields."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from coartic.mcmc.errors import McmcError

if TYPE_CHECKING:
    from coartic.mcmc.posterior import LogPosterior
    from coartic.mcmc.sampler import SamplingResult
    from coartic.table import ParameterTable

QUANTILE_LEVELS: dict[str, float] = {"q2.5": 2.5, "q16": 16.0, "q50": 50.0, "q84": 84.0, "q97.5": 97.5}
# A parameter counts as identified by the data when its 95 % interval spans less than this fraction
# of its prior range, both measured in the sampling coordinate (log units for scale parameters).
IDENTIFIED_FRACTION = 0.1


@dataclass
class ParameterSummary:
    name: str  # 'p.k_r', 'beta' or 'sigma_n'
    start: float  # least-squares value (natural units)
    mean: float
    sd: float
    quantiles: dict[str, float]  # natural units
    prior_fraction: float  # 95 % width / prior width, in sampling coordinates
    identified: bool
    rhat: float
    ess_bulk: float


def quantiles(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """(5, dim): the QUANTILE_LEVELS percentiles of draws shaped (n, dim)."""
    return np.percentile(values, list(QUANTILE_LEVELS.values()), axis=0)


def summarize(posterior: LogPosterior, result: SamplingResult, start: NDArray[np.float64]) -> list[ParameterSummary]:
    """One summary per coordinate, from the post-burn-in thinned draws of every ensemble."""
    draws = result.draws()
    if draws.shape[0] < 2:
        raise McmcError("too few posterior draws to summarise; sample longer")
    natural = posterior.to_natural(draws)
    q_nat = quantiles(natural)
    q_coord = quantiles(draws)
    frac = (q_coord[4] - q_coord[0]) / (posterior.upper - posterior.lower)
    start_nat = posterior.to_natural(np.asarray(start)[None])[0]
    rep = result.report
    out = []
    for j, name in enumerate(posterior.names):
        out.append(
            ParameterSummary(
                name=name,
                start=float(start_nat[j]),
                mean=float(natural[:, j].mean()),
                sd=float(natural[:, j].std(ddof=1)),
                quantiles={k: float(q_nat[i, j]) for i, k in enumerate(QUANTILE_LEVELS)},
                prior_fraction=float(frac[j]),
                identified=bool(frac[j] < IDENTIFIED_FRACTION),
                rhat=float(rep.rhat[j]) if rep else float("nan"),
                ess_bulk=float(rep.ess_bulk[j]) if rep else float("nan"),
            )
        )
    return out


def covers(truth: float, low: float, high: float, bounds: tuple[float, float]) -> bool:
    """Whether an interval [low, high] holds a known truth (calibration checks).

    A truth on a prior bound (k_R = 1) cannot lie strictly inside an equal-tailed interval; there
    it counts when the interval reaches the bound to within 1 % of the prior width.
    """
    lo, hi = bounds
    if truth in (lo, hi):
        edge = high if truth == hi else low
        return bool(abs(edge - truth) < 0.01 * (hi - lo))
    return bool(low <= truth <= high)


def to_jsonable(summaries: list[ParameterSummary]) -> list[dict[str, Any]]:
    out = []
    for s in summaries:
        d = asdict(s)
        d = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}
        out.append(d)
    return out


def write_uncertainty(table: ParameterTable, channel: str, summaries: list[ParameterSummary]) -> int:
    """Store each per-phoneme parameter's quantiles in ``table.uncertainty``; returns how many.

    β, σ_n and the speakers' offsets and scales have no per-phoneme slot in the table; they stay in
    the run's summary file.
    """
    n = 0
    for s in summaries:
        if "." not in s.name or s.name.startswith(("speaker_offset:", "speaker_scale:")):
            continue
        phoneme, parameter = s.name.split(".", 1)
        if phoneme not in table.values and "|" in phoneme:
            # [model] speakers = "targets": row "p|s"; its shared entries are p's, its target s's own
            if parameter == "target":
                continue
            phoneme = phoneme.rpartition("|")[0]
        table.uncertainty.setdefault(phoneme, {}).setdefault(channel, {})[parameter] = dict(s.quantiles)
        n += 1
    return n
