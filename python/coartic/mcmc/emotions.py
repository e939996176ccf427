"""MCMC intervals of the emotions' deviations (``[model] emotions = "targets"``, docs/EMOTIONS.md).

A deviation d = T(p|e) − T(p|neutral) is a difference of two targets, so its interval needs their
joint posterior: ``deviation_posterior`` samples the targets of every row of one phoneme (its
neutral row and each emotion's) together, with the fit's deviation prior (the shrinkage pairs with
the data-estimated τ) and the noise level sampled, every other entry (the dynamics, the other
phonemes) held at the least-squares optimum, on the utterances that contain the phoneme. The
intervals are therefore conditional on the dynamics, like a per-phoneme posterior's (docs/MCMC.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coartic.estimation.problem import ChannelProblem
from coartic.mcmc.errors import McmcError
from coartic.mcmc.posterior import LogPosterior
from coartic.mcmc.run import sample_posterior
from coartic.mcmc.sampler import SamplerSettings
from coartic.table import PARAMETERS

QUANTILES = (2.5, 50.0, 97.5)


@dataclass(frozen=True)
class DeviationInterval:
    channel: str
    emotion: str
    phoneme: str
    fitted: float  # the least-squares (MAP) deviation, mm
    q2_5: float
    q50: float
    q97_5: float
    converged: bool

    @property
    def credible(self) -> bool:
        """The 95 % interval excludes 0."""
        return self.q2_5 > 0.0 or self.q97_5 < 0.0

    def row(self) -> dict[str, Any]:
        return {"channel": self.channel, "emotion": self.emotion, "phoneme": self.phoneme, "fitted": self.fitted,
                "q2.5": self.q2_5, "q50": self.q50, "q97.5": self.q97_5, "credible": self.credible,
                "converged": self.converged}


def _rows_of(problem: ChannelProblem, phoneme: str) -> list[int]:
    rows = problem.speaker_rows
    if rows is None or rows.factor != "emotions":
        raise McmcError(f"channel {problem.data.channel}: the problem has no emotion rows ([model] emotions = \"targets\")")
    if phoneme not in rows.base:
        raise McmcError(f"channel {problem.data.channel}: phoneme {phoneme!r} does not occur "
                        f"(phonemes: {' '.join(rows.base)})")
    p = rows.base.index(phoneme)
    return [r for r, (q, _) in enumerate(rows.rows) if q == p]


def deviation_posterior(problem: ChannelProblem, phoneme: str) -> LogPosterior:
    """The joint posterior of the targets of ``phoneme``'s rows (neutral and every emotion)."""
    idx = _rows_of(problem, phoneme)
    pk = problem.packing
    k = PARAMETERS.index("target")
    free = np.zeros_like(pk.free)
    free[idx, k] = pk.free[idx, k]
    if not free.any():
        raise McmcError(f"channel {problem.data.channel}: the targets of {phoneme!r} are fixed by the spec")
    assert problem.speaker_rows is not None
    labels = {problem.speaker_rows.labels[r] for r in idx}
    return LogPosterior(problem.data.subset(labels), pk.with_free(free, False), problem.options, None,
                        shrinkage=problem.shrink_groups)


def deviation_intervals(problem: ChannelProblem, phoneme: str, directory: Path,
                        settings: SamplerSettings | None = None) -> list[DeviationInterval]:
    """Sample ``deviation_posterior`` into ``directory`` (resumable, as every posterior) and return
    each emotion's deviation of ``phoneme``: the least-squares value and the posterior quantiles."""
    rows = problem.speaker_rows
    assert rows is not None
    post = deviation_posterior(problem, phoneme)
    run = sample_posterior(post, directory, settings or SamplerSettings(), f"{problem.data.channel} /{phoneme}/ "
                           "emotions", phoneme, make_plots=False, progress=False)
    draws = run.result.draws()
    names = run.result.names
    params, _ = problem.packing.unpack(problem.packing.pack())
    k = PARAMETERS.index("target")
    idx = _rows_of(problem, phoneme)
    neutral = next(r for r in idx if rows.rows[r][1] == 0)
    col = {r: names.index(f"{rows.labels[r]}.target") for r in idx if f"{rows.labels[r]}.target" in names}
    out = []
    for r in idx:
        if r == neutral or r not in col or neutral not in col:
            continue
        d = draws[:, col[r]] - draws[:, col[neutral]]
        q = np.percentile(d, QUANTILES)
        out.append(DeviationInterval(problem.data.channel, rows.names[rows.rows[r][1]], phoneme,
                                     float(params[r, k] - params[neutral, k]), float(q[0]), float(q[1]), float(q[2]),
                                     run.result.converged))
    return out
