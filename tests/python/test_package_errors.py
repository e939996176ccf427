"""Every error the package raises on purpose is a coartic.errors.CoarticError (issue 21 item 2):
``except CoarticError`` catches them all, and each keeps its built-in base (ValueError...) too."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "python" / "coartic"
BUILTIN = {"ValueError", "TypeError", "RuntimeError", "KeyError", "IndexError", "OSError", "Exception"}
# Python protocols that require a built-in error, and one raise caught on the next lines:
# (file, raised name, enclosing function)
ALLOWED = {
    ("io/trial.py", "KeyError", "__getitem__"),  # Mapping protocol: `in`, .get() rely on KeyError
    ("estimation/parameters.py", "KeyError", "__getitem__"),
    ("io/emu.py", "ValueError", "parse_ssff"),  # caught below and re-raised as DataError
    ("outputs.py", "OSError", "_exchange"),  # renameat2's errno, as os.rename would raise it
}


def plain_raises() -> list[tuple[str, str, str, int]]:
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for func in [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]:
            for node in ast.walk(func):
                if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) \
                        and isinstance(node.exc.func, ast.Name) and node.exc.func.id in BUILTIN:
                    found.append((path.relative_to(PACKAGE).as_posix(), node.exc.func.id, func.name, node.lineno))
    return found


def test_no_plain_builtin_error_is_raised() -> None:
    bad = sorted({(f, e, fn, line) for f, e, fn, line in plain_raises() if (f, e, fn) not in ALLOWED})
    assert not bad, "raise a coartic.errors.CoarticError subclass instead: " + "; ".join(
        f"{f}:{line} {e} in {fn}()" for f, e, fn, line in bad)


def test_the_check_sees_a_plain_raise(tmp_path: Path) -> None:
    # the walker itself: a plain raise inside a method is found
    tree = ast.parse("class A:\n    def f(self):\n        raise ValueError('x')\n")
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Raise)]
    assert calls and isinstance(calls[0].exc, ast.Call) and calls[0].exc.func.id == "ValueError"  # type: ignore[attr-defined]
