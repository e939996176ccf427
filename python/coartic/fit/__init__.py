"""Least-squares fitting of the coarticulation model (MODEL.md §5) to recorded channels.

``run(spec)`` is the whole job in one call (the ``coartic fit`` command calls it too).
"""

from coartic.fit.spec import FitSpec, SpecError, load_spec

__all__ = ["FitSpec", "SpecError", "load_spec", "run"]


def __getattr__(name: str) -> object:
    # Lazy: importing the spec must not load the engines (nlopt, CasADi) or matplotlib.
    if name == "run":
        from coartic.fit.runner import run

        return run
    raise AttributeError(name)
