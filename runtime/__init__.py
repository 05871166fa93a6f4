"""myriad.runtime: what consumes generated systems (no sympy is imported here, except to compile specs by path).

    from myriad.runtime import load, solve, MultipleShooting, Ipopt
    sol = solve(load("van_der_pol"), MultipleShooting(intervals=20), Ipopt(tol=1e-8))

The public names are imported on first use (PEP 562): ``import myriad.runtime`` and the ``myriad`` command's start
import no JAX (tests/runtime/test_cold_start.py).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING

# Each public name -> the module (relative to this package) that defines it.
_SOURCES = {
    **dict.fromkeys(("Euler", "Heun", "Midpoint", "RK4", "Adaptive"), "integrators"),
    "load": "loader",
    "simulate": "simulate",
    **dict.fromkeys(("Solution", "solve", "solve_batch"), "solve"),
    **dict.fromkeys(("METHODS", "SolveConfig"), "solve_config"),
    **dict.fromkeys(("SLSQP", "Extragradient", "InteriorPoint", "Ipopt"), "solvers"),
    **dict.fromkeys(("OptimalControlUnavailable", "System", "UnsupportedFeature"), "system"),
    **dict.fromkeys(("HermiteSimpson", "MultipleShooting", "SingleShooting", "Trapezoidal"), "transcriptions"),
    "ForwardBackwardSweep": "indirect",
    "clear_caches": "compilation.caches",
}

__all__ = [
    "load", "solve", "solve_batch", "simulate", "Solution", "System", "OptimalControlUnavailable", "UnsupportedFeature",
    "Euler", "Heun", "Midpoint", "RK4", "Adaptive",
    "SingleShooting", "MultipleShooting", "Trapezoidal", "HermiteSimpson", "ForwardBackwardSweep",
    "Ipopt", "SLSQP", "Extragradient", "InteriorPoint", "METHODS", "SolveConfig", "clear_caches",
]

if TYPE_CHECKING:  # what type checkers and editors see; at run time __getattr__ imports each name on first use
    from .compilation.caches import clear_caches
    from .indirect import ForwardBackwardSweep
    from .integrators import RK4, Adaptive, Euler, Heun, Midpoint
    from .loader import load
    from .simulate import simulate
    from .solve import Solution, solve, solve_batch
    from .solve_config import METHODS, SolveConfig
    from .solvers import SLSQP, Extragradient, InteriorPoint, Ipopt
    from .system import OptimalControlUnavailable, System, UnsupportedFeature
    from .transcriptions import HermiteSimpson, MultipleShooting, SingleShooting, Trapezoidal


def __getattr__(name: str):
    if name not in _SOURCES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_SOURCES[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


class _Package(types.ModuleType):
    def __setattr__(self, name: str, value) -> None:
        # Importing the submodule `solve` (or `simulate`) makes it this package's attribute of that name, which would
        # hide the function `from myriad.runtime import solve` means: the function wins, as with eager imports.
        if isinstance(value, types.ModuleType) and _SOURCES.get(name) == name:
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
