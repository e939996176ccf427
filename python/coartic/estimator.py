"""An estimator-style entry point: ``Coarticulation(settings).fit(trials).predict(trials)``, ``.score(trials)``.

A thin layer over the library's one fit and one scorer: ``fit`` is ``coartic.fit.run`` (the fit
``coartic fit`` runs, on trials already loaded, nothing written), ``predict`` is
``coartic.model.evaluate_corpus`` on the fitted table, ``score`` is ``coartic.evaluation.score``'s RMSE.
The settings are estimation's (``coartic.estimation.settings``: the model, the parameters' freedom
and bounds, priors and pooling, offsets, speakers and emotions), built in Python as lmfit's
``Parameters`` are; the fit's own options (channels, engine, staging, starts) are keywords. Both are
checked as a spec file is, so a mistake is named by the key a spec file would have
(``Coarticulation.from_spec`` takes a spec file instead).

Trials are ``coartic.model.Utterance`` objects (labels, segment times, sample times, observed
channels), or the path of a manifest CSV, read as a fit spec's ``[corpus] manifest``.

>>> import numpy as np
>>> from coartic import Coarticulation
>>> from coartic.estimation.settings import EstimationSettings, ModelSettings, ParameterSettings, PriorSettings
>>> from coartic.fit.simulate import vcv_utterances   # /aCa/, /iCi/ made by the model, 0.1 mm noise
>>> trials = vcv_utterances(np.random.default_rng(0), repetitions=2)
>>> settings = EstimationSettings(
...     model=ModelSettings(dominance="centre", handover=False, pauses="one"),   # the model they are made with
...     parameters=ParameterSettings(free=("target", "alpha", "theta_bw", "theta_fw", "k_r")),
...     priors=PriorSettings(target_prior=None, pooled=()))
>>> model = Coarticulation(settings, channels=["LLO"], staging={"enabled": False})
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
from coartic.estimation.settings import EstimationSettings
from coartic.fit.result import FitResult
from coartic.fit.spec import CorpusSpec, FitSpec, load_spec
from coartic.model import Utterance, evaluate_corpus, utterances_for_table
from coartic.table import ParameterTable

Trials = Sequence[Utterance] | str | Path
# what settings built in Python are called in error messages (a spec file's are named by its path)
SETTINGS_NAME = Path("<Coarticulation settings>")


class NotFittedError(CoarticError, RuntimeError):
    """``predict`` or ``score`` before ``fit``."""


class Coarticulation:
    """The coarticulation model as an estimator: settings now, data at ``fit``.

    ``settings`` (``coartic.estimation.settings.EstimationSettings``; default: a spec's defaults) say
    what is estimated; ``channels`` which channels are fitted; ``fit`` takes any other option of a
    fit spec's ``[engine]``, ``[staging]``, ``[fit]``, ``[gaps]`` and ``[validate]`` as
    ``FitSpec.with_options`` does: a section as a table of its keys (``engine={"name": "nlopt"}``,
    ``staging={"enabled": False}``) or its class (``coartic.fit.spec.StagingSection``), or one
    setting by its name (``starts``, ``seed``, ``probe``, ``keep``, ``include_start``, ``max_gap``).
    ``Coarticulation.from_spec(path)`` takes a spec file as it is.

    After ``fit``: ``result_`` (``coartic.fit.result.FitResult``: statistics, ``to_dataframe()``)
    and ``table_`` (``coartic.table.ParameterTable``: ``save``, ``to_dataframe()``).
    """

    def __init__(self, settings: EstimationSettings | None = None, channels: Sequence[str] = ("LLO",),
                 **fit: Any) -> None:
        if settings is not None and not isinstance(settings, EstimationSettings):
            raise UsageError(f"settings: expected coartic.estimation.settings.EstimationSettings, got "
                             f"{type(settings).__name__}")
        settings = settings or EstimationSettings()
        # checked as a spec file is: SpecError names the key a file would have
        path = SETTINGS_NAME if settings.source is None else Path(settings.source)
        self.spec: FitSpec = FitSpec.from_settings(settings, path, "Coarticulation",
                                                   channels=tuple(channels), **fit)
        self.result_: FitResult | None = None
        self.table_: ParameterTable | None = None

    @property
    def settings(self) -> EstimationSettings:
        """The estimation settings (a spec file's, with ``from_spec``)."""
        return self.spec.estimation_settings()

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
        return f"Coarticulation(variant={self.spec.model.variant!r}, channels={list(self.spec.channels)!r}; {state})"

    # ------------------------------------------------------------------ data

    def trials(self, trials: Trials | None) -> list[Utterance]:
        """Utterances as given, or the trials of a manifest CSV (``None``: ``from_spec``'s own
        corpus), read with the spec's label map, role map and gap setting."""
        from coartic.fit.data import load_utterances

        if trials is None:
            return load_utterances(self.spec)
        if isinstance(trials, (str, Path)):
            own = self.spec.corpus
            corpus = (CorpusSpec(manifest=Path(trials)) if own is None
                      else replace(own, manifest=Path(trials), files=(), labels=()))
            return load_utterances(self.spec.with_options(corpus=corpus))
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
