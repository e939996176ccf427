"""The one base class of every error coartic raises on purpose.

``except coartic.errors.CoarticError`` catches them all: bad data (``DataError``), a bad spec
(``SpecError``), table (``TableError``), MCMC settings (``McmcConfigError``), model input
(``ModelInputError``), the Rust core's own errors (``coartic._core.CoarticError``), the
animation runtime's (``AnimationError``). Each subclass keeps its usual built-in base as well
(``ValueError`` for bad input), so existing ``except ValueError`` code still catches them.

Where an error concerns a place in the model's input, it says so in attributes as well as in its
message, so that a program can react without parsing text. Every attribute is ``None`` when it
does not apply:

``utterance``, ``segment``
    Indices counted from 0, as in the lists and arrays given (``segment`` within its utterance).
    Messages count utterances and segments from 1, as label files and the rest of coartic do
    ("utterance 1, segment 3" is ``utterance == 0``, ``segment == 2``).
``phoneme``
    The core gives the row of the parameter matrix (an ``int``); the Python layers, which know
    the phoneme names, give the name (a ``str``).
``parameter``
    A parameter name (``"alpha"``, ``"k_r"``, …) or a global (``"beta"``, ``"apex_fraction"``).
``value``
    The offending value.
``sample``, ``walker``
    Indices counted from 0 into the samples of the corpus and the walkers of a batch.
``reason``
    What is wrong, in a few words ("is not finite", "is outside its domain [0, 1]").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


class CoarticError(Exception):
    """Base of every error coartic raises on purpose; see the module docstring for the attributes."""

    utterance: int | None = None
    segment: int | None = None
    phoneme: int | str | None = None
    parameter: str | None = None
    value: float | None = None
    sample: int | None = None
    walker: int | None = None
    reason: str | None = None


class UsageError(CoarticError, ValueError, TypeError):
    """A library function called with arguments it does not take (a Python caller's mistake, not
    bad data): both a ValueError and a TypeError, as Python's own functions raise either."""


class SpecError(CoarticError, ValueError):
    """A fit specification that cannot be used. The message names the file and the key
    (``spec.toml: [override #3.fixed.theta_bw] ...``); so do the attributes, for programs that must
    not parse prose: ``file`` (the spec's path), ``key`` (the whole place: ``"model.beta"``,
    ``"override #3.fixed.theta_bw"``), ``section`` (``"model"``, ``"override"``; None at the top
    level), ``entry`` (the index of a ``[[override]]``, ``[[tie]]`` or ``[[shrink]]`` table, counted
    from 0 as in the spec's lists: ``override #3`` is entry 2), and where one is at fault
    ``phoneme`` (its name, never an index; several as "p, b"), ``parameter`` and ``value``.
    ``problems`` lists every (key, message) when the schema found several at once."""

    file: Path | None = None
    key: str | None = None
    section: str | None = None
    entry: int | None = None
    problems: tuple[tuple[str, str], ...] = ()

    @classmethod
    def at(cls, file: Path | str | None, key: str | None, message: str, phoneme: str | None = None, *,
           parameter: str | None = None, value: Any = None) -> SpecError:
        """``file: [key] message`` (``file: message`` for the file as a whole, key None), with the
        place in the attributes as well."""
        text = message if key is None else f"[{key}] {message}"
        err = cls(text if file is None else f"{file}: {text}")
        err.file = None if file is None else Path(file)
        err.key, err.phoneme, err.parameter, err.value = key, phoneme, parameter, value
        err.section, err.entry = _section_entry(key)
        err.problems = ((key or "", message),)
        return err


def _section_entry(key: str | None) -> tuple[str | None, int | None]:
    """("override", 2) of "override #3.fixed.theta_bw", ("model", None) of "model.beta"; (None,
    None) at the top level."""
    head = (key or "top level").split(".", 1)[0]
    if head in ("top level", "name"):
        return None, None
    name, sep, number = head.partition(" #")
    return name, int(number) - 1 if sep and number.isdigit() else None
