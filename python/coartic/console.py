"""How every `coartic` command tells people (and scripts) what it does and what went wrong.

Messages name files, keys and labels; a terminal narrower than a temporary path must not break
them mid-path, so errors are soft-wrapped (one logical line, wrapped by the terminal if at all)
and escaped (a file name like `[red]x.toml` is text, not markup). Progress is live in a terminal
and plain lines elsewhere (`LineProgress`); tables that do not fit the width are folded row by row
(`print_table`): no status word is ever cut.
"""
from __future__ import annotations

import time
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import Progress, ProgressColumn, TaskID
from rich.table import Table
from rich.text import Text


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
