"""Integrators: one-step methods with linearly interpolated controls, and rollouts over a uniform grid.

Look one up by name with ``INTEGRATORS["rk4"]()``; see README.md in this folder to add one.
"""

from .adaptive import Adaptive as Adaptive
from .base import AbstractIntegrator as AbstractIntegrator
from .dormand_prince import DormandPrince as DormandPrince
from .rollout import rollout as rollout
from .rollout import rollout_with_cost as rollout_with_cost
from .rollout import with_running_cost as with_running_cost
from .runge_kutta import RK4 as RK4
from .runge_kutta import Euler as Euler
from .runge_kutta import Heun as Heun
from .runge_kutta import Midpoint as Midpoint

# Name -> class, for the CLI. Every concrete integrator must be here (a test checks).
INTEGRATORS: dict[str, type[AbstractIntegrator]] = {
    "euler": Euler,
    "heun": Heun,
    "midpoint": Midpoint,
    "rk4": RK4,
    "adaptive": Adaptive,
    "dopri5": DormandPrince,
}

__all__ = [
    "AbstractIntegrator",
    "Adaptive",
    "DormandPrince",
    "Euler",
    "Heun",
    "INTEGRATORS",
    "Midpoint",
    "RK4",
    "rollout",
    "rollout_with_cost",
    "with_running_cost",
]
