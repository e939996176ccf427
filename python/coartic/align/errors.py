"""The aligner's errors and warnings."""

from coartic.runtime.errors import AnimationError


class AlignError(AnimationError):
    """A recording or transcript the aligner cannot use: the message says which and what to do."""


class AlignWarning(UserWarning):
    """An alignment that was made but may be wrong (low confidence): said on the console, kept in
    the alignment's `warnings`, and written into the alignment report."""
