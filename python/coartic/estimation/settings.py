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

The settings check themselves: each class is a pydantic dataclass whose fields have the checks of
``coartic.estimation.checks`` (the fit spec's, one definition), and construction raises a
``SpecError`` naming the spec key the setting is written with (``ModelSettings(variant="modifed")``:
``[model.variant] 'modifed': expected one of modified, original``; ``EstimationSettings`` adds its
``source``, the spec file when there is one). What no part can check alone (the reference phoneme's
α in a tie, pooled and shared at once, β above its box) is checked by ``EstimationSettings``, with
the function the fit spec calls too (``check_together``). So settings built in Python and handed
straight to ``build_problem`` are refused as a spec file's are, in the same words.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator, ValidationError, model_validator
from pydantic.dataclasses import dataclass

from coartic.errors import SpecError
from coartic.estimation.checks import (ApexFraction, Beta, Bounds, Dominance, EMOTION_MODES, EdgeExtent, Flag,
                                       Handover, LOG_SCALE_PARAMETERS, Number, ParamValues, Parameters, PauseMode,
                                       PlateauFraction, Positive, ReferencePhoneme, SPEAKER_MODES, STRICT, Text,
                                       Variant, _bad, _beta_bounds, _channel_bounds, _channels, _class,
                                       _distinct_params, _group, _names, _offsets, _one_of, _optional, _pooled,
                                       _priors, _shared, _target_prior, key_of, schema_error, spec_errors)
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

# setting -> the spec key it is written with (errors name it): the sections of docs/FITTING.md
SPEC_KEYS: dict[str, str] = {
    **{f: f"model.{f}" for f in ("variant", "reference_phoneme", "apex_fraction", "edge_extent", "dominance",
                                 "plateau_fraction", "handover", "beta", "pauses", "fit_beta", "beta_bounds",
                                 "offsets", "speakers", "speaker_column", "emotions", "emotion_column",
                                 "neutral_emotion")},
    **{f: f"parameters.{f}" for f in ("free", "shared", "start", "bounds", "target_margin", "prior_noise",
                                      "target_prior", "pooled")},
    "start_given": "parameters.start", "channel_bounds": "parameters.bounds", "priors": "parameters.prior",
    "overrides": "override", "ties": "tie", "shrinks": "shrink",
}
# the settings that are lists of tables ([[override]] #N ...)
TABLE_LISTS: tuple[str, ...] = ("overrides", "ties", "shrinks")


def spec_key(loc: Sequence[str | int]) -> str:
    """The spec key of a place in the settings: ("overrides", 2, "fixed") -> "override #3.fixed"."""
    return key_of(loc, SPEC_KEYS, TABLE_LISTS)


def table_keys(part: type) -> list[str]:
    """The keys a ``[[override]]``, ``[[tie]]`` or ``[[shrink]]`` table may have (Shrink's ``log`` is
    ``scale`` there, its ``key`` no key)."""
    names = [f.name for f in dataclasses.fields(part)]
    return [{"log": "scale"}.get(n, n) for n in names if not (part is Shrink and n == "key")]


def _settings_error(e: ValidationError, file: Any, cls: type) -> SpecError:
    # a table built alone is named by its section ([override.free]); the parts by their fields' keys
    root: tuple[str | int, ...] = {"Override": ("override",), "Tie": ("tie",), "Shrink": ("shrink",)}.get(
        cls.__name__, ())
    tables = {"override": Override, "tie": Tie, "shrink": Shrink, "overrides": Override, "ties": Tie,
              "shrinks": Shrink}
    return schema_error(e, file, root, spec_key,
                        lambda loc: table_keys(tables[str(loc[0])]) if loc and str(loc[0]) in tables else None,
                        cls.__name__)


def check_groups(get: Callable[[str], Any]) -> None:
    """Group settings that cannot go together; ``get`` reads a setting by name (the settings' or a
    fit spec's: one check for both)."""
    if get("speakers") != "none" and get("offsets") != "none":
        raise _bad("cannot be combined with [model] offsets yet: choose one", ("speakers",))
    if get("emotions") != "none" and (get("offsets") != "none" or get("speakers") != "none"):
        raise _bad("cannot be combined with [model] offsets or speakers yet: choose one", ("emotions",))


def check_ties_shared(get: Callable[[str], Any]) -> None:
    tied = {q for t in get("ties") for q in t.parameters} & set(get("shared"))
    if tied:
        raise _bad(f"{', '.join(sorted(tied))} is both shared by every phoneme and in a [[tie]]: one or the other",
                   ("shared",))


def check_together(get: Callable[[str], Any]) -> None:
    """What no part of the settings can check alone (the groups, the reference phoneme's α in ties
    and overrides, pooled and shared at once, β above its box), in the order a spec reports them;
    ``get`` reads a setting by name. ``EstimationSettings`` and ``FitSpec`` call it."""
    check_groups(get)
    ref = get("reference_phoneme") or DEFAULT_REFERENCE
    for i, t in enumerate(get("ties")):
        if ref in t.phonemes and "alpha" in t.parameters:
            raise _bad(f"ties alpha of the reference phoneme {ref!r}, which is fixed at 1", ("ties", i),
                       phoneme=ref, parameter="alpha")
    for i, o in enumerate(get("overrides")):
        # alpha is scale-free: the reference phoneme's is 1 by definition (MODEL.md §1)
        if ref in o.phonemes and ("alpha" in o.free or "alpha" in o.start or "alpha" in o.bounds
                                  or o.fixed.get("alpha", 1.0) != 1.0):
            raise _bad(f"sets alpha of the reference phoneme {ref!r}, which is fixed at 1 (alpha is "
                       "scale-free); choose another [model] reference_phoneme to fit it", ("overrides", i),
                       phoneme=ref, parameter="alpha")
    both = set(get("pooled")) & set(get("shared"))
    if both:
        raise _bad(f"{', '.join(sorted(both))} is both shared by every phoneme and pooled: one or the other "
                   "(pooled with its sd estimated reaches shared when the data say so)", ("pooled",))
    check_ties_shared(get)
    beta, beta_bounds = get("beta"), get("beta_bounds")
    if beta > beta_bounds[1]:
        # the model takes any beta >= 0, but past the box a fit may search, rho(u) is gone within a
        # hair of the target: a typo (1e308) must not read as a model that fits badly
        raise _bad(f"beta = {beta:g} is above {beta_bounds[1]:g}, the upper end of [model] beta_bounds "
                   "(the largest beta a fit may reach): lower beta, or widen beta_bounds", ("beta",),
                   parameter="beta", value=beta)


_checked = spec_errors(_settings_error)


@_checked
@dataclass(frozen=True, config=STRICT)
class ModelSettings:
    """The model a fitted table records (spec ``[model]``): ``variant`` "modified" or "original",
    the reference phoneme (α = 1; None: chosen from the data), the channel settings of
    ``coartic.settings`` (apex fraction, edge extent, dominance, plateau fraction, handover), the
    start (or fixed value) of β, and how pauses are labelled ("postures" or "one")."""

    variant: Variant = "modified"
    # α = 1 for it (MODEL.md §1); None: chosen from the data (reference_for)
    reference_phoneme: ReferencePhoneme = None
    # the model's channel settings: defaults and ranges from coartic.settings
    apex_fraction: ApexFraction = default("apex_fraction")
    edge_extent: EdgeExtent = default("edge_extent")
    # the rate-aware options of docs/MODEL.md §2.1
    dominance: Dominance = SPEC_MODEL_DEFAULTS["dominance"]
    plateau_fraction: PlateauFraction = default("plateau_fraction")
    handover: Handover = SPEC_MODEL_DEFAULTS["handover"]
    beta: Beta = default("beta")
    # "postures": initial, final and medial pauses are three rows, short pauses in a closure join
    # it (coartic.pauses); "one": every pause is '#'
    pauses: PauseMode = "postures"

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


@_checked
@dataclass(frozen=True, config=STRICT)
class Override:
    """Per-phoneme (optionally per-channel) changes to which parameters are free, their start and
    bounds (spec ``[[override]]``)."""

    phonemes: Annotated[tuple[str, ...], BeforeValidator(_names)]
    channels: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_channels))] = None  # None: every channel
    fixed: ParamValues = field(default_factory=dict)  # fixed at this value
    free: Parameters = ()  # made free (even if not in the global list)
    start: ParamValues = field(default_factory=dict)
    bounds: Bounds = field(default_factory=dict)

    def applies(self, phoneme: str, channel: str) -> bool:
        return phoneme in self.phonemes and (self.channels is None or channel in self.channels)


@_checked
@dataclass(frozen=True, config=STRICT)
class Tie:
    """Parameters shared by a group of phonemes (spec ``[[tie]]``, e.g. θ and c by place of
    articulation): the first phoneme of the group present in a channel's data carries the value,
    the others take it."""

    phonemes: Annotated[tuple[str, ...], BeforeValidator(_group)]
    parameters: Parameters
    channels: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_channels))] = None  # None: every channel


@_checked
@dataclass(frozen=True, config=STRICT)
class Shrink:
    """Shrinkage of a class of phonemes toward its class mean (spec ``[[shrink]]``): for each
    parameter, one penalty row per member, ``prior_noise · (v_i − mean_class(v)) / sd`` (v the value,
    or its logarithm with ``log``), the mean over every member present in the channel's data (fixed
    ones count in the mean). In a spec, ``scale = "log"`` is ``log = true``."""

    phonemes: Annotated[tuple[str, ...], BeforeValidator(_class)]
    parameters: Annotated[tuple[str, ...], BeforeValidator(_distinct_params)]
    sd: Positive
    log: Flag = False
    channels: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_channels))] = None  # None: every channel
    key: str = "shrink"  # the spec key its errors and reports are named by ("shrink #2")

    @model_validator(mode="before")
    @classmethod
    def _scale(cls, data: Any) -> Any:
        if isinstance(data, Mapping) and "scale" in data:
            data = dict(data)
            scale = data.pop("scale")
            if scale not in ("natural", "log"):
                raise _bad(f"{scale!r}: expected \"natural\" or \"log\"", ("scale",))
            data["log"] = scale == "log"
        return data

    @model_validator(mode="after")
    def _log_scale(self) -> Shrink:
        bad = [p for p in self.parameters if p not in LOG_SCALE_PARAMETERS]
        if self.log and bad:
            raise _bad(f"log scale needs positive parameters ({', '.join(LOG_SCALE_PARAMETERS[:-1])}), "
                       f"not {bad}: shrink those in another [[shrink]] on the natural scale", ("scale",))
        return self


@_checked
@dataclass(frozen=True, config=STRICT)
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

    free: Parameters = DEFAULT_FREE
    # free parameters with one value per channel, shared by every phoneme where they are free
    shared: Annotated[tuple[str, ...], BeforeValidator(_shared)] = DEFAULT_SHARED
    fit_beta: Flag = False
    start: ParamValues = field(default_factory=dict)
    start_given: frozenset[str] | None = None  # None: the keys of start
    bounds: Bounds = field(default_factory=dict)
    channel_bounds: Annotated[dict[str, dict[str, tuple[float, float]]], BeforeValidator(_channel_bounds)] = field(
        default_factory=dict)
    beta_bounds: Annotated[tuple[float, float], BeforeValidator(_beta_bounds)] = DEFAULT_BETA_BOUNDS
    target_margin: Number = 5.0  # mm beyond the observed range for the default target box
    overrides: tuple[Override, ...] = ()
    ties: tuple[Tie, ...] = ()

    @model_validator(mode="after")
    def _consistent(self) -> ParameterSettings:
        check_ties_shared(lambda name: getattr(self, name))
        return self

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


@_checked
@dataclass(frozen=True, config=STRICT)
class PriorSettings:
    """Priors and pooling (spec ``[parameters]`` prior, prior_noise, target_prior, pooled;
    ``[[shrink]]``): Gaussian priors ``"parameter"`` (every phoneme), ``"phoneme.parameter"`` or
    ``"beta"`` -> (mean, sd, on log values), weighed against ``prior_noise`` (mm); ``target_prior``
    None, "estimated" or the sd (mm) of every free target around its phoneme's mean in the data;
    ``pooled`` the free parameters drawn toward one value per channel with an sd estimated from the
    data (coartic.estimation.pooling); ``shrinks`` classes shrunk toward their means."""

    priors: Annotated[dict[str, tuple[float, float, bool]], BeforeValidator(_priors)] = field(default_factory=dict)
    prior_noise: Positive = 1.0
    target_prior: Annotated[float | str | None, BeforeValidator(_target_prior)] = DEFAULT_TARGET_PRIOR
    pooled: Annotated[tuple[str, ...], BeforeValidator(_pooled)] = DEFAULT_POOLED
    shrinks: tuple[Shrink, ...] = ()


@_checked
@dataclass(frozen=True, config=STRICT)
class GroupSettings:
    """Structure across utterances (spec ``[model]`` offsets, speakers, emotions): per-utterance
    offsets ("none", "free" or their sd in mm); several speakers ("none", "offset", "offset_scale" or
    "targets"), read from the utterances' ``speaker_column``; emotions ("none" or "targets"), read
    from ``emotion_column``, ``neutral_emotion`` the reference."""

    offsets: Annotated[str | float, BeforeValidator(_offsets)] = "none"
    speakers: Annotated[str, BeforeValidator(_one_of(SPEAKER_MODES))] = "none"
    speaker_column: Text = "speaker"
    emotions: Annotated[str, BeforeValidator(_one_of(EMOTION_MODES))] = "none"
    emotion_column: Text = "emotion"
    neutral_emotion: Text = "neutral"

    @model_validator(mode="after")
    def _consistent(self) -> GroupSettings:
        check_groups(lambda name: getattr(self, name))
        return self

    @property
    def offset_sd(self) -> float | None:
        """The offsets' sd τ (mm): None without offsets, inf when free."""
        if isinstance(self.offsets, str):
            return float("inf") if self.offsets == "free" else None
        return float(self.offsets)


@spec_errors(_settings_error, "source")
@dataclass(frozen=True, config=STRICT)
class EstimationSettings:
    """Everything ``build_problem`` needs besides the data: the model, the parameters' freedom and
    bounds, priors and pooling, and the groups (offsets, speakers, emotions). ``source`` is what
    errors name as the file (a spec's path; None when built in Python)."""

    model: ModelSettings = field(default_factory=ModelSettings)
    parameters: ParameterSettings = field(default_factory=ParameterSettings)
    priors: PriorSettings = field(default_factory=PriorSettings)
    groups: GroupSettings = field(default_factory=GroupSettings)
    source: Path | str | None = None

    @model_validator(mode="after")
    def _consistent(self) -> EstimationSettings:
        check_together(lambda name: getattr(getattr(self, PART_OF[name]), name))
        return self

    @property
    def where(self) -> str:
        """What messages call these settings: the spec file, or "the settings"."""
        return "the settings" if self.source is None else str(self.source)


# setting name -> the part of EstimationSettings that holds it (a name is in one part only)
PART_OF: Mapping[str, str] = {
    f.name: part for part, cls in (("model", ModelSettings), ("parameters", ParameterSettings),
                                   ("priors", PriorSettings), ("groups", GroupSettings))
    for f in dataclasses.fields(cls)}
