"""Many speakers and sessions: one fit spec over every group of a corpus, units as Dask tasks.

``run_batch(load_batch_spec(path), out)`` is what ``coartic batch`` calls (docs/BATCH.md).
"""

from coartic.batch.spec import BatchSpec, Group, load_batch_spec

__all__ = ["BatchSpec", "Group", "load_batch_spec", "run_batch"]


def __getattr__(name: str) -> object:
    # Lazy: reading a spec must not import Dask.
    if name == "run_batch":
        from coartic.batch.run import run_batch

        return run_batch
    raise AttributeError(name)
