"""The package's import graph has no circle (issues 21, 28): each module imports only modules below
it, whether at the top, inside a function or under ``if TYPE_CHECKING:`` (a function-level or
annotation-only import must not hide a circle: the modules still depend on each other).

The circles still there are listed by name in ``KNOWN_CIRCLES``, each with the issue's work that
removes it; the test asserts that the package has exactly those, so that it fails on a new circle
and on one removed without emptying its entry here."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2] / "python"


# The circles left, each as the set of its modules' names: the work that removes one empties its
# entry, and the test below fails until it does (and on any circle not listed). None is left: the
# last, estimation naming the fit's spec and bound notes in annotations, went when estimation came
# to own its inputs (issue 28 item 1: coartic.estimation.settings).
KNOWN_CIRCLES: set[frozenset[str]] = set()


def modules(root: Path) -> dict[str, Path]:
    """Every module of the package by name: the Python files, and the compiled extension by its stub
    (``_core.pyi``), so that ``from coartic import _core`` is the extension, not the package."""
    out = {}
    for p in sorted((root / "coartic").rglob("*.py*")):
        if p.suffix not in (".py", ".pyi"):
            continue
        parts = p.relative_to(root).with_suffix("").parts
        out.setdefault(".".join(parts[:-1] if parts[-1] == "__init__" else parts), p)
    return out


# The fields of a statement that hold statements (a function's, a class's, an if's, a loop's, a with's
# and a try's bodies, a try's handlers, a match's cases): an import is a statement, so it is in one of
# these, never inside an expression.
BODIES = ("body", "orelse", "finalbody", "handlers", "cases")


def statements(body: list[ast.stmt], type_only: bool) -> Iterator[ast.AST]:
    """Every statement of ``body`` and of the bodies nested in it, at any depth (functions and
    classes included); without ``type_only``, none of an ``if TYPE_CHECKING:``'s. Only the
    statements are visited, not their expressions: 21 thousand of the package's 290 thousand nodes
    (the package's walk 0.23 -> 0.03 CPU-s; parsing it, 0.9, is the rest of a graph)."""
    for node in body:
        if not type_only and isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        yield node
        for field in BODIES:
            yield from statements(getattr(node, field, []), type_only)


def import_graph(root: Path, type_only: bool = True) -> dict[str, set[str]]:
    """module -> the package's modules it imports (a name imported from a package counts as the
    submodule of that name when there is one, else as the package; a relative import is resolved
    against the importing module's package). ``type_only``: imports under ``if TYPE_CHECKING:``
    count too."""
    mods = modules(root)

    def owner(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for m, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        edges: set[str] = set()
        for node in statements(tree.body, type_only):
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


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    """The package's import graph (type-only imports included), parsed once for the file's tests."""
    return import_graph(ROOT)


def test_the_package_has_no_import_circle_but_the_known_ones(graph: dict[str, set[str]]) -> None:
    found = {frozenset(c) for c in circles(graph)}
    assert found - KNOWN_CIRCLES == set(), "new import circle(s)"
    assert KNOWN_CIRCLES - found == set(), "circle(s) removed: take them out of KNOWN_CIRCLES"


def test_the_package_is_a_facade_at_the_top(graph: dict[str, set[str]]) -> None:
    # coartic/__init__.py names the estimator, the trial and the table (for type checkers); no
    # module of the package imports the package back (the version is coartic._version's)
    assert {"coartic.estimator", "coartic.table"} <= graph["coartic"]
    assert sorted(m for m, targets in graph.items() if "coartic" in targets) == []


# The parts above estimation (docs/ARCHITECTURE.md, "Layers"): those that build its settings and use
# its problem.
ABOVE: tuple[str, ...] = ("fit", "mcmc", "evaluation", "report", "jobs", "cli", "runtime", "batch", "estimator")


def above(module: str) -> bool:
    parts = module.split(".")
    return len(parts) > 1 and parts[0] == "coartic" and parts[1] in ABOVE


def test_estimation_imports_nothing_above_it_type_only_imports_included(graph: dict[str, set[str]]) -> None:
    # the shared problem sits below least squares and MCMC (issue 21) and owns its inputs (issue 28):
    # build_problem takes coartic.estimation.settings, which a fit spec builds; no annotation names
    # the spec, and the at-bound notes are estimation's own
    estimation = {m for m in graph if m.split(".")[:2] == ["coartic", "estimation"]}
    assert {"coartic.estimation.problem", "coartic.estimation.settings", "coartic.estimation.bounds"} <= estimation
    assert {(m, t) for m in estimation for t in graph[m] if above(t)} == set()


def test_the_estimation_check_sees_type_only_and_function_imports(tmp_path: Path) -> None:
    # the check itself: an import inside `if TYPE_CHECKING:` or inside a function is an arrow up
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
    graph = import_graph(tmp_path)
    assert graph["coartic.estimation.a"] == {"coartic.fit.spec"} and above("coartic.fit.spec")
    assert graph["coartic.estimation.b"] == {"coartic.report"} and above("coartic.report")


# The shared problem, the fitting library, what evaluates its results and the application that
# writes them, lowest first (issue 28 item 2): a module of each package imports none of a later
# one's, at the top, inside a function or under TYPE_CHECKING.
LAYERS = ("coartic.estimation", "coartic.fit", "coartic.evaluation", "coartic.report", "coartic.jobs")


def package(module: str, packages: tuple[str, ...] = LAYERS) -> str | None:
    return next((p for p in packages if module == p or module.startswith(p + ".")), None)


def upward_arrows(graph: dict[str, set[str]], layers: tuple[str, ...] = LAYERS) -> set[tuple[str, str]]:
    """(module, imported module) for every import from a package of ``layers`` into a later one."""
    rank = {p: i for i, p in enumerate(layers)}
    out = set()
    for m, targets in graph.items():
        src = package(m, layers)
        for t in targets:
            dst = package(t, layers)
            if src is not None and dst is not None and rank[dst] > rank[src]:
                out.add((m, t))
    return out


def test_the_library_sits_below_evaluation_and_the_application(graph: dict[str, set[str]]) -> None:
    # fit -> estimation; evaluation -> fit; report -> evaluation, fit; jobs -> evaluation, fit, report;
    # never back
    assert {"coartic.fit.runner", "coartic.evaluation.validate", "coartic.report.html", "coartic.jobs.fit"} <= set(graph)
    assert upward_arrows(graph) == set()
    # and the arrows that are meant to be there are seen (the check sees the packages' imports)
    assert "coartic.fit.runner" in graph["coartic.evaluation.choose"]
    assert {"coartic.fit.runner", "coartic.evaluation.validate", "coartic.report.html"} <= graph["coartic.jobs.fit"]


def test_an_upward_arrow_is_found(tmp_path: Path) -> None:
    # the layering check itself: a fit module calling up into evaluation inside a function, and one
    # naming a job's type under TYPE_CHECKING, are both upward arrows (the old runner's and result's)
    pkg = tmp_path / "coartic"
    for sub in ("fit", "evaluation", "report", "jobs"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "fit" / "runner.py").write_text("def run():\n    from coartic.evaluation.validate import validate_all\n")
    (pkg / "fit" / "result.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                           "    from coartic.jobs.fit import Job\n")
    (pkg / "evaluation" / "validate.py").write_text("from coartic.fit.runner import run\n")
    (pkg / "jobs" / "fit.py").write_text("from coartic.fit.runner import run\nfrom coartic.report import html\n")
    (pkg / "report" / "html.py").write_text("from coartic.evaluation.validate import x\n")
    assert upward_arrows(import_graph(tmp_path)) == {("coartic.fit.runner", "coartic.evaluation.validate"),
                                                     ("coartic.fit.result", "coartic.jobs.fit")}


def test_a_circle_is_found(tmp_path: Path) -> None:
    # the check itself: a function-level import closing a circle is seen, and so is a TYPE_CHECKING
    # one and a relative one; `from coartic import x` is the submodule x (the extension by its stub)
    pkg = tmp_path / "coartic"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from coartic.a import f\n")
    (pkg / "_ext.pyi").write_text("def h() -> None: ...\n")
    (pkg / "a.py").write_text("from coartic import _ext\nfrom coartic.b import g\n")
    (pkg / "b.py").write_text("def g():\n    from coartic.a import x\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from coartic.sub.d import y\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "d.py").write_text("from .. import c\n")
    graph = import_graph(tmp_path)
    assert graph["coartic.a"] == {"coartic._ext", "coartic.b"}
    assert graph["coartic.sub.d"] == {"coartic.c"}
    assert circles(graph) == [["coartic.a", "coartic.b"], ["coartic.c", "coartic.sub.d"]]
    assert circles(import_graph(tmp_path, type_only=False)) == [["coartic.a", "coartic.b"]]
