"""One channel's utterances as the Rust core's corpus, with observations and weights (``ChannelData``).

MODEL.md §5: all utterances of a channel are fitted jointly, so a phoneme's parameters are shared by
every context it occurs in; ``ChannelData`` packs them into one ``coartic._core.Corpus`` (CSR) with
the observed values (NaN replaced by 0) and the weights (1 valid, 0 masked).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Collection, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic import _core
from coartic.io.errors import DataError
from coartic.model import Utterance, build_corpus
from coartic.table import PAUSE

FloatArray = NDArray[np.float64]


def phoneme_inventory(utterances: Sequence[Utterance]) -> tuple[str, ...]:
    """Phonemes present, pause first, then in order of first appearance (stable across channels)."""
    seen: dict[str, None] = {}
    for u in utterances:
        for lab in u.labels:
            seen.setdefault(lab, None)
    names = list(seen)
    if PAUSE in seen:
        names.remove(PAUSE)
        names.insert(0, PAUSE)
    return tuple(names)


@dataclass
class ChannelData:
    """All utterances of one channel in the Rust core's corpus form, with observations and weights."""

    channel: str
    phonemes: tuple[str, ...]
    utterances: list[Utterance]
    corpus: _core.Corpus
    observed: FloatArray  # NaN replaced by 0 (weight 0 there)
    weights: FloatArray  # 1 valid, 0 masked
    sample_offsets: NDArray[np.int64]

    @classmethod
    def build(cls, utterances: Sequence[Utterance], channel: str,
              phonemes: Sequence[str] | None = None) -> ChannelData:
        utts = [u for u in utterances if channel in u.observed and np.any(u.valid[channel])]
        if not utts:
            raise DataError(f"channel {channel}: no utterance has a valid sample")
        phon = tuple(phonemes) if phonemes is not None else phoneme_inventory(utts)
        y = np.concatenate([u.observed[channel] for u in utts]).astype(np.float64)
        valid = np.concatenate([u.valid[channel] for u in utts]) & np.isfinite(y)
        offsets = np.cumsum([0] + [len(u.times) for u in utts]).astype(np.int64)
        return cls(channel, phon, utts, build_corpus(utts, phon),
                   np.where(valid, y, 0.0), valid.astype(np.float64), offsets)

    def subset(self, labels: Collection[str]) -> ChannelData:
        """The utterances that contain any of ``labels``, with the same phoneme rows (a per-phoneme
        posterior evaluates only the utterances its phoneme's parameters act on)."""
        return ChannelData.build([u for u in self.utterances if not set(labels).isdisjoint(u.labels)], self.channel,
                                 self.phonemes)

    def utterance_samples(self, u: int) -> slice:
        return slice(int(self.sample_offsets[u]), int(self.sample_offsets[u + 1]))

    @property
    def n_valid(self) -> int:
        return int(self.weights.sum())
