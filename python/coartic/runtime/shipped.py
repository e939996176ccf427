"""The parameter table shipped inside the package: every Italian phoneme, fitted on the synthetic
session's Italian flavour (corpus-synthetic/, fit/italian.toml). `coartic speak` and `coartic
animate` use it when no --table is given.

`make table-italian` regenerates it (session, fit, recovery check, then fit/ship_table.py, which
writes the table and its provenance: the checksums of the inputs it was made from and of the table
itself, and the fit's figures).
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

from coartic.runtime.errors import AnimationError
from coartic.table import ParameterTable

SHIPPED_TABLE = "italian_table.json"
SHIPPED_PROVENANCE = "italian_table.provenance.json"


def shipped_table_path() -> Path:
    """Where the shipped table is (a file inside the installed package)."""
    return Path(str(resources.files("coartic.runtime").joinpath(SHIPPED_TABLE)))


def shipped_provenance() -> dict[str, Any]:
    """How the shipped table was made: command, input checksums, the table's checksum, fit figures."""
    path = Path(str(resources.files("coartic.runtime").joinpath(SHIPPED_PROVENANCE)))
    try:
        doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise AnimationError(f"{path}: the shipped table's provenance cannot be read ({err.strerror}); "
                             "reinstall coartic or run `make table-italian`") from None
    return doc


def load_shipped_table() -> ParameterTable:
    """The shipped Italian table, validated like any table."""
    path = shipped_table_path()
    if not path.is_file():
        raise AnimationError(f"the shipped table {path} is missing from this coartic installation: pass "
                             "--table, or reinstall coartic (make table-italian rebuilds it in a checkout)")
    return ParameterTable.load(path)
