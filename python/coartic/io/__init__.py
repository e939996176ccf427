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

# The readers register themselves with coartic.io.registry when imported (load_trial asks the
# registry, not each module); this is the list of formats. Order within a priority is kept.
from coartic.io import c3d, ema, emu, est, markers_csv, mview, xrmb  # noqa: E402,F401  (registration)

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
