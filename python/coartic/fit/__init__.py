"""Least-squares fitting of the coarticulation model (MODEL.md §5) to recorded channels.

``run(spec)`` fits every channel and returns the result; it writes nothing. The job that also
validates and writes the files and the report (what ``coartic fit`` runs) is
``coartic.jobs.fit.fit_job(spec, out)``.
"""

from typing import TYPE_CHECKING

from coartic.errors import SpecError
from coartic.fit.spec import FitSpec, load_spec

if TYPE_CHECKING:  # the type of the lazy attribute below, for type checkers
    from coartic.fit.runner import run

__all__ = ["FitSpec", "SpecError", "load_spec", "run"]


def __getattr__(name: str) -> object:
    # Lazy: importing the spec must not load the engines (nlopt, CasADi) or matplotlib.
    if name == "run":
        from coartic.fit.runner import run

        return run
    raise AttributeError(name)
