"""The layering of ``myriad.runtime``: no import cycle among its modules, and the compilation infrastructure names
no solver, transcription or core type.

The import graph is read from the source with :mod:`ast` (nothing is imported), counting imports inside functions
(a function-local import is how a cycle hides) and skipping ``if TYPE_CHECKING:`` blocks, which never run. An edge
goes to the module named; ``from .pkg import name`` goes to ``pkg.name`` when that is a module, else to the package.
Importing ``a.b.c`` also runs the package ``a/__init__.py``, but those implicit edges are not counted: a package
that re-exports its members would otherwise be a cycle with each of them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2] / "runtime"
PACKAGE = "myriad.runtime"

# Cycles known and owned elsewhere, each a sorted tuple of module names (without the "myriad.runtime." prefix).
# TODO(issue 28): empty this list as the owners break them.
KNOWN_CYCLES: list[tuple[str, ...]] = []


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGE, *parts])


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imported(path: Path, modules: set[str], root: Path = ROOT) -> set[str]:
    """The modules of ``myriad.runtime`` that ``path`` imports anywhere (functions included), TYPE_CHECKING aside."""
    name, is_package = _module_name(path, root), path.name == "__init__.py"
    found: set[str] = set()

    def target(module: str, member: str) -> str:
        return f"{module}.{member}" if f"{module}.{member}" in modules else module

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for other in child.orelse:
                    visit_node(other)
                continue
            visit_node(child)

    def visit_node(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith(PACKAGE))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")[: None if is_package else -1]
                base = base[: len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if module.startswith(PACKAGE):
                found.update(target(module, alias.name) for alias in node.names)
        visit(node)

    visit(ast.parse(path.read_text(), str(path)))
    found.discard(name)
    return {m for m in found if m in modules}


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    paths = {_module_name(p, root): p for p in root.rglob("*.py")}
    modules = set(paths)
    return {m: _imported(p, modules, root) for m, p in paths.items()}


def cycles(graph: dict[str, set[str]]) -> list[tuple[str, ...]]:
    """The strongly connected components of more than one module (Tarjan), each as a sorted tuple."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[tuple[str, ...]] = []

    def connect(v: str) -> None:  # recursion depth is bounded by the number of modules (a few hundred)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(tuple(sorted(component)))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def _short(component: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(sorted(m.removeprefix(PACKAGE + ".") for m in component))


def test_the_graph_counts_function_local_imports_and_skips_type_checking(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "__init__.py").write_text("from .pkg import b as b\n")
    (tmp_path / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import c\n"
                                   "def f():\n    from .pkg.b import g\n")
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "b.py").write_text("import myriad.runtime.c\ndef g():\n    from .. import a\n")
    (tmp_path / "c.py").write_text("from .pkg import b\n")
    graph = {k.removeprefix(PACKAGE + "."): {d.removeprefix(PACKAGE + ".") for d in v}
             for k, v in import_graph(tmp_path).items()}
    assert graph == {PACKAGE: {"pkg.b"}, "a": {"pkg.b"}, "pkg": set(), "pkg.b": {"a", "c"}, "c": {"pkg.b"}}
    assert [_short(c) for c in cycles(import_graph(tmp_path))] == [("a", "c", "pkg.b")]


def test_no_import_cycle_in_runtime():
    found = [_short(c) for c in cycles(import_graph())]
    new = [c for c in found if c not in KNOWN_CYCLES]
    assert not new, "import cycles among myriad.runtime's modules (break them, see runtime/README.md):\n" + \
        "\n".join(" <-> ".join(c) for c in new)
    gone = [c for c in KNOWN_CYCLES if c not in found]
    assert not gone, f"these known cycles are gone: remove them from KNOWN_CYCLES: {gone}"


@pytest.mark.parametrize("package", ["compilation"])
def test_infrastructure_names_no_solver_or_method(package):
    """The compilation package imports nothing of the runtime but itself and the atomic-write helper: solvers,
    transcriptions and core types import it and register their types with it (``programs.register_namedtuple``)."""
    graph = import_graph()
    prefix = f"{PACKAGE}.{package}"
    allowed = {f"{PACKAGE}.atomic"}
    outside = {(m, d) for m, deps in graph.items() if m == prefix or m.startswith(prefix + ".")
               for d in deps if not (d == prefix or d.startswith(prefix + ".")) and d not in allowed}
    assert not outside, f"{package} imports outside itself: {sorted(outside)}"
