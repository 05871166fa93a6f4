"""The shape of the hand-written code: no function longer than about 80 lines (split by concept, STYLE.md)."""

import ast

import pytest

from .helpers import ROOT

MAX_LINES = 80
# Generated modules (`myriadc build` writes them) are exempt: their size follows the spec.
GENERATED = (ROOT / "runtime" / "systems",)


def _functions():
    for folder in ("compiler", "runtime", "bench", "scripts"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if any(path.is_relative_to(g) for g in GENERATED):
                continue
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    yield path.relative_to(ROOT), node


def test_no_hand_written_function_is_over_80_lines():
    long = [f"{path}:{node.lineno}: {node.name} has {node.end_lineno - node.lineno + 1} lines"
            for path, node in _functions() if node.end_lineno - node.lineno + 1 > MAX_LINES]
    assert not long, "split these by concept:\n" + "\n".join(long)


@pytest.mark.parametrize("folder", ["compiler", "runtime", "bench"])
def test_the_walk_sees_the_code(folder):
    assert any(str(path).startswith(folder) for path, _ in _functions())
