"""The settings of an estimation problem, as estimation defines them and everyone builds them.

``EstimationSettings`` is what ``coartic.estimation.problem.build_problem`` takes, in four parts:

``ModelSettings``      the model a table records (variant, reference phoneme, the channel settings
                       of ``coartic.settings``, β, pauses);
``ParameterSettings``  which parameters are free, their starts and bounds, overrides per phoneme
                       (``Override``), ties (``Tie``), β free or not and its box;
``PriorSettings``      Gaussian priors, the prior noise, the target prior, partial pooling,
                       shrinkage toward class means (``Shrink``);
``GroupSettings``      per-utterance offsets, several speakers, emotions.

A fit spec (``coartic.fit.spec.FitSpec``, one TOML file) is one way to write them
(``FitSpec.estimation_settings``); a Python user builds them directly and hands them to
``coartic.Coarticulation``. The defaults here are a spec's defaults (docs/FITTING.md): a spec
that sets nothing and ``EstimationSettings()`` are the same problem.

Errors in the settings name ``source`` (the spec file, when there is one) and the spec key the
setting is written with (``SpecError``), so a mistake reads the same from a file and from Python.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coartic.pauses import is_pause
from coartic.settings import default
from coartic.table import ChannelSettings

# Starting values of the dynamics; targets start from the data (mean value at the target times).
DEFAULT_START: dict[str, float] = {
    "target": 0.0, "alpha": 1.0, "theta_bw": 30.0, "theta_fw": 30.0, "c_bw": 1.0, "c_fw": 1.0,
    "k_r": 0.5, "sigma": 0.0, "psi": 500.0, "delta": 0.0,
}
# Fitting bounds (natural units). MODEL.md allows (0, inf) for alpha, theta and psi; a fit needs
# finite boxes (global engines search them, and a log transform needs them away from 0), so these
# are wide practical boxes. Target bounds default to the data range widened by `target_margin`.
DEFAULT_FIT_BOUNDS: dict[str, tuple[float, float]] = {
    "alpha": (1e-2, 1e2), "theta_bw": (0.5, 2000.0), "theta_fw": (0.5, 2000.0),
    "c_bw": (0.5, 3.0), "c_fw": (0.5, 3.0), "k_r": (0.0, 1.0), "sigma": (-0.5, 0.5),
    "psi": (10.0, 1e5), "delta": (-0.08, 0.08),
}
DEFAULT_BETA_BOUNDS: tuple[float, float] = (0.05, 20.0)
# The model of a spec that sets nothing: the rate-aware dominance (plateau + handover), each phoneme's
# target, alpha, theta_bw and theta_fw free, the dynamics partially pooled toward one value per
# channel with a pooling strength estimated from the data ([parameters] pooled: empirical Bayes,
# coartic.estimation.pooling; it reaches one shared value when the data do not support more), and
# every target drawn toward the data's own mean over its phoneme's segments with an sd estimated the
# same way ([parameters] target_prior = "estimated"). Measured against one shared theta_bw, theta_fw
# per channel (the previous default) and free per-phoneme dynamics, held out on the synthetic
# session (by rate, and data-starved), its gestures flavour (by rate) and the German EMA (by
# utterance and in time): never the worst of the three, and better than the step model on each
# (bench/real_data.py, docs/REAL_DATA.md "Partial pooling").
DEFAULT_FREE: tuple[str, ...] = ("target", "alpha", "theta_bw", "theta_fw")
DEFAULT_SHARED: tuple[str, ...] = ()
DEFAULT_TARGET_PRIOR: float | str | None = "estimated"
DEFAULT_POOLED: tuple[str, ...] = ("alpha", "theta_bw", "theta_fw")
SPEC_MODEL_DEFAULTS: dict[str, Any] = {"dominance": "plateau", "handover": True}
# The reference phoneme (α = 1) of settings that name none: the first of these the data have, /a/
# first (the paper's), then the other vowels from open to close (ModelSettings.reference_for).
DEFAULT_REFERENCE = "a"
REFERENCE_ORDER: tuple[str, ...] = (DEFAULT_REFERENCE, "E", "O", "e", "o", "i", "u")
# Where the default boxes are written, for the sentences that explain a parameter at a bound.
_DEFAULTS_HOME = "coartic/estimation/settings.py"


@dataclass(frozen=True)
class ModelSettings:
    """The model a fitted table records (spec ``[model]``): ``variant`` "modified" or "original",
    the reference phoneme (α = 1; None: chosen from the data), the channel settings of
    ``coartic.settings`` (apex fraction, edge extent, dominance, plateau fraction, handover), the
    start (or fixed value) of β, and how pauses are labelled ("postures" or "one")."""

    variant: str = "modified"
    reference_phoneme: str | None = None
    apex_fraction: float = default("apex_fraction")
    edge_extent: float = default("edge_extent")
    dominance: str = SPEC_MODEL_DEFAULTS["dominance"]
    plateau_fraction: float = default("plateau_fraction")
    handover: bool = SPEC_MODEL_DEFAULTS["handover"]
    beta: float = default("beta")
    pauses: str = "postures"

    def reference_for(self, phonemes: Sequence[str]) -> str:
        """The reference phoneme (α = 1) of a channel whose data have ``phonemes``: the one
        ``reference_phoneme`` names, else the first of REFERENCE_ORDER the data have (/a/, then the
        other vowels from open to close), else the first non-pause phoneme. α is scale-free, so
        which phoneme holds α = 1 changes no fit, only the scale the others' α are written in."""
        if self.reference_phoneme is not None:
            return self.reference_phoneme
        present = [p for p in phonemes if not is_pause(p)] or list(phonemes)
        return next((p for p in REFERENCE_ORDER if p in present), present[0] if present else DEFAULT_REFERENCE)

    def channel_settings(self, channel: str, beta: float | None = None,
                         phonemes: Sequence[str] | None = None) -> ChannelSettings:
        """The settings a fit of ``channel`` uses and writes into its table (``beta``: the fitted
        value, default this one; ``phonemes``: the channel's, for a reference phoneme left to the
        data). The fit's model options are made from them (``coartic.model.channel_options``), so
        a table evaluates as it was fitted."""
        ref = self.reference_for(phonemes) if phonemes is not None else (self.reference_phoneme or DEFAULT_REFERENCE)
        return ChannelSettings(reference_phoneme=ref, beta=self.beta if beta is None else beta,
                               edge_extent=self.edge_extent, apex_fraction=self.apex_fraction,
                               dominance=self.dominance, plateau_fraction=self.plateau_fraction,
                               handover=self.handover)


@dataclass(frozen=True)
class Override:
    """Per-phoneme (optionally per-channel) changes to which parameters are free, their start and
    bounds (spec ``[[override]]``)."""

    phonemes: tuple[str, ...]
    channels: tuple[str, ...] | None = None  # None: every channel
    fixed: dict[str, float] = field(default_factory=dict)  # fixed at this value
    free: tuple[str, ...] = ()  # made free (even if not in the global list)
    start: dict[str, float] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)

    def applies(self, phoneme: str, channel: str) -> bool:
        return phoneme in self.phonemes and (self.channels is None or channel in self.channels)


@dataclass(frozen=True)
class Tie:
    """Parameters shared by a group of phonemes (spec ``[[tie]]``, e.g. θ and c by place of
    articulation): the first phoneme of the group present in a channel's data carries the value,
    the others take it."""

    phonemes: tuple[str, ...]
    parameters: tuple[str, ...]
    channels: tuple[str, ...] | None = None  # None: every channel


@dataclass(frozen=True)
class Shrink:
    """Shrinkage of a class of phonemes toward its class mean (spec ``[[shrink]]``): for each
    parameter, one penalty row per member, ``prior_noise · (v_i − mean_class(v)) / sd`` (v the value,
    or its logarithm with ``log``), the mean over every member present in the channel's data (fixed
    ones count in the mean)."""

    phonemes: tuple[str, ...]
    parameters: tuple[str, ...]
    sd: float
    log: bool = False
    channels: tuple[str, ...] | None = None  # None: every channel
    key: str = "shrink"  # the spec key its errors and reports are named by ("shrink #2")


@dataclass(frozen=True)
class ParameterSettings:
    """Which parameters are free, where they start and the boxes they are fitted in (spec
    ``[parameters]`` free, shared, start, bounds, target_margin; ``[[override]]``, ``[[tie]]``;
    ``[model]`` fit_beta, beta_bounds).

    ``start``: starting values by parameter (``DEFAULT_START`` for the others); the given ones
    (``start_given``, by default every key of ``start``) are checked against the bounds, and a given
    ``target`` replaces the data's targets (a spec's ``start`` holds every parameter, its
    ``start_given`` the keys the file gave). ``bounds``: boxes by parameter (``DEFAULT_FIT_BOUNDS``
    for the others; a ``target`` box replaces the data range widened by ``target_margin`` mm),
    ``channel_bounds`` the boxes of one channel."""

    free: tuple[str, ...] = DEFAULT_FREE
    # free parameters with one value per channel, shared by every phoneme where they are free
    shared: tuple[str, ...] = DEFAULT_SHARED
    fit_beta: bool = False
    start: dict[str, float] = field(default_factory=dict)
    start_given: frozenset[str] | None = None  # None: the keys of start
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    channel_bounds: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    beta_bounds: tuple[float, float] = DEFAULT_BETA_BOUNDS
    target_margin: float = 5.0  # mm beyond the observed range for the default target box
    overrides: tuple[Override, ...] = ()
    ties: tuple[Tie, ...] = ()

    def start_of(self, parameter: str) -> float:
        """The start of ``parameter`` (``"beta"`` is the model's)."""
        return float(self.start.get(parameter, DEFAULT_START[parameter]))

    def box(self, parameter: str) -> tuple[float, float]:
        """The box of ``parameter`` on every channel and phoneme unless a channel bound or an
        override sets another ((-inf, inf) for a target: the data range, ``ParameterSet``)."""
        return self.bounds.get(parameter, DEFAULT_FIT_BOUNDS.get(parameter, (-math.inf, math.inf)))

    @property
    def given(self) -> frozenset[str]:
        """The parameters whose start was given (checked against bounds; a given target is used
        instead of the data's)."""
        return frozenset(self.start) if self.start_given is None else self.start_given

    def bound_source(self, parameter: str) -> str:
        """Where the box of ``parameter`` (or ``"beta"``) comes from when no channel bound or
        override sets it: the spec key that changed it, the data range (targets), or the defaults
        here (``DEFAULT_FIT_BOUNDS``, ``DEFAULT_BETA_BOUNDS``). ``ParameterSet.from_settings`` records
        it for each free entry, so that a parameter at a bound is explained by it
        (coartic.estimation.bounds)."""
        if parameter == "beta":
            return ("[model] beta_bounds" if tuple(self.beta_bounds) != DEFAULT_BETA_BOUNDS
                    else f"the default beta_bounds (DEFAULT_BETA_BOUNDS, {_DEFAULTS_HOME})")
        if parameter == "target" and "target" not in self.bounds:
            return f"the data range widened by [parameters] target_margin = {self.target_margin:g} mm"
        if parameter in self.bounds and tuple(self.bounds[parameter]) != DEFAULT_FIT_BOUNDS.get(parameter):
            return f"[parameters.bounds] {parameter}"
        if parameter in ("alpha", "theta_bw", "theta_fw", "psi"):
            return f"the default box (DEFAULT_FIT_BOUNDS, {_DEFAULTS_HOME}; MODEL.md §1 allows (0, inf))"
        return f"the default box (DEFAULT_FIT_BOUNDS, {_DEFAULTS_HOME}; MODEL.md §1's default bounds)"


@dataclass(frozen=True)
class PriorSettings:
    """Priors and pooling (spec ``[parameters]`` prior, prior_noise, target_prior, pooled;
    ``[[shrink]]``): Gaussian priors ``"parameter"`` (every phoneme), ``"phoneme.parameter"`` or
    ``"beta"`` -> (mean, sd, on log values), weighed against ``prior_noise`` (mm); ``target_prior``
    None, "estimated" or the sd (mm) of every free target around its phoneme's mean in the data;
    ``pooled`` the free parameters drawn toward one value per channel with an sd estimated from the
    data (coartic.estimation.pooling); ``shrinks`` classes shrunk toward their means."""

    priors: dict[str, tuple[float, float, bool]] = field(default_factory=dict)
    prior_noise: float = 1.0
    target_prior: float | str | None = DEFAULT_TARGET_PRIOR
    pooled: tuple[str, ...] = DEFAULT_POOLED
    shrinks: tuple[Shrink, ...] = ()


@dataclass(frozen=True)
class GroupSettings:
    """Structure across utterances (spec ``[model]`` offsets, speakers, emotions): per-utterance
    offsets ("none", "free" or their sd in mm); several speakers ("none", "offset", "offset_scale" or
    "targets"), read from the utterances' ``speaker_column``; emotions ("none" or "targets"), read
    from ``emotion_column``, ``neutral_emotion`` the reference."""

    offsets: str | float = "none"
    speakers: str = "none"
    speaker_column: str = "speaker"
    emotions: str = "none"
    emotion_column: str = "emotion"
    neutral_emotion: str = "neutral"

    @property
    def offset_sd(self) -> float | None:
        """The offsets' sd τ (mm): None without offsets, inf when free."""
        if isinstance(self.offsets, str):
            return float("inf") if self.offsets == "free" else None
        return float(self.offsets)


@dataclass(frozen=True)
class EstimationSettings:
    """Everything ``build_problem`` needs besides the data: the model, the parameters' freedom and
    bounds, priors and pooling, and the groups (offsets, speakers, emotions). ``source`` is what
    errors name as the file (a spec's path; None when built in Python)."""

    model: ModelSettings = field(default_factory=ModelSettings)
    parameters: ParameterSettings = field(default_factory=ParameterSettings)
    priors: PriorSettings = field(default_factory=PriorSettings)
    groups: GroupSettings = field(default_factory=GroupSettings)
    source: Path | str | None = None

    @property
    def where(self) -> str:
        """What messages call these settings: the spec file, or "the settings"."""
        return "the settings" if self.source is None else str(self.source)


# setting name -> the part of EstimationSettings that holds it (a name is in one part only)
PART_OF: Mapping[str, str] = {
    f.name: part for part, cls in (("model", ModelSettings), ("parameters", ParameterSettings),
                                   ("priors", PriorSettings), ("groups", GroupSettings))
    for f in dataclasses.fields(cls)}
