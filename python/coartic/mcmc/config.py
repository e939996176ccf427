"""The ``[mcmc]`` table of a fit spec as a schema (docs/MCMC.md), parsed by the fit spec's machinery.

``McmcSection`` holds the keys as the file gives them (None: not given), each checked by a field
type in the manner of ``coartic.estimation.checks``; ``parse_section`` validates a table and turns
every problem into one ``McmcConfigError`` naming the file and key (``fit/x.toml: [mcmc] scope:
'all': expected one of phonemes, channel``) through the fit spec's one translation
(``coartic.estimation.checks.schema_error``). ``coartic.mcmc.run.parse_config`` makes the
``McmcConfig`` from it and checks what needs the sampler (steps, memory). Imported when a spec is
read (it loads pydantic), not when ``coartic.mcmc`` is.
"""

from __future__ import annotations

import math
from dataclasses import field
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator, ValidationError
from pydantic.dataclasses import dataclass
from pydantic_core import ArgsKwargs

from coartic.errors import SpecError
from coartic.estimation.checks import STRICT, Flag, _bad, _one_of, _optional, schema_error
from coartic.mcmc import sampler
from coartic.mcmc.errors import McmcConfigError
from coartic.mcmc.sampler import SCOPES


def _strings(v: Any) -> tuple[str, ...]:
    # a list only: "p" is more likely a mistake than a one-phoneme list here (as before the schema)
    if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
        raise _bad(f"expected a list of strings, got {v!r}")
    return tuple(v)


def _level(words: tuple[str, str]) -> Callable[[Any], str | float]:
    """One of two words or a positive number in mm (``noise``, ``offsets``)."""
    def check(v: Any) -> str | float:
        if isinstance(v, bool) or not (v in words or (isinstance(v, (int, float)) and v > 0)):
            raise _bad(f"{v!r}: expected \"{words[0]}\", \"{words[1]}\" or a positive number (mm)")
        return float(v) if isinstance(v, (int, float)) else str(v)
    return check


def _at_least(low: int) -> Callable[[Any], int]:
    def check(v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise _bad(f"expected an integer >= {low}, got {v!r}")
        return v
    return check


def _priors(v: Any) -> dict[str, dict[str, tuple[float, float]]]:
    """``"CHANNEL.phoneme.parameter" = [mean, sd]`` (or ``"CHANNEL.beta"``) -> channel -> name -> (mean, sd)."""
    if not isinstance(v, Mapping):
        raise _bad(f"expected a table \"CHANNEL.phoneme.parameter\" = [mean, sd], got {v!r}")
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for key, x in v.items():
        parts = key.split(".")
        if len(parts) == 2 and parts[1] == "beta":
            ch, name = parts[0], "beta"
        elif len(parts) == 3:
            ch, name = parts[0], f"{parts[1]}.{parts[2]}"
        else:
            raise _bad("expected a key \"CHANNEL.phoneme.parameter\" (or \"CHANNEL.beta\")", (key,))
        if not (isinstance(x, list) and len(x) == 2
                and all(isinstance(y, (int, float)) and not isinstance(y, bool) for y in x)):
            raise _bad(f"expected [mean, sd], got {x!r}", (key,))
        if not (x[1] > 0 and math.isfinite(x[0]) and math.isfinite(x[1])):
            raise _bad(f"sd must be positive and both finite, got {x!r}", (key,))
        out.setdefault(ch, {})[name] = (float(x[0]), float(x[1]))
    return out


def _ball(v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
        raise _bad(f"expected a number in (0, 1), got {v!r}")
    return float(v)


def _moves(v: Any) -> str:
    try:
        sampler.check_moves(v)
    except McmcConfigError as exc:
        raise _bad(str(exc)) from None
    return str(v)


Count = Annotated[int | None, BeforeValidator(_optional(_at_least(1)))]


@dataclass(frozen=True, config=STRICT)
class McmcSection:
    """The keys of ``[mcmc]`` (docs/MCMC.md); None where the file gives none (the default is the
    sampler's, or the least-squares model's offsets)."""

    scope: Annotated[str, BeforeValidator(_one_of(SCOPES))] = "phonemes"
    phonemes: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_strings))] = None
    channels: Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_strings))] = None
    noise: Annotated[str | float, BeforeValidator(_level(("free", "fit")))] = "free"
    offsets: Annotated[str | float | None, BeforeValidator(_optional(_level(("free", "none"))))] = None
    priors: Annotated[dict[str, dict[str, tuple[float, float]]], BeforeValidator(_priors)] = field(
        default_factory=dict)
    walkers: Annotated[int, BeforeValidator(_at_least(0))] = 0
    ensembles: Count = None
    chunk_steps: Count = None
    min_steps: Count = None
    max_steps: Count = None
    seed: Annotated[int | None, BeforeValidator(_optional(_at_least(0)))] = None
    ball: Annotated[float | None, BeforeValidator(_optional(_ball))] = None
    moves: Annotated[str | None, BeforeValidator(_optional(_moves))] = None
    plots: Flag = True


ALLOWED: tuple[str, ...] = tuple(McmcSection.__dataclass_fields__)


def parse_section(raw: Any, path: Path) -> McmcSection:
    """The checked ``[mcmc]`` table (None: every default); every problem named as
    ``file: [mcmc] key: message``."""
    if raw is None:
        return McmcSection()
    if not isinstance(raw, dict):
        raise McmcConfigError(f"{path}: [mcmc] must be a table, got {raw!r}")
    unknown = sorted(set(raw) - set(ALLOWED))
    if unknown:  # named one by one, as a key of [mcmc] (the schema would name the table)
        raise McmcConfigError(f"{path}: [mcmc] {', '.join(unknown)}: unknown key(s); allowed: {', '.join(sorted(ALLOWED))}")
    try:
        section: McmcSection = McmcSection.__pydantic_validator__.validate_python(  # type: ignore[attr-defined]
            ArgsKwargs((), dict(raw)))
    except ValidationError as e:
        err: SpecError = schema_error(e, path, (), lambda loc: ".".join(str(p) for p in loc), lambda loc: None,
                                      "[mcmc]")
        raise McmcConfigError("\n".join(f"{path}: [mcmc] {key}: {message}" for key, message in err.problems)) from None
    return section
