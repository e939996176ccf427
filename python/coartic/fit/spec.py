"""The fit specification: a TOML file (``fit/*.toml``) describing one least-squares fit.

Every path in a spec is relative to the spec file. Every error names the spec file and the key at
fault, e.g. ``fit/synthetic.toml: [engine.name] 'foo': unknown engine (scipy, nlopt, casadi)``, and
carries the place as attributes (``SpecError``: file, section, entry, key, phoneme, parameter).

The spec is a typed schema (pydantic v2 dataclasses, chosen by measurement: docs/FITTING.md, "The
spec schema"; ``bench/spec_schema.py``): ``FitSpec`` and its parts check their own fields on every
construction, so ``FitSpec.with_options`` and ``dataclasses.replace`` re-validate what they change
as loading a file does. The TOML document maps onto ``FitSpec`` through one table, ``DOCUMENT``
(section, key -> field), read both ways: to build the fields and to name a field's error by the key
the user wrote. The model's channel settings (default, range, meaning) come from
``coartic.settings``, the parameters' domains from ``coartic.table.MODEL_DOMAIN``.

See ``fit/template.toml`` for a commented example of every key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator, ValidationError, model_validator
from pydantic.dataclasses import dataclass
from pydantic_core import ArgsKwargs

from coartic.errors import SpecError
from coartic.estimation import settings as est
from coartic.estimation.checks import (ApexFraction, Beta, Bounds, Channels, Dominance, EMOTION_MODES, EdgeExtent,
                                       Flag, Handover, LOG_SCALE_PARAMETERS, Names, Number, ParamValues, Parameters,
                                       PauseMode, PlateauFraction, Positive, ReferencePhoneme, SPEAKER_MODES, STRICT,
                                       Text, Variant, _bad, _beta_bounds, _channel_bounds, _count, _number, _offsets,
                                       _one_of, _optional, _params_or_beta, _pooled, _priors, _shared, _target_prior,
                                       key_of, schema_error, spec_errors)
from coartic.estimation.settings import (DEFAULT_BETA_BOUNDS, DEFAULT_FIT_BOUNDS, DEFAULT_FREE, DEFAULT_POOLED,
                                         DEFAULT_SHARED, DEFAULT_START, DEFAULT_TARGET_PRIOR, SPEC_MODEL_DEFAULTS,
                                         EstimationSettings, GroupSettings, ModelSettings, ParameterSettings,
                                         PriorSettings, check_together, table_keys)
from coartic.io.errors import DataError
from coartic.io.roles import RoleMap
from coartic.settings import CHANNEL_SETTINGS, default
from coartic.table import CHANNELS, ChannelSettings
from coartic.textfile import TextDecodeError, read_text

ENGINES: tuple[str, ...] = ("scipy", "nlopt", "casadi")
# [validate] group: what a k-fold validation holds out together (manifest columns, or the file).
# "time": each utterance cut at its middle segment, one half fitted, the other held out (both ways)
VALIDATE_GROUPS: tuple[str, ...] = ("utterance", "sentence", "rate", "speaker", "repetition", "time")

DEFAULT_STAGES: tuple[tuple[str, ...], ...] = (
    ("target",),
    ("alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "delta"),
    ("k_r", "sigma", "psi", "beta"),
)
# [fit] defaults: multi-start estimation (coartic.fit.multistart; measured in bench/multistart.py)
DEFAULT_STARTS = 32
# A start is a local fit from its own point, and their Sobol points are drawn at once: a bound that
# turns a typo (10**9) into an error naming it, not a MemoryError hours later.
MAX_STARTS = 10_000
DEFAULT_PROBE = 10  # evaluations per stage in the probe every start gets
# The probe ranks starts before the local fits go on: a probe as long as a local fit's whole budget
# (coartic.fit.engines.evaluation_budget, thousands) is no longer a probe, and 10**9 is a typo.
MAX_PROBE = 10_000

# Settings ``[choose]`` / ``coartic fit --choose`` may choose by cross-validation, and which end of a
# grid is the stronger regularisation (the one-standard-error rule moves toward it): -1 smaller values,
# +1 larger values, 0 no such direction.
CHOOSABLE: dict[str, int] = {"shrink.sd": -1, "prior_noise": +1, "plateau_fraction": 0, "target_prior": -1}
CHOOSE_RULES: tuple[str, ...] = ("min", "1se")



def _stages(v: Any) -> tuple[tuple[str, ...], ...]:
    if not isinstance(v, (list, tuple)) or not v:
        raise _bad("expected a list of parameter lists")
    return tuple(_params_or_beta(st) for st in v)


def _path(v: Any) -> Path:
    if isinstance(v, Path) or (isinstance(v, str) and v):
        return Path(v)
    raise _bad(f"expected a path string, got {v!r}")


def _paths(v: Any) -> tuple[Path, ...]:
    if isinstance(v, (str, Path)):
        return (_path(v),)
    if not isinstance(v, (list, tuple)):
        raise _bad(f"expected a list of path strings, got {v!r}")
    return tuple(_path(p) for p in v)


def _role_map(v: Any) -> dict[str, Any]:
    if not isinstance(v, Mapping) or not all(
            isinstance(x, str) or (k == "axes" and isinstance(x, Mapping)) for k, x in v.items()):
        raise _bad("expected a table role = 'sensor' (and for EMA axes = { vertical = '+z', anterior = '-y' }), "
                   f"got {v!r}")
    try:  # the role map's own checks (roles, axes, one marker per role), named by the spec key
        RoleMap.from_dict(v, "role map")
    except DataError as bad:
        raise _bad(str(bad)) from None
    return dict(v)


def _select(v: Any) -> dict[str, tuple[str, ...]]:
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table column = [values], got {v!r}")
    return {k: tuple(str(x) for x in (x if isinstance(x, (list, tuple)) else [x])) for k, x in v.items()}


def _table(v: Any) -> dict[str, Any]:
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table, got {v!r}")
    return dict(v)


SpecPath = Annotated[Path, BeforeValidator(_path)]

_STRICT = STRICT


def _fit_error(e: ValidationError, file: Any, cls: type) -> SpecError:
    return spec_error(e, file, _ROOTS.get(cls.__name__, ()))


# Construction (and ``dataclasses.replace``) raises SpecError, named like a spec's own errors,
# instead of pydantic's ValidationError: every coartic error is a CoarticError.
_spec_errors = spec_errors(_fit_error, "path")  # a FitSpec names its file


# --------------------------------------------------------------------------- the schema


# [[override]], [[tie]] and [[shrink]] are estimation's own classes, which check themselves
# (coartic.estimation.settings): a spec's table and one built in Python are checked alike.
Override = est.Override
Tie = est.Tie
Shrink = est.Shrink


def _grid(v: Any) -> tuple[float, ...]:
    if not isinstance(v, (list, tuple)) or len(v) < 2:
        raise _bad(f"expected a list of two values or more, got {v!r}")
    vals = tuple(_number(x) for x in v)
    if len(set(vals)) != len(vals):
        raise _bad(f"repeated values in {list(vals)}")
    return tuple(sorted(vals))


@_spec_errors
@dataclass(frozen=True, config=_STRICT)
class Choose:
    """``[choose]``: a setting chosen by k-fold cross-validation on the training data."""

    key: Annotated[str, BeforeValidator(lambda v: _choose_key(v))]  # "shrink.sd", "shrink #2.sd", ...
    values: Annotated[tuple[float, ...], BeforeValidator(_grid)]
    group: Annotated[str, BeforeValidator(_one_of(VALIDATE_GROUPS))] = "utterance"  # what a fold holds out
    folds: Annotated[int, BeforeValidator(_count(2))] = 5
    rule: Annotated[str, BeforeValidator(_one_of(CHOOSE_RULES))] = "1se"  # "min" or "1se" (strongest within 1 SE)

    @model_validator(mode="after")
    def _values_of_key(self) -> Choose:
        base = choose_base(self.key)
        setting = CHANNEL_SETTINGS.get(str(base))
        if setting is not None and any(setting.problem(v) for v in self.values):
            raise _bad(f"{base} takes values in {setting.allowed}, got {list(self.values)}", ("values",))
        if setting is None and any(not math.isfinite(v) or v <= 0 for v in self.values):
            raise _bad(f"{self.key} takes positive numbers, got {list(self.values)}", ("values",))
        if self.rule == "1se" and CHOOSABLE[str(base)] == 0:
            raise _bad(f"\"1se\" needs a regularisation strength (shrink.sd, prior_noise, target_prior); {self.key} has no "
                       "stronger end: use rule = \"min\"", ("rule",))
        return self


def _choose_key(v: Any) -> str:
    if not isinstance(v, str):
        raise _bad(f"expected a setting name, got {v!r}")
    if choose_base(v) is None:
        raise _bad(f"{v!r}: not a setting cross-validation can choose (known: {', '.join(CHOOSABLE)}, or "
                   "\"shrink #N.sd\" for one [[shrink]])")
    return v


def _label_map(v: Any) -> str | None:
    if v is not None and not isinstance(v, str):
        raise _bad(f"expected a name or path, got {v!r}")
    return v


@_spec_errors
@dataclass(frozen=True, config=_STRICT)
class CorpusSpec:
    manifest: Annotated[Path | None, BeforeValidator(_optional(_path))] = None
    files: Annotated[tuple[Path, ...], BeforeValidator(_paths)] = ()
    labels: Annotated[tuple[Path, ...], BeforeValidator(_paths)] = ()
    file_column: Text = "file"  # manifest column holding the data file
    label_map: Annotated[str | None, BeforeValidator(_label_map)] = None  # a label-map name or path; None: model phonemes
    # role -> marker/sensor name; EMA: "axes" = {vertical, anterior}
    role_map: Annotated[dict[str, Any] | None, BeforeValidator(_optional(_role_map))] = None
    select: Annotated[dict[str, tuple[str, ...]], BeforeValidator(_select)] = dataclasses.field(
        default_factory=dict)  # manifest column -> kept values
    limit: Annotated[int | None, BeforeValidator(_optional(_count(1)))] = None  # only the first N trials (quick looks)

    @model_validator(mode="after")
    def _files_or_manifest(self) -> CorpusSpec:
        if self.manifest is None and not self.files:
            raise _bad("give either manifest = 'path/manifest.csv' or files = [...]")
        if self.manifest is not None and self.files:
            raise _bad("give manifest or files, not both")
        # No labels at all: every file carries its own (an EMU bundle, a Haskins .mat); the loader
        # names the first that does not.
        if self.files and self.labels and len(self.labels) != len(self.files):
            raise _bad(f"{len(self.labels)} label files for {len(self.files)} data files (give one per "
                       "file, or none when every file carries its own labels)", ("labels",))
        return self


@_spec_errors
@dataclass(frozen=True, config=_STRICT)
class FitSpec:
    path: Path  # the spec file (errors and relative paths refer to it)
    name: Text
    # where the trials are read from; None: they are given in Python (coartic.Coarticulation.fit)
    corpus: CorpusSpec | None
    channels: Channels = CHANNELS
    variant: Variant = "modified"
    # α = 1 for it (MODEL.md §1); None: chosen from the data (FitSpec.reference_for)
    reference_phoneme: ReferencePhoneme = None
    # the model's channel settings: defaults and ranges from coartic.settings
    apex_fraction: ApexFraction = default("apex_fraction")
    edge_extent: EdgeExtent = default("edge_extent")
    # the rate-aware options of docs/MODEL.md §2.1 (defaults: today's model)
    dominance: Dominance = SPEC_MODEL_DEFAULTS["dominance"]
    plateau_fraction: PlateauFraction = default("plateau_fraction")
    handover: Handover = SPEC_MODEL_DEFAULTS["handover"]
    beta: Beta = default("beta")
    fit_beta: Flag = False
    beta_bounds: Annotated[tuple[float, float], BeforeValidator(_beta_bounds)] = DEFAULT_BETA_BOUNDS
    free: Parameters = DEFAULT_FREE
    # free parameters with one value per channel, shared by every phoneme where they are free
    shared: Annotated[tuple[str, ...], BeforeValidator(_shared)] = DEFAULT_SHARED
    # sd (mm) of a Gaussian prior drawing every free target toward the mean of the channel over its
    # phoneme's segments in the fitted data (the step model's value); None: no such prior
    target_prior: Annotated[float | str | None, BeforeValidator(_target_prior)] = DEFAULT_TARGET_PRIOR
    # free parameters drawn toward one value per channel with an sd estimated from the data
    # (partial pooling, coartic.estimation.pooling)
    pooled: Annotated[tuple[str, ...], BeforeValidator(_pooled)] = DEFAULT_POOLED
    start_table: Annotated[Path | None, BeforeValidator(_optional(_path))] = None  # start values from a table JSON
    start: ParamValues = dataclasses.field(default_factory=lambda: dict(DEFAULT_START))
    # Gaussian priors (penalties in least squares): "parameter" (every phoneme) or "phoneme.parameter"
    # (or "beta") -> (mean, sd, on log values); weighed against prior_noise (mm)
    priors: Annotated[dict[str, tuple[float, float, bool]], BeforeValidator(_priors)] = dataclasses.field(
        default_factory=dict)
    prior_noise: Positive = 1.0
    # per-utterance offsets in least squares: "none", "free" or their sd (mm)
    offsets: Annotated[str | float, BeforeValidator(_offsets)] = "none"
    # several speakers in one fit: "none", "offset" (a_s + F), "offset_scale" (a_s + b_s·F) or
    # "targets" (own targets per speaker), the speaker read from the manifest column speaker_column;
    # shared dynamics
    speakers: Annotated[str, BeforeValidator(_one_of(SPEAKER_MODES))] = "none"
    speaker_column: Text = "speaker"
    # "postures": initial, final and medial pauses are three rows, short pauses in a closure join
    # it (coartic.pauses); "one": every pause is '#'
    pauses: PauseMode = "postures"
    # emotion as a factor of the fit: "none", or "targets" (each emotion's targets a deviation from the
    # neutral ones, shrunk toward them by a scale the data estimate: coartic.estimation.emotions), the
    # emotion read from the manifest column emotion_column, neutral_emotion the reference
    emotions: Annotated[str, BeforeValidator(_one_of(EMOTION_MODES))] = "none"
    emotion_column: Text = "emotion"
    neutral_emotion: Text = "neutral"
    start_given: frozenset[str] = frozenset()  # the [parameters.start] keys the spec gives (checked against bounds)
    bounds: Bounds = dataclasses.field(default_factory=lambda: dict(DEFAULT_FIT_BOUNDS))
    channel_bounds: Annotated[dict[str, dict[str, tuple[float, float]]], BeforeValidator(_channel_bounds)] = \
        dataclasses.field(default_factory=dict)
    target_margin: Number = 5.0  # mm beyond the observed range for the default target box
    overrides: tuple[Override, ...] = ()
    ties: tuple[Tie, ...] = ()
    shrinks: tuple[Shrink, ...] = ()
    choose: Choose | None = None
    engine: Annotated[str, BeforeValidator(_one_of(ENGINES, "unknown engine"))] = "scipy"
    engine_options: Annotated[dict[str, Any], BeforeValidator(_table)] = dataclasses.field(default_factory=dict)
    staging: Flag = True
    stages: Annotated[tuple[tuple[str, ...], ...], BeforeValidator(_stages)] = DEFAULT_STAGES
    # [fit]: global estimation by multi-start (coartic.fit.multistart); starts = 1 is one local fit
    # from [parameters.start]
    starts: Annotated[int, BeforeValidator(_count(1, MAX_STARTS))] = DEFAULT_STARTS
    seed: Annotated[int, BeforeValidator(_count(0))] = 0
    probe: Annotated[int, BeforeValidator(_count(1, MAX_PROBE))] = DEFAULT_PROBE
    # starts continued after the probe (None: multistart.default_keep)
    keep: Annotated[int | None, BeforeValidator(_optional(_count(1)))] = None
    include_start: Flag = True  # start 0 is [parameters.start] (always continued)
    max_gap: Number = 0.05  # s: gaps up to this are interpolated by the reader, longer ones masked
    # k-fold validation by this grouping (VALIDATE_GROUPS)
    validate_group: Annotated[str | None, BeforeValidator(_optional(_one_of(VALIDATE_GROUPS)))] = None
    # None: one fold per group (leave one group out)
    validate_folds: Annotated[int | None, BeforeValidator(_optional(_count(2)))] = None
    holdout_repetition: Annotated[int | None, BeforeValidator(_optional(_count(1)))] = 5  # counted from 1
    train_rate: str | None = "normal"
    test_rate: str | None = "fast"

    @model_validator(mode="after")
    def _consistent(self) -> FitSpec:
        """What no field can check alone."""
        if not self.channels:
            raise _bad("no channel to fit", ("channels",))
        # the estimation settings' own checks across their parts, in their words
        check_together(lambda name: getattr(self, name))
        if self.keep is not None and self.starts > 1 and self.keep > self.starts:
            raise _bad(f"{self.keep}: more than the {self.starts} starts", ("keep",))
        if self.validate_folds is not None and self.validate_group is None:
            raise _bad("needs group = \"utterance\" (or sentence, rate, speaker, repetition)", ("validate_folds",))
        if self.choose is not None:
            problem = _choose_shrinks(self.choose.key, self.shrinks)
            if problem is not None:
                raise _bad(problem, ("choose", "key"))
        return self

    def with_options(self, **changes: Any) -> FitSpec:
        """The spec with ``changes`` (field = value), checked as loading a file checks it: a
        SpecError names the spec file and the key of the field at fault."""
        return dataclasses.replace(self, **changes)

    @property
    def corpus_spec(self) -> CorpusSpec:
        """The ``[corpus]`` the trials are read from; a SpecError when the trials are given in Python
        (a spec built by ``from_settings`` without one)."""
        if self.corpus is None:
            raise SpecError.at(self.path, "corpus", "no corpus to read: the trials are given in Python (pass them "
                               "to fit, or a manifest path)")
        return self.corpus

    @classmethod
    def from_settings(cls, settings: EstimationSettings, path: Path, name: str, corpus: CorpusSpec | None = None,
                      **fields: Any) -> FitSpec:
        """The spec of a fit with these estimation settings (built in Python: ``coartic.Coarticulation``)
        and the fit's own ``fields`` (channels, engine, staging, starts, ...), checked as a spec file
        is: a SpecError names ``path`` and the key each setting is written with in a file."""
        twice = sorted(set(fields) & set(est.PART_OF))
        if twice:
            raise SpecError.at(path, None, f"{', '.join(twice)}: an estimation setting, given in the settings "
                               "(coartic.estimation.settings), not beside them")
        values: dict[str, Any] = {f.name: getattr(part, f.name) for part in (settings.model, settings.parameters,
                                                                           settings.priors, settings.groups)
                                  for f in dataclasses.fields(part)}
        par = settings.parameters

        def tables(items: Sequence[Any]) -> list[dict[str, Any]]:
            # estimation's Override/Tie/Shrink as tables, checked as the file's [[override]] #N ... are
            return [{f.name: getattr(o, f.name) for f in dataclasses.fields(o)} for o in items]

        values.update(start={**DEFAULT_START, **par.start}, start_given=par.given,
                      bounds={**DEFAULT_FIT_BOUNDS, **par.bounds}, overrides=tables(par.overrides),
                      ties=tables(par.ties), shrinks=tables(settings.priors.shrinks))
        # DEFAULT_STARTS read now, as a file's parse reads it (the tests set it to 1)
        return cls(path=path, name=name, corpus=corpus, **values, **{"starts": DEFAULT_STARTS, **fields})

    def estimation_settings(self) -> EstimationSettings:
        """The estimation settings this spec writes (``coartic.estimation.settings``): what
        ``build_problem`` takes; errors in them name this spec file."""
        return EstimationSettings(
            model=ModelSettings(variant=self.variant, reference_phoneme=self.reference_phoneme,
                                apex_fraction=self.apex_fraction, edge_extent=self.edge_extent,
                                dominance=self.dominance, plateau_fraction=self.plateau_fraction,
                                handover=self.handover, beta=self.beta, pauses=self.pauses),
            parameters=ParameterSettings(free=self.free, shared=self.shared, fit_beta=self.fit_beta,
                                         start=self.start, start_given=self.start_given, bounds=self.bounds,
                                         channel_bounds=self.channel_bounds, beta_bounds=self.beta_bounds,
                                         target_margin=self.target_margin, overrides=self.overrides,
                                         ties=self.ties),
            priors=PriorSettings(priors=self.priors, prior_noise=self.prior_noise, target_prior=self.target_prior,
                                 pooled=self.pooled, shrinks=self.shrinks),
            groups=GroupSettings(offsets=self.offsets, speakers=self.speakers, speaker_column=self.speaker_column,
                                 emotions=self.emotions, emotion_column=self.emotion_column,
                                 neutral_emotion=self.neutral_emotion),
            source=self.path)

    def reference_for(self, phonemes: Sequence[str]) -> str:
        """The reference phoneme (α = 1) of a channel whose data have ``phonemes``
        (``ModelSettings.reference_for``)."""
        return self.estimation_settings().model.reference_for(phonemes)

    def channel_settings(self, channel: str, beta: float | None = None,
                         phonemes: Sequence[str] | None = None) -> ChannelSettings:
        """The settings a fit of ``channel`` uses and writes into its table
        (``ModelSettings.channel_settings``)."""
        return self.estimation_settings().model.channel_settings(channel, beta, phonemes)


def _choose_shrinks(key: str, shrinks: tuple[Shrink, ...]) -> str | None:
    """Why a ``[choose]`` key does not fit the spec's ``[[shrink]]`` tables, or None."""
    if choose_base(key) != "shrink.sd":
        return None
    if not shrinks:
        return f"{key!r}: the spec has no [[shrink]] table"
    if key != "shrink.sd" and not any(s.key == key[: -len(".sd")] for s in shrinks):
        return f"{key!r}: no such table (the spec has {len(shrinks)} [[shrink]])"
    return None


# --------------------------------------------------------------------------- the TOML document

# Each section's keys and the FitSpec field each one sets ("" is the top level). [corpus] and
# [choose] are CorpusSpec and Choose (same key names); [[override]], [[tie]], [[shrink]] lists of
# Override, Tie, Shrink. [mcmc] belongs to coartic.mcmc (docs/MCMC.md): one spec file serves both
# commands, so it is accepted here and not read.
DOCUMENT: dict[str, dict[str, str]] = {
    "": {"name": "name"},
    "model": {k: k for k in ("variant", "channels", "reference_phoneme", "apex_fraction", "edge_extent", "beta",
                             "fit_beta", "beta_bounds", "offsets", "dominance", "plateau_fraction", "handover",
                             "speakers", "speaker_column", "pauses", "emotions", "emotion_column",
                             "neutral_emotion")},
    "parameters": {"free": "free", "start": "start", "start_table": "start_table", "bounds": "bounds",
                   "target_margin": "target_margin", "prior": "priors", "prior_noise": "prior_noise",
                   "shared": "shared", "target_prior": "target_prior", "pooled": "pooled"},
    "engine": {"name": "engine", "options": "engine_options"},
    "staging": {"enabled": "staging", "stages": "stages"},
    "fit": {k: k for k in ("starts", "seed", "probe", "keep", "include_start")},
    "gaps": {"max_gap": "max_gap"},
    "validate": {"holdout_repetition": "holdout_repetition", "train_rate": "train_rate", "test_rate": "test_rate",
                 "group": "validate_group", "folds": "validate_folds"},
}
TABLES: dict[str, str] = {"corpus": "corpus", "choose": "choose"}
ARRAYS: dict[str, str] = {"override": "overrides", "tie": "ties", "shrink": "shrinks"}
IGNORED: tuple[str, ...] = ("mcmc",)
# field -> the key its errors are named by (read backwards from the tables above)
FIELD_KEYS: dict[str, str] = {
    **{f: (f"{s}.{k}" if s else k) for s, keys in DOCUMENT.items() for k, f in keys.items()},
    **{f: s for s, f in TABLES.items()}, **{f: s for s, f in ARRAYS.items()},
    "channel_bounds": "parameters.bounds", "start_given": "parameters.start",
}
# the key prefix of a part's own errors when it is built alone (a Choose by --choose, an Override in Python)
# the part of a spec a location's head is
_PARTS: dict[str, type] = {"overrides": Override, "override": Override, "ties": Tie, "tie": Tie, "shrinks": Shrink,
                           "shrink": Shrink, "corpus": CorpusSpec, "choose": Choose, "--choose": Choose}
_ROOTS: dict[str, tuple[str | int, ...]] = {"Choose": ("choose",), "CorpusSpec": ("corpus",), "Override": ("override",),
                                             "Tie": ("tie",), "Shrink": ("shrink",)}


def _unknown(d: Mapping[str, Any], allowed: Iterable[str], key: str, path: Path) -> None:
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise SpecError.at(path, key, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _relative(base: Path, v: Any) -> Any:
    """A path string relative to the spec's folder (anything else is left to the schema's check)."""
    return base / v if isinstance(v, str) and v and not Path(v).is_absolute() else v


def document_fields(raw: Mapping[str, Any], path: Path) -> dict[str, Any]:
    """The FitSpec fields a TOML document sets (unknown keys refused, relative paths made relative
    to ``path``'s folder); the values are checked by FitSpec itself."""
    sections = {s for s in DOCUMENT if s} | set(TABLES) | set(ARRAYS) | set(IGNORED)
    _unknown(raw, sections | set(DOCUMENT[""]), "top level", path)
    # DEFAULT_STARTS read when parsing, not when the class was made (the tests set it to 1)
    fields: dict[str, Any] = {"path": path, "name": raw.get("name", path.stem), "starts": DEFAULT_STARTS}
    for section, keys in DOCUMENT.items():
        if not section or section not in raw:
            continue
        d = raw[section]
        if not isinstance(d, Mapping):
            raise SpecError.at(path, section, f"expected a table, got {d!r}")
        _unknown(d, keys, section, path)
        fields.update({keys[k]: v for k, v in d.items()})
    base = path.parent
    c = raw.get("corpus")
    if c is None:
        raise SpecError.at(path, "corpus", "missing: give a manifest or a list of files and labels")
    if isinstance(c, Mapping):
        c = dict(c)
        for k in ("manifest",):
            if k in c:
                c[k] = _relative(base, c[k])
        for k in ("files", "labels"):
            if isinstance(c.get(k), list):
                c[k] = [_relative(base, f) for f in c[k]]
        lm = c.get("label_map")
        if isinstance(lm, str) and ("/" in lm or lm.endswith((".tsv", ".json"))):
            c["label_map"] = str(_relative(base, lm))
    fields["corpus"] = c
    if "choose" in raw:
        fields["choose"] = raw["choose"]
    p = raw.get("parameters", {})
    if isinstance(p, Mapping) and "free" in p and "shared" not in p:
        # the shared dynamics belong to the default freedom: a spec that lists its own free set keeps
        # per-phoneme values unless it says shared = [...] too
        fields["shared"] = ()
    if isinstance(p, Mapping) and "free" in p and "pooled" not in p:
        fields["pooled"] = ()  # likewise the pooled dynamics
    if isinstance(p, Mapping) and isinstance(p.get("pooled"), list) and "shared" not in p and "free" not in p:
        fields["shared"] = tuple(q for q in DEFAULT_SHARED if q not in p["pooled"])  # pooled instead of shared
    if isinstance(p, Mapping) and isinstance(p.get("shared"), list) and "pooled" not in p and "free" not in p:
        fields["pooled"] = tuple(q for q in DEFAULT_POOLED if q not in p["shared"])  # shared instead of pooled
    for key in ("pooled",):
        if isinstance(p, Mapping) and isinstance(p.get(key), list):
            frees = [p.get("free", list(DEFAULT_FREE))] + [o.get("free", []) for o in raw.get("override", [])
                                                           if isinstance(o, Mapping)]
            freed = {n for f in frees for n in (f if isinstance(f, list) else [f])}
            if set(p[key]) - freed:
                raise SpecError.at(path, f"parameters.{key}", f"{', '.join(sorted(set(p[key]) - freed))} is not free "
                                   "([parameters] free or an [[override]] free): pooling a fixed value would do nothing")
    if isinstance(p, Mapping) and "shared" in p and isinstance(p["shared"], list):
        frees = [p.get("free", list(DEFAULT_FREE))] + [o.get("free", []) for o in raw.get("override", [])
                                                       if isinstance(o, Mapping)]
        freed = {n for f in frees for n in (f if isinstance(f, list) else [f])}
        if set(p["shared"]) - freed:
            raise SpecError.at(path, "parameters.shared", f"{', '.join(sorted(set(p['shared']) - freed))} is not "
                               "free ([parameters] free or an [[override]] free): sharing a fixed value would do nothing")
    if "start_table" in fields:
        fields["start_table"] = _relative(base, fields["start_table"])
    if isinstance(fields.get("start"), Mapping):
        fields["start_given"] = frozenset(fields["start"])
        fields["start"] = {**DEFAULT_START, **fields["start"]}
    if isinstance(fields.get("bounds"), Mapping):
        given = fields["bounds"]
        fields["channel_bounds"] = {k: v for k, v in given.items() if isinstance(v, Mapping)}
        fields["bounds"] = {**DEFAULT_FIT_BOUNDS, **{k: v for k, v in given.items() if not isinstance(v, Mapping)}}
    for section, field in ARRAYS.items():
        items = raw.get(section, [])
        if not isinstance(items, list):
            raise SpecError.at(path, section, f"expected [[{section}]] tables")
        if section == "shrink":
            for i, t in enumerate(items):  # log and key are a Shrink's fields, not keys of the spec
                if isinstance(t, Mapping):
                    _unknown(t, _keys_of(Shrink), f"shrink #{i + 1}", path)
            # the key its errors and reports are named by
            items = [{**t, "key": f"shrink #{i + 1}"} if isinstance(t, Mapping) else t for i, t in enumerate(items)]
        fields[field] = items
    return fields


def _keys_of(part: type) -> list[str]:
    """The keys a part's spec table may have (``table_keys``: Shrink's ``log`` is ``scale`` there)."""
    return table_keys(part)


def _key_of(loc: Iterable[str | int]) -> str:
    """The spec key of a schema location: ("overrides", 2, "fixed", "theta_bw") ->
    "override #3.fixed.theta_bw", ("plateau_fraction",) -> "model.plateau_fraction"."""
    return key_of(loc, FIELD_KEYS, ARRAYS.values())


def spec_error(e: ValidationError, file: Path | str | None, root: tuple[str | int, ...] = ()) -> SpecError:
    """One SpecError of a FitSpec's (or a part's) ValidationError: every problem as ``file: [key]
    message``, the first one's place in the attributes (``coartic.estimation.checks.schema_error``).
    ``root``: the location of the part validated (a Choose alone is ``[choose]``)."""
    return schema_error(e, file, root, _key_of,
                        lambda head: _keys_of(_PARTS[head]) if head in _PARTS else None, "FitSpec")


def read_document(path: Path) -> dict[str, Any]:
    """The TOML document of a spec file, or a SpecError naming the file."""
    try:
        return tomllib.loads(read_text(path, "fit spec"))
    except FileNotFoundError:
        raise SpecError.at(path, None, "no such fit spec") from None
    except IsADirectoryError:
        raise SpecError.at(path, None, "is a directory, not a fit spec (.toml) file") from None
    except TextDecodeError as e:
        err = SpecError(str(e))
        err.file = path
        raise err from None
    except tomllib.TOMLDecodeError as e:
        raise SpecError.at(path, None, f"not valid TOML: {e}") from None


def load_spec(path: str | Path) -> FitSpec:
    """Read and check a fit spec. Raises SpecError naming the file and key on any problem."""
    path = Path(path)
    return parse_spec(read_document(path), path)


def parse_spec(raw: Mapping[str, Any], path: Path) -> FitSpec:
    """Build a FitSpec from an already parsed TOML document (``path`` locates relative paths)."""
    return FitSpec(**document_fields(raw, path))


def make_choose(path: Path, key: Any, values: Any, group: Any, folds: Any, rule: Any,
                shrinks: tuple[Shrink, ...], where: str) -> Choose:
    """A checked ``Choose`` (from ``[choose]`` or ``coartic fit --choose``); errors name ``where``."""
    try:
        made = Choose.__pydantic_validator__.validate_python(  # type: ignore[attr-defined]
            ArgsKwargs((), {"key": key, "values": values, "group": group, "folds": folds, "rule": rule}))
    except ValidationError as e:
        raise spec_error(e, path, (where,)) from None
    problem = _choose_shrinks(made.key, shrinks)
    if problem is not None:
        raise SpecError.at(path, f"{where}.key", problem)
    return made  # type: ignore[no-any-return]


def synth_hint(manifest: Path) -> str:
    """What to run when ``manifest`` is absent, naming that very corpus (the session and the
    speakers' corpus are both made by ``coartic corpus synth``, which one is not known here)."""
    return (f" (if it is a synthetic corpus: `coartic corpus synth {manifest.parent}`, with `--speakers N` for "
            "several speakers)")


def parse_grid(option: str, text: str, example: str = "") -> tuple[str, list[str]]:
    """``KEY=V1,V2,...`` of a command-line option (``--vary``, ``--choose``): the key and the values
    as given (each command converts them), or a SpecError naming the option."""
    key, sep, values = text.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise SpecError(f"{option} {text!r}: expected KEY=V1,V2,...{f' (e.g. {example})' if example else ''}")
    grid = [v.strip() for v in values.split(",")]
    if not all(grid):
        raise SpecError(f"{option} {text!r}: an empty value between commas")
    return key.strip(), grid


def choose_base(key: str) -> str | None:
    """The CHOOSABLE entry a key belongs to ("shrink #2.sd" -> "shrink.sd"), or None."""
    if key in CHOOSABLE:
        return key
    if key.startswith("shrink #") and key.endswith(".sd") and key[len("shrink #"):-len(".sd")].isdigit():
        return "shrink.sd"
    return None
