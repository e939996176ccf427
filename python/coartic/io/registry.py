"""Which reader reads a file: a registry keyed by extension and, where extensions are shared or
absent, by the file's first bytes.

Each reader module registers itself at import (`register(Reader(...))`); the registry imports the
built-in reader modules the first time a file's reader is asked for (not before: reading labels
alone loads none of them), so `load_trial` finds every format without importing each reader by
name. A new format is one module with one `register` call, plus its name in `BUILTIN_READERS`
(or an import of the module by whoever adds it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING

from coartic.io.errors import DataError

if TYPE_CHECKING:
    from coartic.io.labels import Segments
    from coartic.io.trial import Trial

# How many leading bytes a sniffer sees.
HEAD_BYTES = 4096


@dataclass(frozen=True)
class ReadRequest:
    """What `load_trial` asks of a reader beyond the path."""

    units: str | None = None  # overrides the file's length unit
    allow_truncated: bool = False  # C3D: read the frames a truncated file holds
    level: str | None = None  # a bundle's annotation level whose labels to return (None: default)


@dataclass(frozen=True)
class Reader:
    """One format. `read` returns the trial and the file's own labels (None when it has none).

    `axes`: the (vertical, anterior) axes of the format's sensors when no role map gives them, or
    None when formats of this kind differ between labs: the axes are then guessed from the
    sensors' geometry and stated in the trial's notes. `sensors`: EMA-like sensors, whose roles
    are guessed from their names when no role map is given.
    """

    name: str
    what: str  # for messages: "MOCHA-TIMIT EST track"
    extensions: tuple[str, ...]
    read: Callable[[Path, ReadRequest], tuple[Trial, Segments | None]]
    sniff: Callable[[Path, bytes], bool] | None = None
    axes: tuple[str, str] | None = ("+z", "-y")
    sensors: bool = False
    default: bool = True  # reads files of its extensions that no other reader's sniffer claims
    # readers are asked in this order (then in order of registration): specific formats first,
    # so that a generic sniffer (a marker CSV's `_x` columns) does not claim an EMA table
    priority: int = 50


_READERS: list[Reader] = []
_REGISTERED: dict[str, int] = {}  # each reader's name -> when it first registered
# the modules of the built-in readers, imported on first use
BUILTIN_READERS = ("coartic.io.c3d", "coartic.io.carstens", "coartic.io.ema", "coartic.io.emu",
                   "coartic.io.est", "coartic.io.markers_csv", "coartic.io.mview", "coartic.io.xrmb")


def _load_builtin() -> None:
    for module in BUILTIN_READERS:
        import_module(module)


def register(reader: Reader) -> Reader:
    """Add a reader; a second reader of the same name replaces the first (re-imported module)."""
    for i, r in enumerate(_READERS):
        if r.name == reader.name:
            _READERS[i] = reader
            return reader
    _REGISTERED.setdefault(reader.name, len(_REGISTERED))
    _READERS.append(reader)
    _READERS.sort(key=_rank)
    return reader


def _rank(r: Reader) -> tuple[int, int, int]:
    """Readers are asked by priority, then the built-ins in ``BUILTIN_READERS``' order, then others
    in order of registration: which built-in claims a file must not depend on which reader module
    some caller happened to import first (the EMU reader, imported by a bundle's caller, came
    before C3D's in the list and in the sniffing)."""
    module = getattr(r.read, "__module__", "")
    builtin = BUILTIN_READERS.index(module) if module in BUILTIN_READERS else len(BUILTIN_READERS)
    return (r.priority, builtin, _REGISTERED[r.name])


def readers() -> tuple[Reader, ...]:
    _load_builtin()
    return tuple(_READERS)


def reader_for(p: Path) -> Reader:
    """The reader of `p`: among the readers of its extension, the first whose sniffer accepts the
    content, else the extension's default reader; for an unknown extension, the first reader
    whose sniffer accepts the content."""
    _load_builtin()
    try:
        with p.open("rb") as f:
            head = f.read(HEAD_BYTES)
    except OSError as e:
        raise DataError(f"cannot read: {e.strerror or e}", path=p) from None
    suffix = p.suffix.lower()
    mine = [r for r in _READERS if suffix in r.extensions]
    for r in mine:
        if r.sniff is not None and r.sniff(p, head):
            return r
    default = next((r for r in mine if r.default), None)
    if default is not None:
        return default
    for r in _READERS:
        if r.sniff is not None and r not in mine and r.sniff(p, head):
            return r
    known = "; ".join(f"{r.what} ({', '.join(r.extensions)})" for r in _READERS)
    raise DataError(f"cannot tell the format of this file (extension {suffix!r}); coartic reads "
                    f"{known}", path=p)
