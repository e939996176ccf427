"""The one exception every reader raises on bad input, so callers catch a single type."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from coartic.errors import CoarticError


class DataError(CoarticError, ValueError):
    """Bad or unreadable input data; the message names the file and what is at fault.

    `path`, `line` and `item` (a marker, label, tier or column name) are kept as attributes so
    programs can react without parsing the message.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | PathLike[str] | None = None,
        line: int | None = None,
        item: str | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.line = line
        self.item = item
        where = ""
        if self.path is not None:
            where = f"{self.path}"
            if line is not None:
                where += f", line {line}"
            where += ": "
        super().__init__(where + message)


class DataWarning(UserWarning):
    """Data that reads but looks wrong (implausible values, axes that seem swapped): the result may
    be wrong, so the CLI prints it; `warnings.simplefilter("error", DataWarning)` makes it an error."""


def parse_json(text: str, path: str | PathLike[str]) -> object:
    """A small JSON file (label or role map) read as strictly as a parameter table: duplicate keys
    (json keeps the last silently), deep nesting and unreadable numbers are a DataError."""
    from coartic.table import TableError, parse_json as parse_table_json

    try:
        return parse_table_json(text, str(path))
    except TableError as e:
        raise DataError(str(e).removeprefix(f"{path}: "), path=path) from None
