"""Packaging guards: every subpackage is listed (else it would be missing from a wheel), and the layers stay apart."""

import subprocess
import sys
import tomllib

import pytest

from .helpers import ROOT


def test_every_subpackage_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    found = set()
    for top, name in (("compiler", "myriad.compiler"), ("runtime", "myriad.runtime")):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top)
            found.add(".".join([name, *rel.parts]))
    assert found <= listed, f"add to [tool.setuptools] packages: {sorted(found - listed)}"


def _imports_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(m.split('.')[0] for m in sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    return set(out.stdout.split())


def test_compiler_does_not_import_jax():
    assert "jax" not in _imports_after("import myriad.compiler, myriad.compiler.cli")


@pytest.mark.slow
def test_runtime_does_not_import_sympy():
    mods = _imports_after("import myriad.runtime; from myriad.runtime import systems; systems.get('pendulum')")
    assert "sympy" not in mods and "jax" in mods
