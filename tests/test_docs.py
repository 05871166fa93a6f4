"""The user's documents: README.md stays readable (no table cell over 400 characters: measurement history lives in
docs/notes/), and the site with its API reference builds with ``mkdocs build --strict`` (a docstring reference, a
page or a link that no longer resolves fails here)."""

from __future__ import annotations

import ast
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_CELL = 400


def table_cells(markdown: str) -> list[tuple[int, str]]:
    """``(line, cell text)`` for every cell of every Markdown table outside fenced code blocks; a ``|`` escaped as
    ``\\|`` (as GitHub requires inside a table's code spans) does not split a cell."""
    cells, fenced = [], False
    for number, line in enumerate(markdown.splitlines(), 1):
        stripped = line.strip()
        if stripped.startswith("```"):
            fenced = not fenced
            continue
        if fenced or not stripped.startswith("|"):
            continue
        row = stripped[1:-1] if stripped.endswith("|") and not stripped.endswith("\\|") else stripped[1:]
        cells.extend((number, cell.strip()) for cell in re.split(r"(?<!\\)\|", row))
    return cells


def test_table_cells_are_parsed():
    text = "a\n\n| x | y |\n|---|---|\n| `a \\| b` | c |\n\n```\n| not | a table |\n```\n"
    assert table_cells(text) == [(3, "x"), (3, "y"), (4, "---"), (4, "---"), (5, "`a \\| b`"), (5, "c")]


def _readmes():
    """The project's README.md files: the top level's and every folder's (not the virtualenv's or the site's)."""
    skip = {".venv", "site", "build", ".git"}
    return [p for p in sorted(ROOT.rglob("README.md")) if not skip & set(p.relative_to(ROOT).parts)]


def test_readme_table_cells_are_short():
    assert len(_readmes()) >= 10
    long = [f"{path.relative_to(ROOT)}:{line}: {len(cell)} characters" for path in _readmes()
            for line, cell in table_cells(path.read_text()) if len(cell) > MAX_CELL]
    assert not long, f"table cells over {MAX_CELL} characters (history goes to docs/notes/):\n" + "\n".join(long)


def test_readme_python_examples_parse():
    """Every ```python block of README.md is valid Python (they are run by hand; see the README's Quickstart)."""
    blocks = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(), re.MULTILINE | re.DOTALL)
    assert len(blocks) >= 6
    for block in blocks:
        ast.parse(block)


@pytest.mark.parametrize("module", ["myriad.runtime.cli", "myriad.compiler.cli"])
def test_readme_commands_table_lists_every_command(module, capsys):
    """Each subcommand of ``myriad`` and ``myriadc`` (from their --help) has a row in README.md's Commands table."""
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit):
        main(["--help"])
    names = re.findall(r"^    ([a-z][\w-]*)", capsys.readouterr().out, re.MULTILINE)
    program = "myriad" if module == "myriad.runtime.cli" else "myriadc"
    rows = [cell for _, cell in table_cells((ROOT / "README.md").read_text()) if cell.startswith(f"`{program} ")]
    assert names
    missing = [name for name in names if not any(re.match(rf"`{program} {name}[ `]", row) for row in rows)]
    assert not missing, f"README.md's Commands table has no row for {program} {missing}"


def _help(module: str, argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit):
        importlib.import_module(module).main([*argv, "--help"])
    return capsys.readouterr().out


def test_readme_command_options_exist(capsys):
    """Every ``--option`` a README example or Commands row gives ``myriad COMMAND`` / ``myriadc COMMAND`` is one that
    command's --help lists (the examples keep up with the command line)."""
    text = (ROOT / "README.md").read_text()
    shell = re.findall(r"^```sh\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    lines = [line for block in shell for line in block.splitlines()]
    lines += [cell.strip("`") for _, cell in table_cells(text) if cell.startswith(("`myriad ", "`myriadc "))]
    wrong = []
    for line in lines:
        words = line.split("#")[0].split()
        if len(words) < 2 or words[0] not in ("myriad", "myriadc") or words[1].startswith("-"):
            continue
        module = "myriad.runtime.cli" if words[0] == "myriad" else "myriad.compiler.cli"
        listed = _help(module, [words[1]], capsys)
        wrong += [f"{words[0]} {words[1]} {w}" for w in words[2:] if w.startswith("--")
                  and w.split("=")[0].strip("[]`,.;:()") not in listed]
    assert not wrong, f"README.md uses options the commands do not have: {wrong}"


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="mkdocs is not installed (the docs extra)")
def test_site_builds_strict(tmp_path):
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-f", str(ROOT / "mkdocs.yml"),
         "-d", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    assert (tmp_path / "site" / "api" / "solvers" / "index.html").exists()
