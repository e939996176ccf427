"""How every `coartic` command tells people (and scripts) what it does and what went wrong.

Messages name files, keys and labels; a terminal narrower than a temporary path must not break
them mid-path, so errors are soft-wrapped (one logical line, wrapped by the terminal if at all)
and escaped (a file name like `[red]x.toml` is text, not markup). Progress is live in a terminal
and plain lines elsewhere (`LineProgress`); tables that do not fit the width are folded row by row
(`print_table`): no status word is ever cut.
"""
from __future__ import annotations

import errno
import functools
import time
from typing import Any, Callable, TypeVar

from rich.console import Console
from rich.markup import escape
from rich.progress import Progress, ProgressColumn, TaskID
from rich.table import Table
from rich.text import Text

from coartic.errors import CoarticError


# The exit status of every `coartic` command (docs/OUTPUTS.md, "Exit status").
EXIT_OK = 0
EXIT_NOTHING = 1  # it ran, but nothing usable came out (nothing fitted, no channel, a unit failed)
EXIT_ERROR = 2  # refused: a spec, data, option or output error; nothing was written
EXIT_UNCONFIRMED = 3  # written, but a limit was reached or a result is not confirmed (not converged)
EXIT_INTERRUPTED = 130  # Ctrl-C or kill (128 + SIGINT, as shells report it)

# What an OSError about a path means to the user, and what to do.
_OS_ADVICE = {
    errno.ENOENT: "does not exist: check the path",
    errno.EISDIR: "is a folder: give a file's path",
    errno.ENOTDIR: "goes through a file as if it were a folder: check the path",
    errno.EEXIST: "already exists: choose another path",
    errno.EACCES: "permission denied: choose a path you can read (or write)",
    errno.EPERM: "operation not permitted: choose a path you can read (or write)",
    errno.ENOSPC: "the disk is full: free space or write elsewhere",
    errno.EROFS: "is on a read-only file system: write elsewhere",
}


def _os_message(err: OSError) -> str:
    where = " -> ".join(str(f) for f in (err.filename, err.filename2) if f is not None)
    advice = _OS_ADVICE.get(err.errno or 0, err.strerror or str(err))
    return f"{where}: {advice}" if where else f"{err.strerror or err}"


def _interrupted(err: BaseException) -> str:
    return "interrupted (Ctrl-C or kill): what a command keeps of an interrupted run is in docs/OUTPUTS.md"


def _memory(err: BaseException) -> str:
    return ("out of memory: a setting asks for more than this machine holds (a start count, frame rate or "
            "corpus size): lower it")


# The one table of every command: exception -> exit status -> message. The first row whose type
# matches is used; an exception in no row is a bug in coartic and keeps its traceback.
# Every error coartic raises on purpose is a CoarticError (coartic.errors), whose message names
# the file, key, option or label and the fix; a library's ValueError is a value it refused.
ERRORS: tuple[tuple[type[BaseException], int, Callable[[Any], str]], ...] = (
    (KeyboardInterrupt, EXIT_INTERRUPTED, _interrupted),
    (CoarticError, EXIT_ERROR, str),
    (MemoryError, EXIT_ERROR, _memory),
    (OSError, EXIT_ERROR, _os_message),
    (ValueError, EXIT_ERROR, str),
)


def error_exit(err: BaseException) -> tuple[int, str] | None:
    """The exit status and message of ``err`` by the table ``ERRORS``; None if it is in no row
    (a bug: the traceback is kept)."""
    for kind, code, message in ERRORS:
        if isinstance(err, kind):
            return code, message(err)
    return None


F = TypeVar("F", bound=Callable[..., Any])


def handled(command: F) -> F:
    """``command`` (a typer command function) with its errors reported through ``ERRORS``: one
    soft-wrapped ``error:`` line on stderr and the exit status of the table, no traceback.
    Applied to every command by coartic.cli."""
    import typer

    if getattr(command, "coartic_handled", False):
        return command

    @functools.wraps(command)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except typer.Exit:
            raise
        except BaseException as err:
            found = error_exit(err)
            if found is None:
                raise
            code, message = found
            console = Console(stderr=True)
            if code == EXIT_INTERRUPTED:
                console.print(f"[yellow]{escape(message)}[/]", highlight=False, soft_wrap=True)
            else:
                print_error(console, message)
            raise typer.Exit(code) from None

    run.coartic_handled = True  # type: ignore[attr-defined]
    return run  # type: ignore[return-value]


def positive_finite(value: float | None) -> float | None:
    """A typer callback: a number option that must be finite and above 0 (a duration, a rate).
    NaN passes every comparison, so a bound written as ``x > limit`` alone would let it through."""
    import math

    import typer

    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"{value:g}: give a finite number above 0")
    return value


def print_error(console: Console, err: BaseException | str) -> None:
    console.print(f"[bold red]error:[/] {escape(str(err))}", highlight=False, soft_wrap=True)


def print_warning(console: Console, message: BaseException | str) -> None:
    console.print(f"[bold yellow]warning:[/] {escape(str(message))}", highlight=False, soft_wrap=True)


def show_data_warnings() -> None:
    """Print every `DataWarning` (data that reads but looks wrong) as a `warning:` line on stderr,
    escaped and soft-wrapped like errors, instead of Python's `file:line: DataWarning:` form.
    Other warnings keep Python's printer. Installed once by the `coartic` command."""
    import warnings

    from coartic.io.errors import DataWarning

    if getattr(warnings.showwarning, "coartic", False):
        return
    python_printer = warnings.showwarning
    err = Console(stderr=True)

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
             file: object = None, line: str | None = None) -> None:
        if issubclass(category, DataWarning):
            print_warning(err, message)
        else:
            python_printer(message, category, filename, lineno, file, line)  # type: ignore[arg-type]

    show.coartic = True  # type: ignore[attr-defined]
    warnings.showwarning = show


# Seconds between two progress lines of one task when the output is not a terminal (a log file, a
# pipe, a batch job's output): often enough to show life, rarely enough to read.
PLAIN_EVERY_S = 15.0


class LineProgress(Progress):
    """A rich ``Progress`` that also leaves plain lines, so that a run is followed the same way in
    a terminal, a pipe or a job's log.

    In a terminal the bars are live and transient; when a task stops (or the display closes), its
    final state is printed as one soft-wrapped line, so no status word is cut however narrow the
    terminal. Elsewhere nothing is drawn and every task prints a line when it starts, when its
    description changes (a stage, a unit landed), at most every ``every`` seconds while it
    advances, and when it stops. ``quiet`` prints nothing. The task field ``unit`` names what is
    counted ("evaluations"); the other string fields (``info``, ``status``) follow the count.
    """

    def __init__(self, *columns: str | ProgressColumn, console: Console, quiet: bool = False,
                 every: float = PLAIN_EVERY_S) -> None:
        live = console.is_terminal and not quiet
        super().__init__(*columns, console=console, transient=True, disable=not live)
        self.quiet = quiet
        self.plain = not live and not quiet
        self.every = every
        self._last: dict[TaskID, float] = {}
        self._said: set[TaskID] = set()
        self._text: dict[TaskID, str] = {}

    def line(self, task_id: TaskID) -> Text:
        """The task's state as one line: description, count, fields, elapsed time."""
        with self._lock:
            task = self._tasks[task_id]
            parts = [self.console.render_str(task.description, highlight=False)]
            unit = task.fields.get("unit", "")
            if task.total is not None:
                parts.append(Text(f"{task.completed:g}/{task.total:g}" + (f" {unit}" if unit else "")))
            elif task.completed:
                parts.append(Text(f"{task.completed:g}" + (f" {unit}" if unit else "")))
            for k, v in task.fields.items():
                if k != "unit" and isinstance(v, str) and v:
                    parts.append(self.console.render_str(v, highlight=False))
            if task.elapsed:
                parts.append(Text(f"({task.elapsed:.0f} s)"))
        return Text(" ").join(p for p in parts if p.plain)

    def _say(self, task_id: TaskID) -> None:
        self._last[task_id] = time.monotonic()
        line = self.line(task_id)
        if line.plain != self._text.get(task_id):  # e.g. a task stopped right after its last update
            self._text[task_id] = line.plain
            self.console.print(line, soft_wrap=True, highlight=False)

    def add_task(self, description: str, start: bool = True, total: float | None = 100.0, completed: int = 0,
                 visible: bool = True, **fields: Any) -> TaskID:
        task_id = super().add_task(description, start, total, completed, visible, **fields)
        if self.plain:
            self._say(task_id)
        return task_id

    def update(self, task_id: TaskID, *, total: float | None = None, completed: float | None = None,
               advance: float | None = None, description: str | None = None, visible: bool | None = None,
               refresh: bool = False, **fields: Any) -> None:
        before = self._tasks[task_id].description
        super().update(task_id, total=total, completed=completed, advance=advance, description=description,
                       visible=visible, refresh=refresh, **fields)
        if self.plain:
            changed = description is not None and description != before
            if changed or time.monotonic() - self._last.get(task_id, 0.0) >= self.every:
                self._say(task_id)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        if self.plain and time.monotonic() - self._last.get(task_id, 0.0) >= self.every:
            self._say(task_id)

    def stop_task(self, task_id: TaskID) -> None:
        super().stop_task(task_id)
        if not self.quiet and task_id not in self._said:
            self._said.add(task_id)
            self._say(task_id)

    def stop(self) -> None:
        super().stop()
        if self.quiet:
            return
        for task_id in list(self._tasks):  # tasks left running: their last state, once
            if task_id not in self._said:
                self._said.add(task_id)
                self._say(task_id)


def print_table(console: Console, table: Table, keys: int = 1) -> None:
    """``table`` as a table when every cell fits on one line at the console's width; else its
    title, one block per row (its first ``keys`` cells as a heading, then "column value" pairs
    filling lines, a pair never split: a lone pair wider than the console is soft-wrapped, not
    cut), and its caption. A status word is never cut and a row never wraps over many lines,
    whatever the width."""
    # measured unclamped: rich clamps a table's measure to the width it is given
    if console.measure(table, options=console.options.update_width(1 << 20)).maximum <= console.width:
        console.print(table)
        return
    if table.title:
        title = table.title if isinstance(table.title, Text) else console.render_str(str(table.title))
        console.print(title, highlight=False)
    headers = [str(c.header) for c in table.columns]
    cells = [[c if isinstance(c, Text) else console.render_str(str(c), highlight=False) for c in col.cells]
             for col in table.columns]
    indent = 2
    for r in range(table.row_count):
        row = [cells[c][r] for c in range(len(headers))]
        heading = Text(" ").join(row[:keys])
        heading.stylize("bold")
        console.print(heading, soft_wrap=True, highlight=False)
        pairs = [Text.assemble((h, "dim"), " ", v) for h, v in zip(headers[keys:], row[keys:])]
        line: list[Text] = []
        width = indent
        for p in pairs:
            w = p.cell_len + (3 if line else 0)
            if line and width + w > console.width:
                console.print(Text(" " * indent) + Text("   ").join(line), soft_wrap=True, highlight=False)
                line, width, w = [], indent, p.cell_len
            line.append(p)
            width += w
        if line:
            console.print(Text(" " * indent) + Text("   ").join(line), soft_wrap=True, highlight=False)
    if table.caption:
        caption = table.caption if isinstance(table.caption, Text) else console.render_str(str(table.caption))
        caption.stylize("dim")
        console.print(caption, highlight=False)
