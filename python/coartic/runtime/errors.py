"""The runtime's own exceptions: each message names the file, line, phone, phoneme or parameter at fault."""

from coartic.errors import CoarticError


class AnimationError(CoarticError):
    """Base class for every error of the animation runtime; the CLI prints it without a traceback."""


class FapFormatError(AnimationError):
    """A FAP text file that does not follow the `2.1 <name> <fps> <nframes>` layout."""


class FestivalError(AnimationError):
    """Festival is missing, failed, or produced no usable Segment relation."""


class PhoneMapError(AnimationError):
    """A Festival phone that phones_italian.tsv does not map, or a malformed phone map."""


class MissingPhonemeError(AnimationError):
    """A phoneme of the utterance (or a channel) that the parameter table does not have.

    `segment` is the 0-based index of the segment at fault, when there is one.
    """

    def __init__(self, message: str, segment: int | None = None) -> None:
        super().__init__(message)
        self.segment = segment
