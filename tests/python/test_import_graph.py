"""The package's import graph has no circle (issue 21): each module imports only modules below it,
whether at the top or inside a function (a function-level import must not hide a circle).
Imports under ``if TYPE_CHECKING:`` are for annotations only and are left out of the circle check;
estimation's own inputs are checked with them included (issue 28: estimation imports nothing above
it, not even for an annotation)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2] / "python"


def modules(root: Path) -> dict[str, Path]:
    out = {}
    for p in (root / "coartic").rglob("*.py"):
        parts = p.relative_to(root).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def import_graph(root: Path, typing: bool = False) -> dict[str, set[str]]:
    """module -> the package's modules it imports (a name imported from a package counts as the
    submodule of that name when there is one, else as the package); ``typing``: imports under
    ``if TYPE_CHECKING:`` count too."""
    mods = modules(root)

    def owner(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for m, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        typing_only = {id(n) for node in ast.walk(tree)
                       if not typing and isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
                       for n in ast.walk(node)}
        edges: set[str] = set()
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = m.split(".") if path.name == "__init__.py" else m.split(".")[:-1]
                    base = ".".join(pkg[:len(pkg) - node.level + 1] + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            else:
                continue
            edges |= {o for t in targets if t.startswith("coartic") and (o := owner(t)) not in (None, m)}
        graph[m] = edges
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_package_has_no_import_circle() -> None:
    assert circles(import_graph(ROOT)) == []


# The parts above estimation (docs/ARCHITECTURE.md, "Layers"): those that build its settings and use
# its problem.
ABOVE: tuple[str, ...] = ("fit", "mcmc", "evaluation", "report", "cli", "runtime", "batch", "estimator")


def above(module: str) -> bool:
    parts = module.split(".")
    return len(parts) > 1 and parts[0] == "coartic" and parts[1] in ABOVE


def test_estimation_imports_nothing_above_it_type_only_imports_included() -> None:
    # the shared problem sits below least squares and MCMC (issue 21) and owns its inputs (issue 28):
    # build_problem takes coartic.estimation.settings, which a fit spec builds; no annotation names
    # the spec, and the at-bound notes are estimation's own
    graph = import_graph(ROOT, typing=True)
    estimation = {m for m in graph if m.split(".")[:2] == ["coartic", "estimation"]}
    assert {"coartic.estimation.problem", "coartic.estimation.settings", "coartic.estimation.bounds"} <= estimation
    assert {(m, t) for m in estimation for t in graph[m] if above(t)} == set()


def test_the_estimation_check_sees_type_only_and_function_imports(tmp_path: Path) -> None:
    # the check itself: an import inside `if TYPE_CHECKING:` or inside a function is an arrow
    pkg = tmp_path / "coartic"
    (pkg / "estimation").mkdir(parents=True)
    (pkg / "fit").mkdir()
    for init in (pkg / "__init__.py", pkg / "estimation" / "__init__.py", pkg / "fit" / "__init__.py"):
        init.write_text("")
    (pkg / "fit" / "spec.py").write_text("class FitSpec: ...\n")
    (pkg / "report.py").write_text("")
    (pkg / "estimation" / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                             "    from coartic.fit.spec import FitSpec\n")
    (pkg / "estimation" / "b.py").write_text("def f():\n    import coartic.report\n")
    graph = import_graph(tmp_path, typing=True)
    assert graph["coartic.estimation.a"] == {"coartic.fit.spec"} and above("coartic.fit.spec")
    assert graph["coartic.estimation.b"] == {"coartic.report"} and above("coartic.report")
    assert import_graph(tmp_path)["coartic.estimation.a"] == set()  # the circle check leaves it out


def test_a_circle_is_found(tmp_path: Path) -> None:
    # the check itself: a function-level import closing a circle is seen, a TYPE_CHECKING one is not
    pkg = tmp_path / "coartic"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from coartic.b import g\n")
    (pkg / "b.py").write_text("def g():\n    from coartic.a import x\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from coartic.a import x\n")
    assert circles(import_graph(tmp_path)) == [["coartic.a", "coartic.b"]]
