"""Boundary accuracy of one segmentation against another (docs/ALIGN.md).

The two may use different phone sets (an aligner's IPA, MAUS's SAMPA): both are compared as model
phonemes, their sequences paired by edit distance (phones inserted or left out by one of them have
no partner), and a boundary is the start of a paired phone: where the phone before it ends.
Pauses take part like phones, so that the start and end of speech count; the recording's first
instant (0 s, the start of both) does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from coartic.io.labels import Segments


@dataclass(frozen=True)
class BoundaryAccuracy:
    """Errors (s) of the paired boundaries, and how many phones each side has and were paired."""

    errors: NDArray[np.float64]
    n_reference: int
    n_aligned: int

    @property
    def median_ms(self) -> float:
        return float(np.median(self.errors) * 1000) if len(self.errors) else float("nan")

    @property
    def p90_ms(self) -> float:
        return float(np.percentile(self.errors, 90) * 1000) if len(self.errors) else float("nan")

    def within(self, ms: float) -> float:
        """Fraction of the paired boundaries within `ms` of the reference."""
        return float(np.mean(self.errors <= ms / 1000 + 1e-9)) if len(self.errors) else float("nan")

    def summary(self) -> str:
        return (f"{len(self.errors)} boundaries (of {self.n_reference} reference phones): median "
                f"{self.median_ms:.0f} ms, 90th percentile {self.p90_ms:.0f} ms, {100 * self.within(20):.0f} % "
                f"within 20 ms, {100 * self.within(40):.0f} % within 40 ms")

    @staticmethod
    def pooled(parts: list[BoundaryAccuracy]) -> BoundaryAccuracy:
        return BoundaryAccuracy(np.concatenate([p.errors for p in parts]) if parts else np.zeros(0),
                                sum(p.n_reference for p in parts), sum(p.n_aligned for p in parts))


def _merge_pauses(seg: Segments, pause: str) -> tuple[list[str], list[float]]:
    labels: list[str] = []
    starts: list[float] = []
    for lab, s in zip(seg.labels, seg.starts):
        if lab == pause and labels and labels[-1] == pause:
            continue
        labels.append(lab)
        starts.append(float(s))
    return labels, starts


def pair_phones(reference: list[str], aligned: list[str]) -> list[tuple[int, int]]:
    """Index pairs (reference, aligned) of the phones an edit-distance alignment matches or substitutes."""
    n, m = len(reference), len(aligned)
    cost = np.zeros((n + 1, m + 1))
    cost[:, 0] = np.arange(n + 1)
    cost[0, :] = np.arange(m + 1)
    for a in range(1, n + 1):
        for b in range(1, m + 1):
            sub = 0.0 if reference[a - 1] == aligned[b - 1] else 1.0
            cost[a, b] = min(cost[a - 1, b - 1] + sub, cost[a - 1, b] + 1.0, cost[a, b - 1] + 1.0)
    pairs: list[tuple[int, int]] = []
    a, b = n, m
    while a > 0 and b > 0:
        sub = 0.0 if reference[a - 1] == aligned[b - 1] else 1.0
        if cost[a, b] == cost[a - 1, b - 1] + sub:
            pairs.append((a - 1, b - 1))
            a, b = a - 1, b - 1
        elif cost[a, b] == cost[a - 1, b] + 1.0:
            a -= 1
        else:
            b -= 1
    return pairs[::-1]


def boundary_accuracy(reference: Segments, aligned: Segments, pause: str = "#") -> BoundaryAccuracy:
    """Boundary errors of `aligned` against `reference`, both in model phonemes (module docstring)."""
    ref_labels, ref_starts = _merge_pauses(reference, pause)
    hyp_labels, hyp_starts = _merge_pauses(aligned, pause)
    errors = [abs(ref_starts[r] - hyp_starts[h]) for r, h in pair_phones(ref_labels, hyp_labels)
              if ref_starts[r] > 0 or hyp_starts[h] > 0]
    return BoundaryAccuracy(np.asarray(errors, dtype=np.float64), len(ref_labels), len(hyp_labels))
