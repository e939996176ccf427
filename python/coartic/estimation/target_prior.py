"""Every target drawn toward the data's own mean of its phoneme (``[parameters] target_prior``).

The step model (each phoneme's mean over its segments, ``coartic.evaluation.baselines``) is what a fitted
table must beat held out; on little data a free target can sit far from anything its phoneme's
segments show (a short consonant's target is extrapolated from a few samples and its neighbours)
and carry that error to every new utterance. A Gaussian prior ``target ~ N(segment mean, sd)``
with the noise of ``[parameters] prior_noise`` is one more least-squares row per phoneme
(``coartic.estimation.penalties.Penalty``): the data outweigh it where they determine the target,
and as sd -> 0 the table becomes a step model smoothed by the dominance functions.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.estimation.packing import Prior
from coartic.model import Utterance
from coartic.table import PARAMETERS


def segment_means(utterances: Sequence[Utterance], channel: str) -> dict[str, float]:
    """Each phoneme's mean of ``channel`` over the valid samples inside its segments (phonemes
    with no such sample are absent): the step model's value."""
    return {lab: m for lab, (m, _) in segment_stats(utterances, channel).items()}


def segment_stats(utterances: Sequence[Utterance], channel: str) -> dict[str, tuple[float, int]]:
    """``segment_means`` and, with each, the number of samples it averages."""
    acc: dict[str, list[float]] = {}
    for u in utterances:
        y = u.observed[channel]
        ok = u.valid[channel] & np.isfinite(y)
        seg = u.sample_segments()
        for i, lab in enumerate(u.labels):
            m = ok & (seg == i)
            if m.any():
                a = acc.setdefault(lab, [0.0, 0.0])
                a[0] += float(y[m].sum())
                a[1] += float(m.sum())
    return {lab: (s / k, int(k)) for lab, (s, k) in acc.items()}


def target_priors(sd: float | None, utterances: Sequence[Utterance], channel: str, phonemes: Sequence[str],
                  free: NDArray[np.bool_], given: Mapping[str, Prior]) -> dict[str, Prior]:
    """The ``"phoneme.target"`` priors of one channel: every phoneme whose target is free, centred on
    its segment mean, sd ``sd`` mm (None: none); a prior the spec gives for a target wins."""
    if sd is None:
        return {}
    means = segment_means(utterances, channel)
    k = PARAMETERS.index("target")
    return {f"{p}.target": Prior(means[p], sd, False) for i, p in enumerate(phonemes)
            if free[i, k] and p in means and f"{p}.target" not in given}
