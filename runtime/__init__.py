"""myriad.runtime: what consumes generated systems (no sympy is imported here, except to compile specs by path).

    from myriad.runtime import load, solve, MultipleShooting, Ipopt
    sol = solve(load("van_der_pol"), MultipleShooting(intervals=20), Ipopt(tol=1e-8))
"""

from .integrators import RK4 as RK4
from .integrators import Adaptive as Adaptive
from .integrators import Euler as Euler
from .integrators import Heun as Heun
from .integrators import Midpoint as Midpoint
from .loader import load as load
from .simulate import simulate as simulate
from .solve import Solution as Solution
from .solve import solve as solve
from .solve import solve_batch as solve_batch
from .solve_config import METHODS as METHODS
from .solve_config import SolveConfig as SolveConfig
from .solvers import SLSQP as SLSQP
from .solvers import Extragradient as Extragradient
from .solvers import InteriorPoint as InteriorPoint
from .solvers import Ipopt as Ipopt
from .system import OptimalControlUnavailable as OptimalControlUnavailable
from .system import System as System
from .system import UnsupportedFeature as UnsupportedFeature
from .transcriptions import ForwardBackwardSweep as ForwardBackwardSweep
from .transcriptions import HermiteSimpson as HermiteSimpson
from .transcriptions import MultipleShooting as MultipleShooting
from .transcriptions import SingleShooting as SingleShooting
from .transcriptions import Trapezoidal as Trapezoidal

__all__ = [
    "load", "solve", "solve_batch", "simulate", "Solution", "System", "OptimalControlUnavailable", "UnsupportedFeature",
    "Euler", "Heun", "Midpoint", "RK4", "Adaptive",
    "SingleShooting", "MultipleShooting", "Trapezoidal", "HermiteSimpson", "ForwardBackwardSweep",
    "Ipopt", "SLSQP", "Extragradient", "InteriorPoint", "METHODS", "SolveConfig",
]
