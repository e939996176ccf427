"""Recorded data in: C3D, marker CSV/TSV and EMA tables, phone labels, label maps, gaps.

`load_trial(path, labels=..., label_map=..., role_map=...)` is the entry point; every reader
raises `DataError` (a ValueError) naming the file and the marker, label or line at fault.
See docs/DATA.md.
"""

from coartic.io.errors import DataError, DataWarning
from coartic.io.gaps import DEFAULT_MAX_GAP, Gap
from coartic.io.labelmap import PAUSE, LabelMap
from coartic.io.labels import Segments, read_labels
from coartic.io.roles import RoleMap
from coartic.io.trial import ALL_CHANNELS, Channels, Trial, common_rate, load_trial

__all__ = [
    "ALL_CHANNELS",
    "DEFAULT_MAX_GAP",
    "PAUSE",
    "Channels",
    "DataError",
    "DataWarning",
    "Gap",
    "LabelMap",
    "RoleMap",
    "Segments",
    "Trial",
    "common_rate",
    "load_trial",
    "read_labels",
]
