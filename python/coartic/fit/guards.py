"""Settings that quietly mislead on little data, refused or warned about before anything is fitted
(issue 19 item 8), each with the reason and the alternative.

- ``[model] offsets = "free"`` on one utterance: its offset is confounded with the common level of
  the targets (the model is a weighted mean of targets, so targets + c and offset − c predict the
  same), and least squares fits the offset instead of the speech (0.90 mm in-sample, 2.06 mm as
  measured in issue 19): refused. A shrunk offset (a number, its sd) on one utterance: warned.
- ``[choose]`` with fewer than two groups of its grouping: there is nothing to score a value on:
  refused; with two, each fold fits on one group and the one-SE rule rests on two folds: warned.
- A phoneme that occurs only in utterances with no valid sample of a channel: no sample lies within
  its reach, the fit leaves it out of that channel: warned.

Parameters the data cannot identify are found after the fit (``coartic.fit.result.unidentified_reasons``).
"""

from __future__ import annotations

from typing import Sequence

from coartic.model import Utterance
from coartic.errors import SpecError
from coartic.fit.spec import FitSpec


def small_data_notes(spec: FitSpec, utterances: Sequence[Utterance]) -> list[str]:
    """The warnings for ``spec`` on ``utterances`` (the training data of this fit); raises
    SpecError, naming the key, for a setting the data cannot support."""
    notes: list[str] = []
    n = len(utterances)
    if spec.groups.offsets != "none" and n < 2:
        if spec.groups.offsets == "free":
            raise SpecError.at(spec.path, "model.offsets", f"\"free\" on {n} utterance: a free per-utterance offset "
                               "is confounded with the targets' common level, so the fit would fit the offset "
                               "instead of the speech; use offsets = \"none\" (and score with the offset removed: "
                               "coartic score reports it), or fit more utterances")
        notes.append(f"[model] offsets = {spec.groups.offsets:g} on one utterance: its offset is confounded with the "
                     "targets' common level and only the prior (its sd) holds it; offsets = \"none\" or more "
                     "utterances give the targets their own level")
    for ch in spec.channels:  # the fit leaves out utterances without a valid sample of the channel
        measured = {lab for u in utterances if ch in u.valid and u.valid[ch].any() for lab in u.labels}
        lost = sorted({lab for u in utterances for lab in u.labels} - measured)
        if lost:
            notes.append(f"{ch}: phoneme(s) {' '.join(lost)} occur only in utterances with no valid {ch} sample: no "
                         f"measured sample lies within their reach, so they are not fitted and the table has no "
                         f"{ch} for them; mask fewer samples ([corpus] max_gap) or add recordings that carry them")
    c = spec.choose
    if c is not None:
        from coartic.fit.data import group_of

        groups = sorted({group_of(u, c.group, spec) for u in utterances})
        if len(groups) < 2:
            raise SpecError.at(spec.path, "choose", f"group = {c.group!r}: the {n} training utterance(s) form "
                               f"{len(groups)} {c.group} group, and choosing {c.key} by cross-validation needs "
                               "at least two (fit on some, score on the others); set the value in the spec, or "
                               "compare values on recordings held out by hand (coartic compare --vary "
                               f"{c.key}=V1,V2 with a [validate] split), or add recordings")
        if len(groups) == 2 or min(c.folds, len(groups)) == 2:
            notes.append(f"[choose] group = {c.group!r}: two folds only, each fitting on half the training data; "
                         f"the choice of {c.key} rests on two held-out RMSEs"
                         + (" and the one-SE rule on their spread" if c.rule == "1se" else ""))
    return notes
