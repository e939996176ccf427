"""coartic: labial coarticulation modelling (Cohen-Massaro as modified by Cosi & Perin).

The model lives in the Rust core ``coartic._core``; ``ParameterTable`` holds its parameters and
``trajectories`` evaluates them for a segment list; ``Coarticulation`` is the estimator-style
entry point (``fit``, ``predict``, ``score`` on trials: ``coartic.estimator``). ``Trial`` and ``load_trial`` (the data
readers) are imported on first use, so ``import coartic`` stays light.
"""

from typing import Any

from coartic.model import build_corpus, trajectories
from coartic.table import ALL_CHANNELS, CHANNELS, PARAMETERS, TONGUE_CHANNELS, ParameterTable

__version__ = "0.1.0"

__all__ = [
    "ALL_CHANNELS",
    "Coarticulation",
    "CHANNELS",
    "PARAMETERS",
    "TONGUE_CHANNELS",
    "ParameterTable",
    "Trial",
    "build_corpus",
    "load_trial",
    "trajectories",
    "__version__",
]


def __getattr__(name: str) -> Any:
    if name == "Coarticulation":  # the estimator (coartic.estimator) loads the fit layer: on first use
        from coartic.estimator import Coarticulation

        return Coarticulation
    if name in ("Trial", "load_trial"):
        from coartic.io import trial

        return getattr(trial, name)
    raise AttributeError(f"module 'coartic' has no attribute {name!r}")
