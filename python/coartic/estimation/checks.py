"""The checks of a setting's value, shared by the estimation settings (coartic.estimation.settings)
and the fit spec (coartic.fit.spec), and the one translation of their errors into ``SpecError``.

Each field type is an ``Annotated`` pydantic type whose validator raises a ``PydanticCustomError``
(``_bad``) carrying the message and the place below the field; ``schema_error`` turns a schema's
``ValidationError`` into one ``SpecError`` naming the key each problem is written with in a spec
file (``[parameters.free] unknown parameter 'kr'``), and ``spec_errors`` makes a schema class raise
it on construction. So a setting built in Python is refused in the words a spec file's is.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import BeforeValidator, ConfigDict, ValidationError, ValidationInfo
from pydantic_core import PydanticCustomError

from coartic.errors import SpecError
from coartic.settings import CHANNEL_SETTINGS
from coartic.pauses import PAUSE_MODES
from coartic.table import ALL_CHANNELS, PARAMETERS, VARIANTS, domain_problem

# Fitted on a log scale: their bounds and log-scale priors need positive values.
LOG_SCALE_PARAMETERS = ("alpha", "theta_bw", "theta_fw", "psi", "beta")
SPEAKER_MODES: tuple[str, ...] = ("none", "offset", "offset_scale", "targets")
# "targets": a target per (phoneme, emotion), dynamics shared; "targets+dynamics": also each emotion's
# own alpha, theta_bw, theta_fw per phoneme, pooled toward neutral (coartic.estimation.emotions)
EMOTION_MODES: tuple[str, ...] = ("none", "targets", "targets+dynamics")

# Every schema refuses keys it does not know (a typo is an error, not a default silently kept).
STRICT = ConfigDict(extra="forbid", arbitrary_types_allowed=True)
T = TypeVar("T")


# --------------------------------------------------------------------------- field types
# Each check raises a PydanticCustomError whose context may hold ``loc`` (a place below the field,
# e.g. the parameter of a table) and ``phoneme``/``parameter``/``value``: schema_error() turns them
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
# the [model] keys of estimation.settings.ModelSettings (the fit spec holds one)
Variant = Annotated[str, BeforeValidator(_one_of(VARIANTS))]
ReferencePhoneme = Annotated[str | None, BeforeValidator(_optional(_text))]
ApexFraction = Annotated[float, BeforeValidator(_setting("apex_fraction"))]
EdgeExtent = Annotated[float, BeforeValidator(_setting("edge_extent"))]
Dominance = Annotated[str, BeforeValidator(_setting("dominance"))]
PlateauFraction = Annotated[float, BeforeValidator(_setting("plateau_fraction"))]
Handover = Annotated[bool, BeforeValidator(_setting("handover"))]
Beta = Annotated[float, BeforeValidator(_setting("beta"))]
PauseMode = Annotated[str, BeforeValidator(_one_of(PAUSE_MODES))]

def _group(v: Any) -> tuple[str, ...]:
    names = _names(v)
    if len(set(names)) < 2:
        raise _bad(f"a tie needs two phonemes or more, got {list(names)}")
    return names


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


# --------------------------------------------------------------------------- errors

_MESSAGES: dict[str, str] = {
    "missing": "missing", "dict_type": "expected a table", "dataclass_type": "expected a table",
    "dataclass_args_type": "expected a table", "tuple_type": "expected a list", "string_type": "expected a string",
    "float_type": "expected a number", "int_type": "expected an integer", "bool_type": "expected true or false",
}


def key_of(loc: Iterable[str | int], keys: Mapping[str, str], arrays: Iterable[str]) -> str:
    """The spec key of a schema location, ``keys`` mapping a field to its key and ``arrays`` the
    fields that are lists of tables: ("overrides", 2, "fixed", "theta_bw") ->
    "override #3.fixed.theta_bw", ("plateau_fraction",) -> "model.plateau_fraction"."""
    parts = list(loc)
    if not parts:
        return "top level"
    head = str(parts.pop(0))
    key = keys.get(head, head)
    if head in set(arrays) and parts and isinstance(parts[0], int):
        key += f" #{int(parts.pop(0)) + 1}"
    for p in parts:
        key += f".{p}"
    return key


def schema_error(e: ValidationError, file: Path | str | None, root: tuple[str | int, ...],
                 key: Callable[[Sequence[str | int]], str],
                 allowed: Callable[[Sequence[str | int]], Sequence[str] | None],
                 owner: str) -> SpecError:
    """One SpecError of a schema's ValidationError: every problem as ``file: [key] message``, the
    first one's place in the attributes. ``root``: the location of the part validated (a Choose
    alone is ``[choose]``); ``key`` names a location; ``allowed`` gives the keys the table at a
    location may have (for unknown keys; at ``()`` a document's top level, None for a class built
    in Python); ``owner`` is the class named when a keyword is no
    field of it."""
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
        problems.append((key(loc), message, ctx))
    for loc, names in unknown.items():
        keys = allowed(loc)
        if not loc and keys is None:  # a keyword that is no field of a class built in Python
            problems.append(("top level", f"{owner} has no field(s) {sorted(names)}", {}))
            continue
        problems.append((key(loc), f"unknown key(s) {sorted(names)}{'' if keys is None else f'; allowed: {sorted(keys)}'}",
                         {}))
    first_key, message, place = problems[0]
    where = f"{file}: " if file is not None else ""
    first = SpecError.at(file, first_key, message, place.get("phoneme"), parameter=place.get("parameter"),
                         value=place.get("value"))
    if len(problems) > 1:
        first.args = ("\n".join(f"{where}[{k}] {m}" for k, m, _ in problems),)
    first.problems = tuple((k, m) for k, m, _ in problems)
    return first


def spec_errors(convert: Callable[[ValidationError, Any, type], SpecError],
                file_field: str | None = None) -> Callable[[type[T]], type[T]]:
    """A class decorator: construction (and ``dataclasses.replace``) raises ``convert``'s SpecError
    instead of pydantic's ValidationError (every coartic error is a CoarticError); ``file_field``
    names the field holding the file errors name."""
    def wrap(cls: type[T]) -> type[T]:
        init = cls.__init__
        names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]

        @functools.wraps(init)
        def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
            if len(args) <= len(names) and not set(names[:len(args)]) & set(kwargs):
                # by name, so that an error names the field, not its position (Tie(("p",), ...))
                kwargs, args = {**dict(zip(names, args)), **kwargs}, ()
            try:
                init(self, *args, **kwargs)
            except ValidationError as e:
                raise convert(e, None if file_field is None else kwargs.get(file_field), cls) from None

        cls.__init__ = __init__  # type: ignore[method-assign]
        return cls
    return wrap
