"""coartic: labial coarticulation modelling (Cohen-Massaro as modified by Cosi & Perin).

The model lives in the Rust core ``coartic._core``; ``ParameterTable`` holds its parameters and
``trajectories`` evaluates them for a segment list; ``Coarticulation`` is the estimator-style
entry point (``fit``, ``predict``, ``score`` on trials: ``coartic.estimator``). Every name below
is imported on first use, so ``import coartic`` (and ``coartic --help``) loads neither the core
nor SciPy.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

from coartic._version import __version__

if TYPE_CHECKING:
    from coartic.estimator import Coarticulation
    from coartic.io.load import load_trial
    from coartic.io.trial import Trial
    from coartic.model import build_corpus, trajectories
    from coartic.table import ALL_CHANNELS, CHANNELS, PARAMETERS, TONGUE_CHANNELS, ParameterTable

# name -> the module that defines it
_LAZY: dict[str, str] = {
    "ALL_CHANNELS": "coartic.table",
    "CHANNELS": "coartic.table",
    "Coarticulation": "coartic.estimator",
    "PARAMETERS": "coartic.table",
    "ParameterTable": "coartic.table",
    "TONGUE_CHANNELS": "coartic.table",
    "Trial": "coartic.io.trial",
    "build_corpus": "coartic.model",
    "load_trial": "coartic.io.load",
    "trajectories": "coartic.model",
}

__all__ = [*_LAZY, "__version__"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'coartic' has no attribute {name!r}")
