"""Outputs that are whole or absent, and never a mix of two runs (docs/OUTPUTS.md).

- ``atomic_write_text`` / ``atomic_write_bytes`` / ``atomic_path``: a file is written under a
  temporary name beside its destination, flushed to disk (fsync) and renamed over it, so a reader
  (or a crash) sees the old file or the new one, never half of one.
- ``OutputDir``: the output directory of one command. Staged (``coartic fit``, ``animate``,
  ``speak``): the run writes into ``.NAME.partial`` beside ``NAME``, and only a finished (or
  Ctrl-C-interrupted) run is swapped in, as a whole, by one rename. In place (``coartic mcmc``,
  whose chains must survive to be resumed): the directory is claimed for the run. Either way a
  lock keeps two runs out of one directory, a marker file (``coartic_run.json``) records which run
  wrote it, and a directory holding another run's output, or files no coartic run wrote, is
  refused unless ``--force``.
- ``DeferredSignals``: Ctrl-C (SIGINT) and ``kill`` (SIGTERM) as KeyboardInterrupt, held back
  while something must reach the disk whole (a chain chunk, the swap of a directory).
"""

from __future__ import annotations

import ctypes
import datetime as _dt
import errno
import fcntl
import json
import os
import shutil
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Callable, Iterator, Mapping, Sequence

from coartic._version import __version__
from coartic.errors import CoarticError

RUN_MARKER = "coartic_run.json"
RUN_SCHEMA = "coartic.run/1"
PARTIAL_SUFFIX = ".partial"  # the staging directory: .NAME.partial beside NAME
OLD_SUFFIX = ".old"  # the previous output between the two renames of a swap without renameat2
LOCK_SUFFIX = ".lock"


class OutputError(CoarticError, ValueError):
    """An output directory that this run must not write (another run's output, in use, unsafe)."""


# ------------------------------------------------------------------------------------ files
def fsync_dir(path: str | os.PathLike[str]) -> None:
    """Make a rename or a new entry in ``path`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as f:
        os.fsync(f.fileno())


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed over ``path`` (after fsync) when the
    block ends without an exception, removed otherwise. The temporary name keeps the suffix, so
    writers that choose the format by suffix (np.savez, matplotlib) behave the same."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    try:
        yield tmp
        _fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding)


def check_output_file(path: str | os.PathLike[str], option: str, example: str = "out.png",
                      create_folder: bool = False) -> Path:
    """An output file an option names, checked before any work: not a folder, in a folder that
    exists (or can be made, with ``create_folder``) and is not a file. The errors name the option
    and the fix, instead of a raw [Errno 21] after the work is done."""
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{option} {p}: is a folder; give the file to write, e.g. {option} {p / example}")
    folder = p.parent
    while not folder.exists() and folder.parent != folder:
        if not create_folder:
            raise OutputError(f"{option} {p}: the folder {p.parent} does not exist; create it or write elsewhere")
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError(f"{option} {p}: {folder} is a file, not a folder; write elsewhere")
    return p


# ---------------------------------------------------------------------------------- signals
def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 100) -> Path:
    """Write a matplotlib figure as PNG through ``atomic_path`` and close it; return the path."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)


class DeferredSignals:
    """Ctrl-C (SIGINT) and ``kill`` (SIGTERM) become KeyboardInterrupt inside the ``with`` block,
    except inside ``saving()``, where they are held back until the block is done (the data on
    disk whole). Outside the main thread (where Python cannot install handlers) it does nothing."""

    def __init__(self) -> None:
        self.old: dict[int, Any] = {}
        self.pending: int | None = None
        self.critical = 0

    def __enter__(self) -> DeferredSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.critical:
            self.pending = signum
            return
        raise KeyboardInterrupt(f"signal {signum}")

    @contextmanager
    def saving(self) -> Iterator[None]:
        self.critical += 1
        try:
            yield
        finally:
            self.critical -= 1
        if self.pending is not None and not self.critical:
            signum, self.pending = self.pending, None
            raise KeyboardInterrupt(f"signal {signum}")

    def __exit__(self, *exc: object) -> None:
        for sig, old in self.old.items():
            signal.signal(sig, old)
        self.old = {}


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold Ctrl-C and SIGTERM until the block is done, then deliver them as KeyboardInterrupt."""
    with DeferredSignals() as signals, signals.saving():
        yield


# -------------------------------------------------------------------------- directory swap
_RENAME_EXCHANGE = 2  # linux/fs.h


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directory entries in one step (Linux renameat2 RENAME_EXCHANGE); False where the
    system or the file system does not offer it."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    r = fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if r == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EPERM, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(a))


def _fsync_tree(root: Path) -> None:
    for dirpath, _, filenames in os.walk(root):
        for name in filenames:
            p = Path(dirpath) / name
            if not p.is_symlink():
                _fsync_file(p)
        fsync_dir(dirpath)


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _inside(path: Path, directory: Path) -> bool:
    return path == directory or directory in path.parents


def read_marker(directory: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The run marker of an output directory, or None if it has none (or an unreadable one)."""
    p = Path(directory) / RUN_MARKER
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("schema") == RUN_SCHEMA else None


def _describe(command: str, identity: Mapping[str, Any]) -> str:
    return f"coartic {command} " + ", ".join(f"{k} {v}" for k, v in identity.items())


class OutputDir:
    """The output directory of one run (see the module docstring); ``with OutputDir(...) as d``
    gives the directory to write into (the staging directory, or ``out`` itself when not staged).

    ``identity`` says which run this is (e.g. the spec's path and the channels): a rerun with the
    same command and identity replaces (or, in place, continues) what is there; anything else is
    refused unless ``force``. ``recognise(out)`` may accept an output written before markers
    existed. ``protect``: paths that must not be inside ``out`` (the run's inputs), since
    replacing ``out`` deletes it. On leaving the block: normally the run is committed as
    ``status`` ("complete" unless the caller set "interrupted"); on KeyboardInterrupt it is
    committed as "interrupted" if it wrote anything; on any other exception it is discarded and
    ``out`` is left as it was.
    """

    def __init__(self, out: str | os.PathLike[str], command: str, identity: Mapping[str, Any], *,
                 force: bool = False, staged: bool = True, protect: Sequence[str | os.PathLike[str]] = (),
                 recognise: Callable[[Path], bool] | None = None) -> None:
        # Resolved (symlinks, `..`) before anything is compared or removed: a symlink to the output
        # directory keeps its link and the directory it points to is replaced; an input reached
        # through a symlinked folder is still recognised as inside it.
        self.given = Path(out)
        self.out = Path(os.path.realpath(out))
        if self.out.parent == self.out:  # before the names below: the root has none
            raise OutputError(f"{self._named()}: the root directory cannot be an output directory (replacing "
                              "it would delete everything); choose a folder of its own as --out")
        self.command = command
        self.identity = {k: (str(v) if isinstance(v, os.PathLike) else v) for k, v in identity.items()}
        self.force = force
        self.staged = staged
        self.protect = [Path(os.path.realpath(p)) for p in protect]
        self.recognise = recognise
        self.status = "complete"
        self._abandoned = False
        self.started = _now()
        name = self.out.name
        self.partial = self.out.with_name(f".{name}{PARTIAL_SUFFIX}")
        self.old = self.out.with_name(f".{name}{OLD_SUFFIX}")
        self.lock_path = self.out.with_name(f".{name}{LOCK_SUFFIX}")
        self._lock_fd: int | None = None
        self.path = self.partial if staged else self.out

    # -------------------------------------------------------------------- checks and lock
    def _named(self) -> str:
        """The output directory as given, and where it resolves to when that differs."""
        given = str(self.given)
        return given if os.path.abspath(given) == str(self.out) else f"{given} (resolves to {self.out})"

    def _check_safe(self) -> None:
        if self.out.exists() and not self.out.is_dir():
            raise OutputError(f"{self._named()}: exists and is a file, not a directory; choose another --out")
        cwd = Path(os.path.realpath(os.getcwd()))
        if self.out.exists() and _inside(cwd, self.out):
            raise OutputError(f"{self._named()}: is (or contains) the current directory; replacing it would delete "
                              "it, so choose an output directory of its own")
        for p in self.protect:
            if _inside(p, self.out):
                raise OutputError(f"{self._named()}: contains {p}, an input of this run; replacing the output "
                                  "directory would delete it, so choose another --out")
        self._check_parent()
        self._check_lock_file()

    def _check_parent(self) -> None:
        """The folder --out goes into can be made: its nearest existing ancestor is a folder."""
        ancestor = self.out.parent
        while not ancestor.exists() and ancestor.parent != ancestor:
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise OutputError(f"{self._named()}: {ancestor} is a file, not a folder, so --out cannot be made "
                              "inside it; choose another --out")

    def _check_ours(self, path: Path, what: str) -> None:
        """``path`` (.NAME.partial, .NAME.old) is removed or renamed by the run: only when it is
        coartic's own (a run marker in it, or an empty folder), never a user's folder of that name."""
        if not os.path.lexists(path):
            return
        if path.is_symlink() or not path.is_dir():
            mine = False
        else:
            mine = read_marker(path) is not None or not any(path.iterdir())
        if not mine:
            hint = (f" If it is the previous content of {self.out} (a run killed while replacing it), rename it "
                    f"back to {self.out.name}." if what.startswith("previous") else "")
            raise OutputError(f"{path}: coartic uses this name for the {what} of --out {self._named()}, but it is "
                              f"not coartic's (no {RUN_MARKER} in it), so it is neither removed nor replaced.{hint} "
                              "Move it away, or choose another --out")

    def _check_lock_file(self) -> None:
        """``.NAME.lock`` is truncated and removed by the run: only coartic's own lock file is."""
        p = self.lock_path
        if not os.path.lexists(p):
            return
        mine = False
        if not p.is_symlink() and p.is_file() and p.stat().st_size <= 1000:
            text = p.read_bytes()
            mine = not text or (text.startswith(b"pid ") and b", coartic " in text)
        if not mine:
            raise OutputError(f"{p}: coartic uses this name for the lock of --out {self._named()}, but it is not "
                              "coartic's lock file, so it is not overwritten. Move it away, or choose another --out")

    def _lock(self) -> None:
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputError(f"{self._named()}: cannot create the folder it goes into ({e.strerror}: "
                              f"{e.filename}); choose another --out") from None
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
            except OSError as e:
                raise OutputError(f"{self._named()}: cannot create its lock file {self.lock_path} "
                                  f"({e.strerror}); choose a folder you can write as --out") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                try:
                    holder = os.read(fd, 200).decode("utf-8", "replace").strip()
                finally:
                    os.close(fd)
                raise OutputError(f"{self.out}: another coartic run is writing it ({holder or 'lock held'}, "
                                  f"lock {self.lock_path}); wait for it to finish or choose another --out") from None
            # the previous holder may have removed the lock file between our open and our lock
            try:
                same = os.stat(self.lock_path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()}, coartic {self.command}, since {self.started}".encode())
        self._lock_fd = fd

    def _unlock(self) -> None:
        if self._lock_fd is None:
            return
        try:
            self.lock_path.unlink(missing_ok=True)
        finally:
            os.close(self._lock_fd)  # closing releases the flock
            self._lock_fd = None

    def _recover(self) -> None:
        """Tidy what a killed run left (we hold the lock, so no live run owns it), once it is
        checked to be coartic's own."""
        for path, what in ((self.partial, "staging folder"), (self.old, "previous output, set aside during a swap")):
            self._check_ours(path, what)
        if self.old.exists():
            if self.out.exists():
                shutil.rmtree(self.old)
            else:  # killed between the two renames of a swap: the previous output comes back
                os.replace(self.old, self.out)
        if self.partial.exists():
            shutil.rmtree(self.partial)

    def _check_owner(self) -> bool:
        """True if ``out`` holds nothing, or this same run's output; raise if it is another's."""
        if not self.out.exists() or not any(self.out.iterdir()):
            return True
        marker = read_marker(self.out)
        if marker is not None:
            theirs = {k: v for k, v in marker.get("identity", {}).items()}
            if marker.get("command") == self.command and theirs == self.identity:
                return True
            what = _describe(str(marker.get("command")), theirs)
        elif self.recognise is not None and self.recognise(self.out):
            return True
        else:
            what = f"files that no coartic run wrote (no {RUN_MARKER})"
        if self.force:
            return False
        raise OutputError(f"{self.out}: holds {what}; this run ({_describe(self.command, self.identity)}) would "
                          "replace it. Choose another --out, or pass --force to replace it")

    # ------------------------------------------------------------------------ the run
    def __enter__(self) -> Path:
        self._check_safe()
        self._lock()
        try:
            self._recover()
            same = self._check_owner()
            if self.staged:
                self.partial.mkdir()
                self._write_marker(self.partial, "running")  # marks it coartic's (see _check_ours)
            else:
                if not same and self.out.exists():  # --force in place: start from nothing
                    shutil.rmtree(self.out)
                self.out.mkdir(parents=True, exist_ok=True)
                self._write_marker(self.out, "running")
        except BaseException:
            self._unlock()
            raise
        return self.path

    def _write_marker(self, directory: Path, status: str) -> None:
        doc = {"schema": RUN_SCHEMA, "command": self.command, "identity": self.identity, "status": status,
               "started": self.started, "finished": None if status == "running" else _now(),
               "argv": sys.argv, "pid": os.getpid(), "coartic": __version__}
        atomic_write_text(directory / RUN_MARKER, json.dumps(doc, indent=1, ensure_ascii=False) + "\n")

    def commit(self) -> None:
        """Mark the run and make it the output: swap the staging directory in, whole."""
        with signals_held():  # a second Ctrl-C must not stop the swap half-way
            if not self.staged:
                self._write_marker(self.out, self.status)
                return
            self._write_marker(self.partial, self.status)
            _fsync_tree(self.partial)
            if self.out.exists() and _exchange(self.partial, self.out):
                shutil.rmtree(self.partial)  # now the previous output
            else:
                if self.out.exists():
                    os.replace(self.out, self.old)
                os.replace(self.partial, self.out)
                fsync_dir(self.out.parent)
                if self.old.exists():
                    shutil.rmtree(self.old)
            fsync_dir(self.out.parent)

    def abandon(self) -> None:
        """Leave ``out`` as it was when the block ends (the run has nothing worth keeping)."""
        self._abandoned = True

    def discard(self) -> None:
        if self.staged and self.partial.exists():
            shutil.rmtree(self.partial, ignore_errors=True)
        elif not self.staged and self.out.exists():
            self._write_marker(self.out, "failed")

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            if self._abandoned:
                self.discard()
            elif exc_type is None:
                self.commit()
            elif issubclass(exc_type, KeyboardInterrupt) and self._wrote_something():
                self.status = "interrupted"
                self.commit()
            else:
                self.discard()
        finally:
            self._unlock()

    def _wrote_something(self) -> bool:
        return self.path.exists() and any(p.name != RUN_MARKER for p in self.path.iterdir())


__all__ = ["OutputDir", "OutputError", "DeferredSignals", "atomic_path", "atomic_write_bytes", "check_output_file",
           "atomic_write_text", "fsync_dir", "read_marker", "save_figure", "signals_held", "RUN_MARKER"]
