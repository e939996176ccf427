"""The MCMC side's errors, all ``coartic.errors.CoarticError`` (and ``ValueError``, as before)."""

from __future__ import annotations

from coartic.errors import CoarticError


class McmcError(CoarticError, ValueError):
    """A posterior that cannot be sampled as asked: the message names the channel, table or file."""


class McmcConfigError(McmcError):
    """A bad ``[mcmc]`` section; the message names the file and key."""


class ChainError(McmcError):
    """A chain store (directory of chunks) that cannot be resumed: the message names the file and
    what to delete."""
