"""How every `coartic` command tells people (and scripts) what went wrong.

Messages name files, keys and labels; a terminal narrower than a temporary path must not break
them mid-path, so errors are soft-wrapped (one logical line, wrapped by the terminal if at all)
and escaped (a file name like `[red]x.toml` is text, not markup).
"""
from __future__ import annotations

from rich.console import Console
from rich.markup import escape


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
