"""The fit specification: a TOML file (``fit/*.toml``) describing one least-squares fit.

Every path in a spec is relative to the spec file. Every error names the spec file and the key at
fault, e.g. ``fit/synthetic.toml: [engine.name] 'foo': unknown engine (scipy, nlopt, casadi)``, and
carries the place as attributes (``SpecError``: file, section, entry, key, phoneme, parameter).

The spec is a typed schema (pydantic v2 dataclasses, chosen by measurement: docs/FITTING.md, "The
spec schema"; ``bench/spec_schema.py``), nested as the file is: ``FitSpec`` holds the estimation
settings as estimation's own classes (``spec.model`` is a ``ModelSettings``, ``spec.parameters``,
``spec.priors``, ``spec.groups`` likewise: every field and default written once, in
``coartic.estimation.settings``) and the fit's own sections (``EngineSection``, ``StagingSection``,
``FitSection``, ``GapsSection``, ``ValidateSection``, ``CorpusSpec``, ``Choose``). Each part checks
its own fields on every construction, so ``FitSpec.with_options`` and ``dataclasses.replace``
re-validate what they change as loading a file does. A ``[model]`` or ``[parameters]`` key is the
setting whose spec key it is (estimation's ``SPEC_KEYS``, read both ways: to sort the file's keys
into the settings' parts and to name a setting's error by the key the user wrote); the other
sections are their classes, key for key. The model's channel settings (default, range, meaning)
come from ``coartic.settings``, the parameters' domains from ``coartic.table.MODEL_DOMAIN``.

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
from coartic.estimation.checks import (Channels, Flag, Number, STRICT, Text, _bad, _count, _number, _one_of,
                                       _optional, _params_or_beta, key_of, schema_error, spec_errors)
from coartic.estimation.settings import (DEFAULT_POOLED, DEFAULT_SHARED, DEFAULT_FREE, EstimationSettings,
                                         GroupSettings, ModelSettings, ParameterSettings, PriorSettings,
                                         check_together, table_keys)
from coartic.io.errors import DataError
from coartic.io.roles import RoleMap
from coartic.settings import CHANNEL_SETTINGS
from coartic.table import CHANNELS, PARAMETERS, ChannelSettings
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


OptionalPath = Annotated[Path | None, BeforeValidator(_optional(_path))]
Select = Annotated[dict[str, tuple[str, ...]], BeforeValidator(_select)]  # manifest column -> kept values


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
@dataclass(frozen=True, config=STRICT)
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
@dataclass(frozen=True, config=STRICT)
class CorpusSpec:
    manifest: OptionalPath = None
    files: Annotated[tuple[Path, ...], BeforeValidator(_paths)] = ()
    labels: Annotated[tuple[Path, ...], BeforeValidator(_paths)] = ()
    file_column: Text = "file"  # manifest column holding the data file
    label_map: Annotated[str | None, BeforeValidator(_label_map)] = None  # a label-map name or path; None: model phonemes
    # role -> marker/sensor name; EMA: "axes" = {vertical, anterior}
    role_map: Annotated[dict[str, Any] | None, BeforeValidator(_optional(_role_map))] = None
    select: Select = dataclasses.field(default_factory=dict)
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
@dataclass(frozen=True, config=STRICT)
class EngineSection:
    """``[engine]``: the least-squares engine (``ENGINES``) and its options."""

    name: Annotated[str, BeforeValidator(_one_of(ENGINES, "unknown engine"))] = "scipy"
    options: Annotated[dict[str, Any], BeforeValidator(_table)] = dataclasses.field(default_factory=dict)


@_spec_errors
@dataclass(frozen=True, config=STRICT)
class StagingSection:
    """``[staging]``: fit in stages (targets, then timing and dynamics, then resistance and shape)."""

    enabled: Flag = True
    stages: Annotated[tuple[tuple[str, ...], ...], BeforeValidator(_stages)] = DEFAULT_STAGES


@_spec_errors
@dataclass(frozen=True, config=STRICT)
class FitSection:
    """``[fit]``: global estimation by multi-start (coartic.fit.multistart); ``starts = 1`` is one
    local fit from ``[parameters.start]``."""

    # DEFAULT_STARTS read when a spec is made, not when the class was (the tests set it to 1)
    starts: Annotated[int, BeforeValidator(_count(1, MAX_STARTS))] = dataclasses.field(
        default_factory=lambda: DEFAULT_STARTS)
    seed: Annotated[int, BeforeValidator(_count(0))] = 0
    probe: Annotated[int, BeforeValidator(_count(1, MAX_PROBE))] = DEFAULT_PROBE
    # starts continued after the probe (None: multistart.default_keep)
    keep: Annotated[int | None, BeforeValidator(_optional(_count(1)))] = None
    include_start: Flag = True  # start 0 is [parameters.start] (always continued)

    @model_validator(mode="after")
    def _keep_within_starts(self) -> FitSection:
        if self.keep is not None and self.starts > 1 and self.keep > self.starts:
            raise _bad(f"{self.keep}: more than the {self.starts} starts", ("keep",))
        return self


@_spec_errors
@dataclass(frozen=True, config=STRICT)
class GapsSection:
    """``[gaps]``: gaps up to ``max_gap`` s are interpolated by the reader, longer ones masked."""

    max_gap: Number = 0.05


@_spec_errors
@dataclass(frozen=True, config=STRICT)
class ValidateSection:
    """``[validate]``: held-out checks, by repetition and rate, or k-fold by ``group``."""

    holdout_repetition: Annotated[int | None, BeforeValidator(_optional(_count(1)))] = 5  # counted from 1
    train_rate: str | None = "normal"
    test_rate: str | None = "fast"
    # k-fold validation by this grouping (VALIDATE_GROUPS)
    group: Annotated[str | None, BeforeValidator(_optional(_one_of(VALIDATE_GROUPS)))] = None
    # None: one fold per group (leave one group out)
    folds: Annotated[int | None, BeforeValidator(_optional(_count(2)))] = None

    @model_validator(mode="after")
    def _folds_need_a_group(self) -> ValidateSection:
        if self.folds is not None and self.group is None:
            raise _bad("needs group = \"utterance\" (or sentence, rate, speaker, repetition)", ("folds",))
        return self


@_spec_errors
@dataclass(frozen=True, config=STRICT)
class FitSpec:
    """A fit spec, section by section. The estimation settings are estimation's own classes
    (``model``, ``parameters``, ``priors``, ``groups``: ``coartic.estimation.settings``), whose
    keys a file writes in ``[model]`` and ``[parameters]`` (``SPEC_KEYS`` there); the fit's own
    sections are ``engine``, ``staging``, ``fit``, ``gaps``, ``validate``, keyed as in the file."""

    path: Path  # the spec file (errors and relative paths refer to it)
    name: Text
    # where the trials are read from; None: they are given in Python (coartic.Coarticulation.fit)
    corpus: CorpusSpec | None
    channels: Channels = CHANNELS  # written in [model]
    model: ModelSettings = dataclasses.field(default_factory=ModelSettings)
    parameters: ParameterSettings = dataclasses.field(default_factory=ParameterSettings)
    priors: PriorSettings = dataclasses.field(default_factory=PriorSettings)
    groups: GroupSettings = dataclasses.field(default_factory=GroupSettings)
    start_table: OptionalPath = None  # start values from a table JSON (written in [parameters])
    choose: Choose | None = None
    engine: EngineSection = dataclasses.field(default_factory=EngineSection)
    staging: StagingSection = dataclasses.field(default_factory=StagingSection)
    fit: FitSection = dataclasses.field(default_factory=FitSection)
    gaps: GapsSection = dataclasses.field(default_factory=GapsSection)
    validate: ValidateSection = dataclasses.field(default_factory=ValidateSection)

    @model_validator(mode="after")
    def _consistent(self) -> FitSpec:
        """What no section can check alone."""
        if not self.channels:
            raise _bad("no channel to fit", ("channels",))
        # the estimation settings' own checks across their parts, in their words
        check_together(lambda name: getattr(getattr(self, est.PART_OF[name]), name))
        if self.choose is not None:
            problem = _choose_shrinks(self.choose.key, self.priors.shrinks)
            if problem is not None:
                raise _bad(problem, ("choose", "key"))
        return self

    def with_options(self, **changes: Any) -> FitSpec:
        """The spec with ``changes``, checked as loading a file checks it: a SpecError names the spec
        file and the key at fault. A change is a field of the spec (a section given whole, or as a
        table of the keys it changes: ``engine={"name": "nlopt"}``) or a setting of one section by
        its own name (``starts=1``, ``free=(...)``: ``SETTING_SECTION``)."""
        direct: dict[str, Any] = {}
        tables: dict[str, dict[str, Any]] = {}
        unknown = []
        for k, v in changes.items():
            if k in SECTIONS and isinstance(v, Mapping):
                tables.setdefault(k, {}).update(v)
            elif k in _FIELDS:
                direct[k] = v
            elif k in SETTING_SECTION:
                tables.setdefault(SETTING_SECTION[k], {})[k] = v
            else:
                unknown.append(k)
        if unknown:
            raise SpecError.at(self.path, "top level", f"FitSpec has no field(s) {sorted(unknown)}")
        for section, table in tables.items():
            current = direct.get(section, getattr(self, section))
            direct[section] = {**{f.name: getattr(current, f.name) for f in dataclasses.fields(current)}, **table}
        return dataclasses.replace(self, **direct)

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
                      **options: Any) -> FitSpec:
        """The spec of a fit with these estimation settings (built in Python: ``coartic.Coarticulation``)
        and the fit's own ``options`` (channels, engine, staging, starts, ... as ``with_options``
        takes them), checked as a spec file is: a SpecError names ``path`` and the key each option is
        written with in a file."""
        twice = sorted(k for k in options if est.PART_OF.get(k) in _SETTINGS_PARTS or k in _SETTINGS_PARTS)
        if twice:
            raise SpecError.at(path, None, f"{', '.join(twice)}: an estimation setting, given in the settings "
                               "(coartic.estimation.settings), not beside them")
        spec = cls(path=path, name=name, corpus=corpus, model=settings.model, parameters=settings.parameters,
                   priors=settings.priors, groups=settings.groups)
        return spec.with_options(**options)

    def estimation_settings(self) -> EstimationSettings:
        """The estimation settings this spec writes (``coartic.estimation.settings``): what
        ``build_problem`` takes; errors in them name this spec file."""
        return EstimationSettings(model=self.model, parameters=self.parameters, priors=self.priors,
                                  groups=self.groups, source=self.path)

    def reference_for(self, phonemes: Sequence[str]) -> str:
        """The reference phoneme (α = 1) of a channel whose data have ``phonemes``
        (``ModelSettings.reference_for``)."""
        return self.model.reference_for(phonemes)

    def channel_settings(self, channel: str, beta: float | None = None,
                         phonemes: Sequence[str] | None = None) -> ChannelSettings:
        """The settings a fit of ``channel`` uses and writes into its table
        (``ModelSettings.channel_settings``)."""
        return self.model.channel_settings(channel, beta, phonemes)


# The estimation settings' parts (their settings keyed by coartic.estimation.settings.SPEC_KEYS) and
# the file section whose keys a part's settings are: [model] and [parameters] hold several parts.
_SETTINGS_PARTS: dict[str, str] = {"model": "model", "parameters": "parameters", "priors": "parameters",
                                   "groups": "model"}
# the spec's fields written in a section of the estimation settings' keys
_OWN_KEYS: dict[str, str] = {"channels": "model.channels", "start_table": "parameters.start_table"}
_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(FitSpec))
# the sections (each a class of its own) and a setting's section by the setting's name, for
# with_options; names in two sections (or a field of the spec: engine's name) go in their section
SECTIONS: dict[str, type] = {f: c for f, c in (
    ("model", ModelSettings), ("parameters", ParameterSettings), ("priors", PriorSettings),
    ("groups", GroupSettings), ("engine", EngineSection), ("staging", StagingSection), ("fit", FitSection),
    ("gaps", GapsSection), ("validate", ValidateSection), ("corpus", CorpusSpec), ("choose", Choose))}
_NAMES = [(f.name, s) for s, c in SECTIONS.items() if s not in ("corpus", "choose") for f in dataclasses.fields(c)]
SETTING_SECTION: dict[str, str] = {n: s for n, s in _NAMES
                                   if [m for m, _ in _NAMES].count(n) == 1 and n not in _FIELDS}


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

# A [model] or [parameters] key is the estimation setting whose spec key it is (SPEC_KEYS, read
# backwards: the first setting of a key, "parameters.start" is start, not start_given), or one of
# the spec's own fields (_OWN_KEYS); every other section is its class, key for key. [[override]],
# [[tie]] and [[shrink]] are the settings' lists of Override, Tie, Shrink. [mcmc] belongs to
# coartic.mcmc (docs/MCMC.md): one spec file serves both commands, so it is accepted here and not read.
SETTING_OF_KEY: dict[str, str] = {}
for _setting, _key in est.SPEC_KEYS.items():
    if "." in _key:
        SETTING_OF_KEY.setdefault(_key, _setting)
SECTION_KEYS: dict[str, tuple[str, ...]] = {
    **{s: tuple(sorted({k.split(".", 1)[1] for k in SETTING_OF_KEY if k.startswith(f"{s}.")}
                       | {k.split(".", 1)[1] for k in _OWN_KEYS.values() if k.startswith(f"{s}.")}))
       for s in ("model", "parameters")},
    **{s: tuple(f.name for f in dataclasses.fields(SECTIONS[s])) for s in ("engine", "staging", "fit", "gaps",
                                                                           "validate")},
}
ARRAYS: dict[str, tuple[str, str]] = {"override": ("parameters", "overrides"), "tie": ("parameters", "ties"),
                                      "shrink": ("priors", "shrinks")}
TOP_KEYS: tuple[str, ...] = ("name", "corpus", "choose", *SECTION_KEYS, *ARRAYS, "mcmc")
# a part built alone (a Choose by --choose, an Override in Python) is named by its section
_PARTS: dict[str, type] = {"override": Override, "tie": Tie, "shrink": Shrink, "corpus": CorpusSpec,
                           "choose": Choose, "--choose": Choose, "engine": EngineSection,
                           "staging": StagingSection, "fit": FitSection, "gaps": GapsSection,
                           "validate": ValidateSection}
_ROOTS: dict[str, tuple[str | int, ...]] = {c.__name__: (s,) for s, c in _PARTS.items() if s != "--choose"}


def _unknown(d: Mapping[str, Any], allowed: Iterable[str], key: str, path: Path) -> None:
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise SpecError.at(path, key, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _relative(base: Path, v: Any) -> Any:
    """A path string relative to the spec's folder (anything else is left to the schema's check)."""
    return base / v if isinstance(v, str) and v and not Path(v).is_absolute() else v


def document_fields(raw: Mapping[str, Any], path: Path) -> dict[str, Any]:
    """The FitSpec fields a TOML document sets, section by section (unknown keys of [model] and
    [parameters] refused here, where they are sorted into the settings' parts; relative paths made
    relative to ``path``'s folder); the values are checked by FitSpec itself."""
    _unknown(raw, TOP_KEYS, "top level", path)
    fields: dict[str, Any] = {"path": path, "name": raw.get("name", path.stem)}
    parts: dict[str, dict[str, Any]] = {part: {} for part in _SETTINGS_PARTS}
    for section in SECTION_KEYS:
        if section not in raw:
            continue
        d = raw[section]
        if not isinstance(d, Mapping):
            raise SpecError.at(path, section, f"expected a table, got {d!r}")
        if section not in ("model", "parameters"):
            fields[section] = dict(d)  # its class refuses unknown keys, named in this section
            continue
        _unknown(d, SECTION_KEYS[section], section, path)
        for k, v in d.items():
            own = next((f for f, key in _OWN_KEYS.items() if key == f"{section}.{k}"), None)
            if own is not None:
                fields[own] = v
            else:
                setting = SETTING_OF_KEY[f"{section}.{k}"]
                parts[est.PART_OF[setting]][setting] = v
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
    par, pri = parts["parameters"], parts["priors"]
    if isinstance(p, Mapping) and "free" in p and "shared" not in p:
        # the shared dynamics belong to the default freedom: a spec that lists its own free set keeps
        # per-phoneme values unless it says shared = [...] too
        par["shared"] = ()
    if isinstance(p, Mapping) and "free" in p and "pooled" not in p:
        pri["pooled"] = ()  # likewise the pooled dynamics
    if isinstance(p, Mapping) and isinstance(p.get("pooled"), list) and "shared" not in p and "free" not in p:
        par["shared"] = tuple(q for q in DEFAULT_SHARED if q not in p["pooled"])  # pooled instead of shared
    if isinstance(p, Mapping) and isinstance(p.get("shared"), list) and "pooled" not in p and "free" not in p:
        pri["pooled"] = tuple(q for q in DEFAULT_POOLED if q not in p["shared"])  # shared instead of pooled
    for key in ("pooled", "shared"):
        if isinstance(p, Mapping) and isinstance(p.get(key), list):
            frees = [p.get("free", list(DEFAULT_FREE))] + [o.get("free", []) for o in raw.get("override", [])
                                                           if isinstance(o, Mapping)]
            freed = {n for f in frees for n in (f if isinstance(f, list) else [f])}
            # a name that is no parameter at all (a typo) is left to the schema, whose message lists the known ones
            fixed = {n for n in p[key] if isinstance(n, str) and n in PARAMETERS} - freed
            if fixed:
                what = "pooling" if key == "pooled" else "sharing"
                raise SpecError.at(path, f"parameters.{key}", f"{', '.join(sorted(fixed))} is not free "
                                   f"([parameters] free or an [[override]] free): {what} a fixed value would do nothing")
    if "start_table" in fields:
        fields["start_table"] = _relative(base, fields["start_table"])
    if isinstance(par.get("bounds"), Mapping):
        given = par["bounds"]
        par["channel_bounds"] = {k: v for k, v in given.items() if isinstance(v, Mapping)}
        par["bounds"] = {k: v for k, v in given.items() if not isinstance(v, Mapping)}
    for section, (part, field) in ARRAYS.items():
        items = raw.get(section, [])
        if not isinstance(items, list):
            raise SpecError.at(path, section, f"expected [[{section}]] tables")
        if section == "shrink":
            for i, t in enumerate(items):  # log and key are a Shrink's fields, not keys of the spec
                if isinstance(t, Mapping):
                    _unknown(t, table_keys(Shrink), f"shrink #{i + 1}", path)
            # the key its errors and reports are named by
            items = [{**t, "key": f"shrink #{i + 1}"} if isinstance(t, Mapping) else t for i, t in enumerate(items)]
        parts[part][field] = items
    fields.update(parts)
    return fields


def _key_of(loc: Sequence[str | int]) -> str:
    """The spec key of a schema location: ("parameters", "overrides", 2, "fixed", "theta_bw") ->
    "override #3.fixed.theta_bw", ("model", "plateau_fraction") -> "model.plateau_fraction",
    ("fit", "starts") -> "fit.starts"."""
    parts = list(loc)
    if not parts:
        return "top level"
    head = str(parts[0])
    if head in _SETTINGS_PARTS:  # a part of the estimation settings: its settings' keys
        return est.spec_key(parts[1:]) if len(parts) > 1 else _SETTINGS_PARTS[head]
    if head in est.SPEC_KEYS:  # a setting named by the checks across parts (check_together)
        return est.spec_key(parts)
    if head in _OWN_KEYS:
        return ".".join([_OWN_KEYS[head], *map(str, parts[1:])])
    return key_of(parts, {}, ())


def _allowed(loc: Sequence[str | int]) -> list[str] | None:
    """The keys the table at ``loc`` may have (None: the spec itself, built in Python)."""
    if len(loc) >= 3 and loc[0] in _SETTINGS_PARTS and isinstance(loc[2], int):
        table = {"overrides": Override, "ties": Tie, "shrinks": Shrink}.get(str(loc[1]))
        return None if table is None else table_keys(table)
    if len(loc) == 1 and str(loc[0]) in SECTIONS:
        return table_keys(SECTIONS[str(loc[0])])
    return table_keys(_PARTS[str(loc[0])]) if loc and str(loc[0]) in _PARTS else None


def spec_error(e: ValidationError, file: Path | str | None, root: tuple[str | int, ...] = ()) -> SpecError:
    """One SpecError of a FitSpec's (or a part's) ValidationError: every problem as ``file: [key]
    message``, the first one's place in the attributes (``coartic.estimation.checks.schema_error``).
    ``root``: the location of the part validated (a Choose alone is ``[choose]``)."""
    return schema_error(e, file, root, _key_of, _allowed, "FitSpec")


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
