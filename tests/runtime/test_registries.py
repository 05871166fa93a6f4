"""Registry completeness over the whole of ``runtime/``, module by module.

The per-package tests (``test_integrators``, ``test_solvers``, ``test_transcriptions``) check the classes that their
package *exports* or a fixed list of modules. This one imports every module under ``myriad.runtime`` (also files that
no ``__init__`` imports yet) and requires each concrete subclass of the three abstract bases to be registered, so a
new method cannot be forgotten by skipping the export step or by living outside its package.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import myriad.runtime as runtime
from myriad.runtime.integrators import INTEGRATORS, AbstractIntegrator
from myriad.runtime.solvers import SOLVERS, AbstractNLPSolver
from myriad.runtime.transcriptions import INDIRECT, TRANSCRIPTIONS, AbstractTranscription


def _runtime_modules():
    names = sorted(m.name for m in pkgutil.walk_packages(runtime.__path__, prefix=runtime.__name__ + "."))
    return [importlib.import_module(name) for name in names]


def _concrete_subclasses(base) -> set[type]:
    """Concrete subclasses of ``base`` *defined* in some runtime module (re-exports are counted once)."""
    found = set()
    for module in _runtime_modules():
        for obj in vars(module).values():
            if (inspect.isclass(obj) and obj.__module__ == module.__name__ and issubclass(obj, base)
                    and obj is not base and not inspect.isabstract(obj)):
                found.add(obj)
    return found


def test_the_walk_sees_every_package():
    names = {m.__name__ for m in _runtime_modules()}
    for pkg in ("integrators", "solvers", "transcriptions", "systems"):
        assert f"myriad.runtime.{pkg}" in names
    assert "myriad.runtime.solvers.extragradient" in names and "myriad.runtime.transcriptions.fbsm" in names


@pytest.mark.parametrize("base, registries", [
    (AbstractTranscription, (TRANSCRIPTIONS,)),
    (AbstractNLPSolver, (SOLVERS,)),
    (AbstractIntegrator, (INTEGRATORS,)),
], ids=["transcriptions", "solvers", "integrators"])
def test_every_concrete_subclass_is_registered(base, registries):
    registered = {cls for table in registries for cls in table.values()}
    concrete = _concrete_subclasses(base)
    assert concrete, f"no concrete {base.__name__} found: the module walk is broken"
    missing = sorted(f"{c.__module__}.{c.__qualname__}" for c in concrete - registered)
    assert not missing, f"concrete {base.__name__} subclasses not in the registry: {missing}"
    # ... and the registry holds nothing else (no abstract class, nothing from outside the hierarchy).
    assert registered == concrete


def test_registry_names_are_unique_lowercase_and_indirect_methods_are_not_transcriptions():
    tables = [TRANSCRIPTIONS, INDIRECT, SOLVERS, INTEGRATORS]
    for table in tables:
        assert all(name == name.lower() and name.isidentifier() for name in table)
        assert len(set(table.values())) == len(table)  # one name per class
    assert not set(TRANSCRIPTIONS) & set(INDIRECT)
    for cls in INDIRECT.values():
        # An indirect method produces no NLP: it must not pose as a transcription, and it solves by itself.
        assert not issubclass(cls, AbstractTranscription)
        assert callable(getattr(cls, "solve", None)) and callable(getattr(cls, "run", None))
