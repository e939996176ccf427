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
