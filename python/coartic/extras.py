"""The optional parts of coartic, the packages each needs, and the error that says what to install.

`pip install coartic` is the core: the model, the readers, least squares with SciPy, tables, the
report and the runtime (Festival, the TTS, is a system package). The rest comes as extras, each
installed by name (`pip install 'coartic[mcmc]'`, or `coartic[all]`); `make setup` installs all of
them. A part whose extra is missing stops with `MissingExtra`, naming the extra to install, before
it starts any work. This table and pyproject.toml's `[project.optional-dependencies]` say the
same (tests/python/test_extras.py checks it).
"""

from __future__ import annotations

from collections.abc import Sequence
from importlib.util import find_spec

from coartic.errors import CoarticError

# extra → the modules it brings (import names)
EXTRAS: dict[str, tuple[str, ...]] = {
    "mcmc": ("emcee", "corner", "arviz", "xarray", "pandas"),
    "batch": ("dask", "distributed"),
    "engines": ("nlopt", "casadi"),
    "dataframe": ("pandas",),
    "speech": ("pocketsphinx", "python_speech_features", "dtw"),
    "perceive": ("flask", "waitress", "sqlalchemy", "psycopg", "statsmodels", "pandas"),
}
# a requirement whose import name differs from its distribution's
IMPORT_NAMES = {"dtw-python": "dtw"}


class MissingExtra(CoarticError, ImportError, ValueError):
    """An optional part of coartic asked for without its packages; `extra` names what to install.

    An ImportError, which is what it is, and a ValueError, so that every command's error path
    (which reports bad input by message and exit code) reports it as it reports a bad option."""

    def __init__(self, extra: str, what: str, missing: Sequence[str]) -> None:
        self.extra = extra
        self.missing = tuple(missing)
        super().__init__(f"{what} needs coartic's [{extra}] extra ({', '.join(missing)} "
                         f"{'is' if len(missing) == 1 else 'are'} not installed): "
                         f"pip install 'coartic[{extra}]'")


def missing_modules(modules: Sequence[str]) -> list[str]:
    """Those of `modules` that cannot be imported (looked up, not imported: cheap)."""
    out = []
    for m in modules:
        try:
            found = find_spec(m) is not None
        except (ImportError, ValueError):  # a parent package missing, or a module set to None
            found = False
        if not found:
            out.append(m)
    return out


def require(extra: str, what: str, modules: Sequence[str] | None = None) -> None:
    """Stop with `MissingExtra` unless the extra's packages (or the `modules` of it that `what`
    uses) are installed."""
    missing = missing_modules(EXTRAS[extra] if modules is None else modules)
    if missing:
        raise MissingExtra(extra, what, missing)
