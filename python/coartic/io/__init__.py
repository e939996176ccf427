"""Recorded data in: C3D, marker CSV/TSV and EMA tables, phone labels, label maps, gaps.

`load_trial(path, labels=..., label_map=..., role_map=...)` is the entry point; every reader
raises `DataError` (a ValueError) naming the file and the marker, label or line at fault.
See docs/DATA.md. The names below are imported on first use: reading labels (coartic.io.labels)
does not load SciPy's signal processing, which only gap filling (coartic.io.gaps) needs.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # "X as X": re-exported for the type checker (__all__ below is built at run time)
    from coartic.io.errors import DataError as DataError, DataWarning as DataWarning
    from coartic.io.gaps import DEFAULT_MAX_GAP as DEFAULT_MAX_GAP, Gap as Gap
    from coartic.io.labelmap import LabelMap as LabelMap
    from coartic.io.labels import Segments as Segments, read_labels as read_labels
    from coartic.io.roles import RoleMap as RoleMap
    from coartic.io.trial import Channels as Channels, Trial as Trial, common_rate as common_rate
    from coartic.io.load import load_trial as load_trial
    from coartic.table import ALL_CHANNELS as ALL_CHANNELS, PAUSE as PAUSE

# name -> the module that defines it
_LAZY: dict[str, str] = {
    "ALL_CHANNELS": "coartic.io.trial",
    "DEFAULT_MAX_GAP": "coartic.io.gaps",
    "PAUSE": "coartic.io.labelmap",
    "Channels": "coartic.io.trial",
    "DataError": "coartic.io.errors",
    "DataWarning": "coartic.io.errors",
    "Gap": "coartic.io.gaps",
    "LabelMap": "coartic.io.labelmap",
    "RoleMap": "coartic.io.roles",
    "Segments": "coartic.io.labels",
    "Trial": "coartic.io.trial",
    "common_rate": "coartic.io.trial",
    "load_trial": "coartic.io.load",
    "read_labels": "coartic.io.labels",
}

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'coartic.io' has no attribute {name!r}")
