"""myriad.runtime: what consumes generated systems (no sympy is imported here, except to compile specs by path).

    from myriad.runtime import load, solve, MultipleShooting, Ipopt
    sol = solve(load("van_der_pol"), MultipleShooting(intervals=20), Ipopt(tol=1e-8))
"""

from .integrators import RK4, Adaptive, Euler, Heun, Midpoint
from .loader import load
from .simulate import simulate
from .solve import Solution, solve, solve_batch
from .solve_config import METHODS, SolveConfig
from .solvers import SLSQP, Extragradient, InteriorPoint, Ipopt
from .system import OptimalControlUnavailable, System, UnsupportedFeature
from .transcriptions import ForwardBackwardSweep, HermiteSimpson, MultipleShooting, SingleShooting, Trapezoidal

__all__ = [
    "load", "solve", "solve_batch", "simulate", "Solution", "System", "OptimalControlUnavailable", "UnsupportedFeature",
    "Euler", "Heun", "Midpoint", "RK4", "Adaptive",
    "SingleShooting", "MultipleShooting", "Trapezoidal", "HermiteSimpson", "ForwardBackwardSweep",
    "Ipopt", "SLSQP", "Extragradient", "InteriorPoint", "METHODS", "SolveConfig",
]
