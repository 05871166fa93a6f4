"""NLP solvers: each turns an :class:`~myriad.runtime.nlp.NLP` and its ``data`` into an ``NLPResult``.

``SOLVERS`` maps a solver's registry name to its class; tests iterate over it and a meta-test checks that every
concrete solver in this package is registered. See README.md for adding one.
"""

from .base import AbstractNLPSolver as AbstractNLPSolver
from .base import constraint_violation as constraint_violation
from .base import constraint_violations as constraint_violations
from .extragradient import Extragradient as Extragradient
from .extragradient import ExtragradientSolution as ExtragradientSolution
from .interior_point import InteriorPoint as InteriorPoint
from .interior_point import InteriorPointSolution as InteriorPointSolution
from .ipopt import Ipopt as Ipopt
from .pure import AbstractPureSolver as AbstractPureSolver
from .slsqp import SLSQP as SLSQP

SOLVERS: dict[str, type[AbstractNLPSolver]] = {
    "ipopt": Ipopt,
    "slsqp": SLSQP,
    "extragradient": Extragradient,
    "interior_point": InteriorPoint,
}

__all__ = [
    "AbstractNLPSolver",
    "AbstractPureSolver",
    "Extragradient",
    "ExtragradientSolution",
    "InteriorPoint",
    "InteriorPointSolution",
    "Ipopt",
    "SLSQP",
    "SOLVERS",
    "constraint_violation",
    "constraint_violations",
]
