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
import functools
import math
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import BeforeValidator, ConfigDict, ValidationError, ValidationInfo, model_validator
from pydantic.dataclasses import dataclass
from pydantic_core import ArgsKwargs, PydanticCustomError

from coartic.errors import SpecError
from coartic.estimation import settings as est
from coartic.estimation.settings import (DEFAULT_BETA_BOUNDS, DEFAULT_FIT_BOUNDS, DEFAULT_FREE, DEFAULT_POOLED,
                                         DEFAULT_REFERENCE, DEFAULT_SHARED, DEFAULT_START, DEFAULT_TARGET_PRIOR,
                                         SPEC_MODEL_DEFAULTS, EstimationSettings, GroupSettings, ModelSettings,
                                         ParameterSettings, PriorSettings)
from coartic.io.errors import DataError
from coartic.io.roles import RoleMap
from coartic.settings import CHANNEL_SETTINGS, default
from coartic.table import ALL_CHANNELS, CHANNELS, PARAMETERS, PAUSE, VARIANTS, ChannelSettings, domain_problem
from coartic.pauses import PAUSE_MODES
from coartic.textfile import TextDecodeError, read_text

ENGINES: tuple[str, ...] = ("scipy", "nlopt", "casadi")
# [validate] group: what a k-fold validation holds out together (manifest columns, or the file).
# "time": each utterance cut at its middle segment, one half fitted, the other held out (both ways)
VALIDATE_GROUPS: tuple[str, ...] = ("utterance", "sentence", "rate", "speaker", "repetition", "time")
SPEAKER_MODES: tuple[str, ...] = ("none", "offset", "offset_scale", "targets")
EMOTION_MODES: tuple[str, ...] = ("none", "targets")

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
# Fitted on a log scale: their bounds and log-scale priors need positive values.
LOG_SCALE_PARAMETERS = ("alpha", "theta_bw", "theta_fw", "psi", "beta")

# Settings ``[choose]`` / ``coartic fit --choose`` may choose by cross-validation, and which end of a
# grid is the stronger regularisation (the one-standard-error rule moves toward it): -1 smaller values,
# +1 larger values, 0 no such direction.
CHOOSABLE: dict[str, int] = {"shrink.sd": -1, "prior_noise": +1, "plateau_fraction": 0, "target_prior": -1}
CHOOSE_RULES: tuple[str, ...] = ("min", "1se")


# --------------------------------------------------------------------------- field types
# Each check raises a PydanticCustomError whose context may hold ``loc`` (a place below the field,
# e.g. the parameter of a table) and ``phoneme``/``parameter``/``value``: spec_error() turns them
# into the SpecError's key and attributes.


def _bad(message: str, loc: tuple[str | int, ...] = (), **place: Any) -> PydanticCustomError:
    return PydanticCustomError("coartic_spec", "{message}", {"message": message, "loc": loc, **place})


def _number(v: Any) -> float:
    # TOML has nan: refused here, once, so that no comparison downstream lets it through
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
        raise _bad(f"expected a number, got {v!r}")
    return float(v)


def _positive(v: Any) -> float:
    x = _number(v)
    if not (x > 0 and math.isfinite(x)):
        raise _bad(f"{x} must be a positive number")
    return x


def _flag(v: Any) -> bool:
    if not isinstance(v, bool):
        raise _bad(f"expected true or false, got {v!r}")
    return v


def _count(low: int, high: int | None = None) -> Callable[[Any], int]:
    def check(v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise _bad(f"expected {'a positive integer' if low == 1 else f'an integer >= {low}'}, got {v!r}")
        if high is not None and v > high:
            raise _bad(f"{v}: at most {high}; lower it")
        return v
    return check


def _optional(check: Callable[[Any], Any]) -> Callable[[Any], Any]:
    return lambda v: None if v is None else check(v)


def _one_of(choices: tuple[str, ...], what: str = "") -> Callable[[Any], str]:
    def check(v: Any) -> str:
        if v not in choices:
            raise _bad(f"{v!r}: {what or 'expected one of'} ({', '.join(choices)})" if what
                       else f"{v!r}: expected one of {', '.join(choices)}")
        return str(v)
    return check


def _names(v: Any) -> tuple[str, ...]:
    """A string or a list of strings (``phonemes = "p"`` is ``["p"]``)."""
    if isinstance(v, str):
        return (v,)
    if not isinstance(v, (list, tuple)) or not all(isinstance(s, str) for s in v):
        raise _bad(f"expected a list of strings, got {v!r}")
    return tuple(v)


def _known(allowed: tuple[str, ...], what: str) -> Callable[[Any], tuple[str, ...]]:
    def check(v: Any) -> tuple[str, ...]:
        names = _names(v)
        for n in names:
            if n not in allowed:
                raise _bad(f"unknown {what} {n!r}; known: {', '.join(allowed)}",
                           parameter=n if what == "parameter" else None)
        return names
    return check


_params = _known(PARAMETERS, "parameter")
_params_or_beta = _known(PARAMETERS + ("beta",), "parameter")
_channels = _known(ALL_CHANNELS, "channel")


def _stages(v: Any) -> tuple[tuple[str, ...], ...]:
    if not isinstance(v, (list, tuple)) or not v:
        raise _bad("expected a list of parameter lists")
    return tuple(_params_or_beta(st) for st in v)


def _setting(name: str) -> Callable[[Any], Any]:
    """A ``[model]`` channel setting checked against coartic.settings (its one definition)."""
    setting = CHANNEL_SETTINGS[name]

    def check(v: Any) -> Any:
        problem = setting.problem(v)
        if problem is not None:
            raise _bad(f"{name} = {v!r} {problem} ({setting.meaning})", parameter=name, value=v)
        return v if setting.flag or setting.choices else float(v)
    return check


def _param_values(v: Any, info: ValidationInfo) -> dict[str, float]:
    """``parameter = value`` pairs (starts, fixed values), each in its parameter's model domain
    (MODEL.md §1); in an ``[[override]]`` the errors name its phonemes."""
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table of parameter = value, got {v!r}")
    _params(tuple(v))
    phonemes: tuple[str, ...] = tuple((info.data or {}).get("phonemes", ()))
    out: dict[str, float] = {}
    for k, x in v.items():
        try:
            out[k] = _number(x)
        except PydanticCustomError:
            raise _bad(f"expected a number, got {x!r}", (k,), parameter=k) from None
        problem = domain_problem(k, out[k])
        if problem is not None:
            whose = f" (of {', '.join(phonemes)})" if phonemes else ""
            raise _bad(f"{k} = {out[k]:g}{whose} {problem}, the model's domain of {k}", (k,), parameter=k,
                       value=out[k], phoneme=", ".join(phonemes) or None)
    return out


def _interval(v: Any, loc: tuple[str | int, ...] = ()) -> tuple[float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise _bad(f"expected [low, high], got {v!r}", loc)
    try:
        return _number(v[0]), _number(v[1])
    except PydanticCustomError as e:
        raise _bad(str(e), loc) from None


def _bounds(v: Any) -> dict[str, tuple[float, float]]:
    """``parameter = [low, high]`` boxes; a log-scale parameter's low must be positive."""
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table of parameter = [low, high], got {v!r}")
    _params(tuple(v))
    out: dict[str, tuple[float, float]] = {}
    for k, x in v.items():
        lo, hi = _interval(x, (k,))
        if not lo < hi:
            raise _bad(f"low {lo} must be below high {hi}", (k,), parameter=k)
        if k in LOG_SCALE_PARAMETERS and lo <= 0:
            raise _bad(f"low {lo} must be > 0 (fitted on a log scale)", (k,), parameter=k, value=lo)
        out[k] = (lo, hi)
    return out


def _channel_bounds(v: Any) -> dict[str, dict[str, tuple[float, float]]]:
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table channel = {{ parameter = [low, high] }}, got {v!r}")
    _channels(tuple(v))
    out = {}
    for ch, b in v.items():
        try:
            out[ch] = _bounds(b)
        except PydanticCustomError as e:
            ctx = e.context or {}
            raise _bad(str(e), (ch, *ctx.get("loc", ())), parameter=ctx.get("parameter")) from None
    return out


def _beta_bounds(v: Any) -> tuple[float, float]:
    lo, hi = _interval(v)
    if not 0.0 <= lo < hi:
        raise _bad(f"need 0 <= low < high, got {(lo, hi)}")
    return lo, hi


def _prior(key: str, v: Any) -> tuple[float, float, bool]:
    """[mean, sd] on the natural value, or { mean = m, sd = s, scale = "log" } on its logarithm (m
    its median); (mean, sd, log) as given back by a FitSpec re-validated."""
    name = key.rpartition(".")[2]
    _params_or_beta((name,))
    if isinstance(v, (list, tuple)) and len(v) == 2:
        mean, sd, scale = _number(v[0]), _number(v[1]), "natural"
    elif isinstance(v, tuple) and len(v) == 3 and isinstance(v[2], bool):
        mean, sd, scale = _number(v[0]), _number(v[1]), "log" if v[2] else "natural"
    elif isinstance(v, Mapping):
        unknown = sorted(set(v) - {"mean", "sd", "scale"})
        if unknown:
            raise _bad(f"unknown key(s) {unknown}; allowed: ['mean', 'scale', 'sd']")
        if "mean" not in v or "sd" not in v:
            raise _bad("needs mean and sd")
        mean, sd, scale = _number(v["mean"]), _number(v["sd"]), v.get("scale", "natural")
    else:
        raise _bad(f"expected [mean, sd] or {{ mean, sd, scale }}, got {v!r}")
    if scale not in ("natural", "log"):
        raise _bad(f"scale = {scale!r}: expected \"natural\" or \"log\"")
    if not (math.isfinite(mean) and math.isfinite(sd) and sd > 0):
        raise _bad(f"needs a finite mean and a positive sd, got mean {mean}, sd {sd}")
    if scale == "log" and (name not in LOG_SCALE_PARAMETERS or mean <= 0):
        raise _bad(f"a log-scale prior needs a positive parameter ({', '.join(LOG_SCALE_PARAMETERS)}) "
                   f"and a positive mean, got {name} with mean {mean}")
    return mean, sd, scale == "log"


def _priors(v: Any) -> dict[str, tuple[float, float, bool]]:
    """``[parameters.prior]``: key "parameter", "phoneme.parameter" or "beta"."""
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table \"phoneme.parameter\" = [mean, sd], got {v!r}")
    out = {}
    for key, x in v.items():
        try:
            out[key] = _prior(key, x)
        except PydanticCustomError as e:
            raise _bad(str(e), (key,)) from None
    return out


def _target_prior(v: Any) -> float | str | None:
    """``[parameters] target_prior``: "none" (or None), "estimated" (its sd estimated from the data,
    coartic.estimation.pooling), or the prior's sd in mm."""
    if v is None or v == "none":
        return None
    if v == "estimated":
        return "estimated"
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise _bad(f"{v!r}: expected \"none\", \"estimated\" or a positive number (the sd in mm of every target "
                   "around its phoneme's mean in the data)")
    return float(v)


def _shared(v: Any) -> tuple[str, ...]:
    names = _params(v)
    if "target" in names:
        raise _bad("target cannot be shared: one target for every phoneme is the constant model", parameter="target")
    return names


def _pooled(v: Any) -> tuple[str, ...]:
    names = _params(v)
    if "target" in names:
        raise _bad("target cannot be pooled toward one value (the constant model): use target_prior = \"estimated\"",
                   parameter="target")
    return names


def _offsets(v: Any) -> str | float:
    if isinstance(v, bool) or not (v in ("none", "free") or (
            isinstance(v, (int, float)) and math.isfinite(v) and v > 0)):
        raise _bad(f"{v!r}: expected \"none\", \"free\" or a positive number (the offsets' sd in mm)")
    return v if isinstance(v, str) else float(v)


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


def _text(v: Any) -> str:
    if not isinstance(v, str) or not v:
        raise _bad(f"{v!r}: expected a non-empty string")
    return v


Number = Annotated[float, BeforeValidator(_number)]
Positive = Annotated[float, BeforeValidator(_positive)]
Flag = Annotated[bool, BeforeValidator(_flag)]
Text = Annotated[str, BeforeValidator(_text)]
Names = Annotated[tuple[str, ...], BeforeValidator(_names)]
Parameters = Annotated[tuple[str, ...], BeforeValidator(_params)]
Channels = Annotated[tuple[str, ...], BeforeValidator(_channels)]
ParamValues = Annotated[dict[str, float], BeforeValidator(_param_values)]
Bounds = Annotated[dict[str, tuple[float, float]], BeforeValidator(_bounds)]
SpecPath = Annotated[Path, BeforeValidator(_path)]

_STRICT = ConfigDict(extra="forbid", arbitrary_types_allowed=True)
T = TypeVar("T")


def _spec_errors(cls: type[T]) -> type[T]:
    """Construction (and ``dataclasses.replace``) raises SpecError, named like a spec's own
    errors, instead of pydantic's ValidationError: every coartic error is a CoarticError."""
    init = cls.__init__

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        try:
            init(self, *args, **kwargs)
        except ValidationError as e:
            file = (kwargs["path"] if "path" in kwargs else args[0] if args else None) if cls is FitSpec else None
            raise spec_error(e, file, _ROOTS.get(cls.__name__, ())) from None

    cls.__init__ = __init__  # type: ignore[method-assign]
    return cls


# --------------------------------------------------------------------------- the schema


@_spec_errors
@dataclass(frozen=True, config=_STRICT)
class Override(est.Override):
    """``[[override]]``: estimation's Override (coartic.estimation.settings), checked as a spec's table."""

    phonemes: Annotated[tuple[str, ...], BeforeValidator(_names)]
    channels: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_channels))] = None  # None: every channel
    fixed: ParamValues = dataclasses.field(default_factory=dict)  # fixed at this value
    free: Parameters = ()  # made free (even if not in the global list)
    start: ParamValues = dataclasses.field(default_factory=dict)
    bounds: Bounds = dataclasses.field(default_factory=dict)


def _group(v: Any) -> tuple[str, ...]:
    names = _names(v)
    if len(set(names)) < 2:
        raise _bad(f"a tie needs two phonemes or more, got {list(names)}")
    return names


@_spec_errors
@dataclass(frozen=True, config=_STRICT)
class Tie(est.Tie):
    """``[[tie]]``: estimation's Tie (coartic.estimation.settings), checked as a spec's table."""

    phonemes: Annotated[tuple[str, ...], BeforeValidator(_group)]
    parameters: Parameters
    channels: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_channels))] = None  # None: every channel


def _class(v: Any) -> tuple[str, ...]:
    names = _names(v)
    if len(set(names)) < 2 or len(set(names)) != len(names):
        raise _bad(f"a class needs two distinct phonemes or more, got {list(names)}")
    return names


def _distinct_params(v: Any) -> tuple[str, ...]:
    names = _params(v)
    if not names or len(set(names)) != len(names):
        raise _bad(f"expected distinct parameters, got {list(names)}")
    return names


@_spec_errors
@dataclass(frozen=True, config=_STRICT)
class Shrink(est.Shrink):
    """``[[shrink]]``: estimation's Shrink (coartic.estimation.settings), checked as a spec's table.
    In the spec, ``scale = "log"`` is ``log = true``."""

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
    variant: Annotated[str, BeforeValidator(_one_of(VARIANTS))] = "modified"
    # α = 1 for it (MODEL.md §1); None: chosen from the data (FitSpec.reference_for)
    reference_phoneme: Annotated[str | None, BeforeValidator(_optional(_text))] = None
    # the model's channel settings: defaults and ranges from coartic.settings
    apex_fraction: Annotated[float, BeforeValidator(_setting("apex_fraction"))] = default("apex_fraction")
    edge_extent: Annotated[float, BeforeValidator(_setting("edge_extent"))] = default("edge_extent")
    # the rate-aware options of docs/MODEL.md §2.1 (defaults: today's model)
    dominance: Annotated[str, BeforeValidator(_setting("dominance"))] = SPEC_MODEL_DEFAULTS["dominance"]
    plateau_fraction: Annotated[float, BeforeValidator(_setting("plateau_fraction"))] = default("plateau_fraction")
    handover: Annotated[bool, BeforeValidator(_setting("handover"))] = SPEC_MODEL_DEFAULTS["handover"]
    beta: Annotated[float, BeforeValidator(_setting("beta"))] = default("beta")
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
    pauses: Annotated[str, BeforeValidator(_one_of(PAUSE_MODES))] = "postures"
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
        if self.speakers != "none" and self.offsets != "none":
            raise _bad("cannot be combined with [model] offsets yet: choose one", ("speakers",))
        if self.emotions != "none" and (self.offsets != "none" or self.speakers != "none"):
            raise _bad("cannot be combined with [model] offsets or speakers yet: choose one", ("emotions",))
        ref = self.reference_phoneme or DEFAULT_REFERENCE
        for i, t in enumerate(self.ties):
            if ref in t.phonemes and "alpha" in t.parameters:
                raise _bad(f"ties alpha of the reference phoneme {ref!r}, which is fixed at 1", ("ties", i),
                           phoneme=ref, parameter="alpha")
        for i, o in enumerate(self.overrides):
            # alpha is scale-free: the reference phoneme's is 1 by definition (MODEL.md §1)
            if ref in o.phonemes and ("alpha" in o.free or "alpha" in o.start or "alpha" in o.bounds
                                      or o.fixed.get("alpha", 1.0) != 1.0):
                raise _bad(f"sets alpha of the reference phoneme {ref!r}, which is fixed at 1 (alpha is "
                           "scale-free); choose another [model] reference_phoneme to fit it", ("overrides", i),
                           phoneme=ref, parameter="alpha")
        both = set(self.pooled) & set(self.shared)
        if both:
            raise _bad(f"{', '.join(sorted(both))} is both shared by every phoneme and pooled: one or the other "
                       "(pooled with its sd estimated reaches shared when the data say so)", ("pooled",))
        tied = {q for t in self.ties for q in t.parameters} & set(self.shared)
        if tied:
            raise _bad(f"{', '.join(sorted(tied))} is both shared by every phoneme and in a [[tie]]: one or the other",
                       ("shared",))
        if self.beta > self.beta_bounds[1]:
            # the model takes any beta >= 0, but past the box a fit may search, rho(u) is gone within a
            # hair of the target: a typo (1e308) must not read as a model that fits badly
            raise _bad(f"beta = {self.beta:g} is above {self.beta_bounds[1]:g}, the upper end of [model] beta_bounds "
                       "(the largest beta a fit may reach): lower beta, or widen beta_bounds", ("beta",),
                       parameter="beta", value=self.beta)
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
    """The keys a part's spec table may have (Shrink's ``log`` is ``scale`` there, its ``key`` no key)."""
    names = [f.name for f in dataclasses.fields(part)]
    return [{"log": "scale"}.get(n, n) for n in names if not (part is Shrink and n == "key")]


def _key_of(loc: Iterable[str | int]) -> str:
    """The spec key of a schema location: ("overrides", 2, "fixed", "theta_bw") ->
    "override #3.fixed.theta_bw", ("plateau_fraction",) -> "model.plateau_fraction"."""
    parts = list(loc)
    if not parts:
        return "top level"
    head = str(parts.pop(0))
    key = FIELD_KEYS.get(head, head)
    if head in ARRAYS.values() and parts and isinstance(parts[0], int):
        key += f" #{int(parts.pop(0)) + 1}"
    for p in parts:
        key += f".{p}"
    return key


_MESSAGES: dict[str, str] = {
    "missing": "missing", "dict_type": "expected a table", "dataclass_type": "expected a table",
    "dataclass_args_type": "expected a table", "tuple_type": "expected a list", "string_type": "expected a string",
    "float_type": "expected a number", "int_type": "expected an integer", "bool_type": "expected true or false",
}


def spec_error(e: ValidationError, file: Path | str | None, root: tuple[str | int, ...] = ()) -> SpecError:
    """One SpecError of a schema's ValidationError: every problem as ``file: [key] message``, the
    first one's place in the attributes. ``root``: the location of the part validated (a Choose
    alone is ``[choose]``)."""
    problems: list[tuple[str, str, dict[str, Any]]] = []
    unknown: dict[tuple[Any, ...], list[str]] = {}
    for err in e.errors(include_url=False):
        loc = (*root, *err["loc"])
        ctx = dict(err.get("ctx") or {})
        if err["type"] == "unexpected_keyword_argument":
            unknown.setdefault(loc[:-1], []).append(str(loc[-1]))
            continue
        if err["type"] == "coartic_spec":
            loc = (*loc, *ctx.pop("loc", ()))
            message = str(ctx.pop("message"))
        elif err["type"] == "missing":
            loc, message = loc[:-1], f"missing key {loc[-1]!r}"
        else:
            message = f"{_MESSAGES.get(err['type'], err['msg'])}, got {err['input']!r}"
        ctx.pop("error", None)
        problems.append((_key_of(loc), message, ctx))
    for loc, names in unknown.items():
        if not loc:  # FitSpec(...) or with_options given a name that is no field (a TOML key never gets here)
            problems.append(("top level", f"FitSpec has no field(s) {sorted(names)}", {}))
            continue
        part = _PARTS.get(str(loc[0]))
        allowed = "" if part is None else f"; allowed: {sorted(_keys_of(part))}"
        problems.append((_key_of(loc), f"unknown key(s) {sorted(names)}{allowed}", {}))
    key, message, place = problems[0]
    where = f"{file}: " if file is not None else ""
    first = SpecError.at(file, key, message, place.get("phoneme"), parameter=place.get("parameter"),
                         value=place.get("value"))
    if len(problems) > 1:
        first.args = ("\n".join(f"{where}[{k}] {m}" for k, m, _ in problems),)
    first.problems = tuple((k, m) for k, m, _ in problems)
    return first


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
