"""The end-to-end learner reaches the solvers through their public objects only (issue 28): no module of
``runtime/e2e/`` imports a solver's internals, and one module holds the implicit-function (KKT) rule.

Both checks read the source (``ast``): they hold for function-local imports too."""

import ast
from pathlib import Path

RUNTIME = Path(__file__).resolve().parents[3] / "runtime"
INTERNALS = {"loop", "box", "lagrangian", "penalty", "scaling"}


def _imported_modules(path: Path) -> set[tuple[str, ...]]:
    """Every imported module of ``path`` as its dotted parts (``from .x import y`` gives ``x`` and ``x.y``: ``y``
    may be a module)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(tuple(alias.name.split(".")) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = tuple((node.module or "").split(".")) if node.module else ()
            out.add(base)
            out.update(base + (alias.name,) for alias in node.names)
    return out


def test_no_end_to_end_module_imports_a_solvers_internals():
    offenders = {
        f"{path.name}: {'.'.join(parts)}"
        for path in sorted((RUNTIME / "e2e").rglob("*.py"))
        for parts in _imported_modules(path)
        if "solvers" in parts and INTERNALS & set(parts[parts.index("solvers") + 1:])
    }
    assert not offenders, sorted(offenders)


def test_one_implicit_function_rule():
    """Only ``runtime/solvers/implicit.py`` defines a ``jax.custom_vjp`` or solves a KKT system for a VJP."""
    holders = set()
    for path in sorted(RUNTIME.rglob("*.py")):
        if "systems" in path.relative_to(RUNTIME).parts:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "custom_vjp":
                holders.add(str(path.relative_to(RUNTIME)))
            if isinstance(node, ast.FunctionDef) and node.name in ("kkt_vjp", "_data_vjp"):
                holders.add(str(path.relative_to(RUNTIME)))
    assert holders == {"solvers/implicit.py"}, sorted(holders)
