"""The one registry meta-test, over the whole of ``runtime/``, module by module.

It imports every module under ``myriad.runtime`` (also files that no ``__init__`` imports yet) and requires each
concrete subclass of the abstract bases to be registered under its ``label``, and every registered configuration to
be a frozen, hashable dataclass (a static ``jax.jit`` argument), so a new method cannot be forgotten by skipping
the export step or by living outside its package.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil

import pytest

import myriad.runtime as runtime
from myriad.runtime.integrators import INTEGRATORS, AbstractIntegrator
from myriad.runtime.method import AbstractMethod
from myriad.runtime.solvers import SOLVERS, AbstractNLPSolver, AbstractPureSolver
from myriad.runtime.transcriptions import INDIRECT, TRANSCRIPTIONS, AbstractTranscription

# Third-party packages of the optional extras (`rl`: rejax, gymnax, flax): a module built on one of them is skipped
# where the extra is not installed, and only for that reason.
OPTIONAL = {"flax", "gymnax", "rejax"}


def _runtime_modules():
    names = sorted(m.name for m in pkgutil.walk_packages(runtime.__path__, prefix=runtime.__name__ + "."))
    modules = []
    for name in names:
        try:
            modules.append(importlib.import_module(name))
        except ModuleNotFoundError as exc:
            if (exc.name or "").split(".")[0] not in OPTIONAL:
                raise
    return modules


def _concrete_subclasses(base, exclude=None) -> set[type]:
    """Concrete subclasses of ``base`` *defined* in some runtime module (re-exports are counted once)."""
    found = set()
    for module in _runtime_modules():
        for obj in vars(module).values():
            if (inspect.isclass(obj) and obj.__module__ == module.__name__ and issubclass(obj, base)
                    and obj is not base and not inspect.isabstract(obj)
                    and not (exclude and issubclass(obj, exclude))):
                found.add(obj)
    return found


def test_the_walk_sees_every_package():
    names = {m.__name__ for m in _runtime_modules()}
    for pkg in ("integrators", "solvers", "transcriptions", "indirect", "systems"):
        assert f"myriad.runtime.{pkg}" in names
    assert "myriad.runtime.solvers.extragradient" in names


KINDS = {
    "transcriptions": (AbstractTranscription, None, TRANSCRIPTIONS),
    "indirect": (AbstractMethod, AbstractTranscription, INDIRECT),
    "solvers": (AbstractNLPSolver, None, SOLVERS),
    "integrators": (AbstractIntegrator, None, INTEGRATORS),
}


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_concrete_subclass_is_registered_under_its_label(kind):
    base, exclude, table = KINDS[kind]
    concrete = _concrete_subclasses(base, exclude)
    assert concrete, f"no concrete {base.__name__} found: the module walk is broken"
    registered = set(table.values())
    missing = sorted(f"{c.__module__}.{c.__qualname__}" for c in concrete - registered)
    assert not missing, f"concrete {base.__name__} subclasses not in the registry: {missing}"
    # ... and the registry holds nothing else (no abstract class, nothing from outside the hierarchy).
    assert registered == concrete
    for name, cls in table.items():
        assert name == name.lower() and name.isidentifier()
        assert cls.label == name, f"{cls.__qualname__}.label is {cls.label!r}, registered as {name!r}"
        a, b = cls(), cls()
        assert dataclasses.is_dataclass(a) and a == b and hash(a) == hash(b), name
        if dataclasses.fields(a):
            with pytest.raises(dataclasses.FrozenInstanceError):
                setattr(a, dataclasses.fields(a)[0].name, None)
    assert len(set(table.values())) == len(table)  # one name per class


def test_methods_solvers_and_integrators_have_what_the_glue_reads():
    assert not set(TRANSCRIPTIONS) & set(INDIRECT)
    for cls in [*TRANSCRIPTIONS.values(), *INDIRECT.values()]:
        # One grid word: every method builds itself on an N-interval control grid, and names its quadrature.
        assert callable(cls.on_grid) and isinstance(cls.on_grid(8).quadrature, str)
    for cls in INDIRECT.values():
        # An indirect method produces no NLP: it must not pose as a transcription; it solves by itself.
        assert not issubclass(cls, AbstractTranscription) and issubclass(cls, AbstractMethod)
        assert issubclass(cls, AbstractPureSolver)  # the sweep is one pure JAX function of the problem data
    for cls in INTEGRATORS.values():
        assert isinstance(cls.order, int) and cls.order >= 1 and isinstance(cls.fixed_step, bool)
    pure = {cls for cls in SOLVERS.values() if issubclass(cls, AbstractPureSolver)}
    assert pure, "no pure-JAX NLP solver registered: solve_batch would have nothing to run"
