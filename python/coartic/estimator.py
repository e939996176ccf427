"""An estimator-style entry point: ``Coarticulation(...).fit(trials).predict(trials)``, ``.score(trials)``.

A thin layer over the library's one fit and one scorer: ``fit`` is ``coartic.fit.run`` (the fit
``coartic fit`` runs, on trials already loaded, nothing written), ``predict`` is
``coartic.model.evaluate_corpus`` on the fitted table, ``score`` is ``coartic.evaluation.score``'s RMSE.
The settings are a fit spec's (docs/FITTING.md), checked by the same parser, so every mistake is
named as in a spec file.

Trials are ``coartic.model.Utterance`` objects (labels, segment times, sample times, observed
channels), or the path of a manifest CSV, read as a fit spec's ``[corpus] manifest``.

>>> import numpy as np
>>> from coartic import Coarticulation
>>> from coartic.fit.simulate import vcv_utterances   # /aCa/, /iCi/ made by the model, 0.1 mm noise
>>> trials = vcv_utterances(np.random.default_rng(0), repetitions=2)
>>> model = Coarticulation(variant="modified", dominance="centre", handover=False,   # the model they are made with
...                        channels=["LLO"], staging=False, free=["target", "alpha", "theta_bw", "theta_fw", "k_r"],
...                        spec={"model": {"pauses": "one"}, "parameters": {"target_prior": "none"}})
>>> sorted(model.fit(trials[::2]).table_.phonemes)
['#', 'a', 'i', 'l', 'p', 't']
>>> round(model.score(trials[1::2]), 2)   # RMSE (mm) on the trials it did not see
0.1
>>> model.predict(trials[1:2])[0]["LLO"].shape == trials[1].times.shape
True
>>> model.result_.to_dataframe().query("phoneme == 'p' and parameter == 'k_r'")["value"].round(1).tolist()
[1.0]
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.errors import CoarticError, UsageError
from coartic.fit.result import FitResult
from coartic.fit.spec import FitSpec, load_spec, parse_spec
from coartic.model import Utterance, evaluate_corpus, utterances_for_table
from coartic.table import ParameterTable

Trials = Sequence[Utterance] | str | Path
# what a spec built from keyword settings is called in error messages
SETTINGS_NAME = Path("<Coarticulation settings>")


class NotFittedError(CoarticError, RuntimeError):
    """``predict`` or ``score`` before ``fit``."""


class Coarticulation:
    """The coarticulation model as an estimator: settings now, data at ``fit``.

    ``variant``, ``channels`` and any other ``[model]`` key of a fit spec (``reference_phoneme``,
    ``dominance``, ``plateau_fraction``, ``fit_beta``, ``speakers``, ...) as keywords; ``free``
    is ``[parameters] free``, ``engine`` ``[engine] name``, ``staging`` ``[staging] enabled``;
    ``spec`` adds whole sections as a fit spec's TOML document would (``{"parameters": {"bounds":
    ...}, "tie": [...]}``). ``Coarticulation.from_spec(path)`` takes a spec file as it is.

    After ``fit``: ``result_`` (``coartic.fit.result.FitResult``: statistics, ``to_dataframe()``)
    and ``table_`` (``coartic.table.ParameterTable``: ``save``, ``to_dataframe()``).
    """

    def __init__(self, variant: str = "modified", channels: Sequence[str] = ("LLO",), *,
                 free: Sequence[str] | None = None, engine: str | None = None, staging: bool | None = None,
                 spec: dict[str, Any] | None = None, **model: Any) -> None:
        doc: dict[str, Any] = {k: (dict(v) if isinstance(v, dict) else v) for k, v in (spec or {}).items()}
        doc.setdefault("name", "Coarticulation")
        # the trials come to fit(); the spec parser needs a corpus, which is never read
        doc.setdefault("corpus", {"manifest": "<trials given to fit>"})
        doc["model"] = {**doc.get("model", {}), "variant": variant, "channels": list(channels), **model}
        if free is not None:
            doc["parameters"] = {**doc.get("parameters", {}), "free": list(free)}
        if engine is not None:
            doc["engine"] = {**doc.get("engine", {}), "name": engine}
        if staging is not None:
            doc["staging"] = {**doc.get("staging", {}), "enabled": staging}
        self.spec: FitSpec = parse_spec(doc, SETTINGS_NAME)  # SpecError names the key, as for a file
        self.result_: FitResult | None = None
        self.table_: ParameterTable | None = None

    @classmethod
    def from_spec(cls, path: str | Path) -> Coarticulation:
        """The estimator of a fit spec file (its ``[corpus]`` is what ``fit(path_of_manifest)``
        replaces, or is read by ``fit(None)``)."""
        self = cls.__new__(cls)
        self.spec = load_spec(path)
        self.result_ = None
        self.table_ = None
        return self

    @property
    def channels(self) -> tuple[str, ...]:
        return self.spec.channels

    def __repr__(self) -> str:
        state = "fitted" if self.table_ is not None else "not fitted"
        return f"Coarticulation(variant={self.spec.variant!r}, channels={list(self.spec.channels)!r}; {state})"

    # ------------------------------------------------------------------ data

    def trials(self, trials: Trials | None) -> list[Utterance]:
        """Utterances as given, or the trials of a manifest CSV (``None``: ``from_spec``'s own
        corpus), read with the spec's label map, role map and gap setting."""
        from coartic.fit.data import load_utterances

        if trials is None:
            return load_utterances(self.spec)
        if isinstance(trials, (str, Path)):
            return load_utterances(self.spec.with_options(corpus=replace(self.spec.corpus, manifest=Path(trials),
                                                                         files=(), labels=())))
        utts = list(trials)
        bad = [type(u).__name__ for u in utts if not isinstance(u, Utterance)]
        if bad:
            raise UsageError(f"trials: expected coartic.model.Utterance objects or a manifest path, got {bad[0]}")
        if not utts:
            raise UsageError("trials: no trial given")
        return utts

    def _fitted(self) -> ParameterTable:
        if self.table_ is None:
            raise NotFittedError("this Coarticulation is not fitted yet: call fit(trials) first")
        return self.table_

    # ------------------------------------------------------------------ estimator

    def fit(self, trials: Trials | None) -> Coarticulation:
        """Fit every channel on ``trials`` with ``coartic.fit.run`` (nothing is written; a ``[choose]``
        setting chosen by ``coartic.evaluation.choose.cross_validate`` on them); returns self. Raises
        ``coartic.fit.runner.FitFailed`` when an engine fails, naming the channel."""
        from coartic.evaluation.choose import cross_validate
        from coartic.fit.runner import run

        result = run(self.spec, utterances=self.trials(trials), quiet=True, choose=cross_validate)
        self.result_, self.table_ = result, result.table()
        return self

    def predict(self, trials: Trials) -> list[dict[str, NDArray[np.float64]]]:
        """Per trial, each channel's model trajectory at the trial's sample times (mm)."""
        table = self._fitted()
        # the labels as the table reads them (the pause postures it was fitted with), as score does
        utts = utterances_for_table(table, self.trials(trials))
        per_channel = {ch: evaluate_corpus(table, ch, utts) for ch in self.channels}
        return [{ch: per_channel[ch][i] for ch in self.channels} for i in range(len(utts))]

    def score(self, trials: Trials, channel: str | None = None) -> float:
        """RMSE (mm) of the predictions against the trials' observed samples, over every valid
        sample of every channel (or of ``channel``): lower is better, unlike scikit-learn's
        ``score``. The details per channel, utterance and phoneme: ``score_report``."""
        report = self.score_report(trials)
        rows = [r for r in report.channel_rows() if channel is None or r["channel"] == channel]
        if not rows:
            raise UsageError(f"channel {channel!r}: not fitted (channels: {', '.join(self.channels)})")
        n = sum(r["samples"] for r in rows)
        return math.sqrt(sum(r["rmse_mm"] ** 2 * r["samples"] for r in rows) / n) if n else math.nan

    def score_report(self, trials: Trials) -> Any:
        """``coartic.evaluation.score.Score`` of the fitted table on ``trials`` (RMSE per channel,
        utterance and phoneme, with and without offsets; ``save`` writes what ``coartic score`` does)."""
        from coartic.evaluation.score import score_utterances

        return score_utterances(self._fitted(), self.trials(trials), channels=self.channels)


__all__ = ["Coarticulation", "NotFittedError"]
