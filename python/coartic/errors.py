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
