"""The method interface: how an optimal-control problem is solved, whether by transcription or indirectly.

:func:`~myriad.runtime.solve.solve` and :func:`~myriad.runtime.solve.solve_batch` only ever call these methods, so
a new kind of method (a transcription, an indirect method) plugs in without touching them. Every method is registered
by its label in :data:`~myriad.runtime.solve_config.METHODS` (the union of the transcriptions' and the indirect
methods' registries), the names the commands and the sweep take.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

from .data import ProblemData
from .solution import Solution
from .system import System

__all__ = ["AbstractMethod"]


class AbstractMethod(abc.ABC):
    """A way to solve a system: a direct transcription handed to an NLP solver, or an indirect method.

    Class attributes:
        label: the registry name (``"hermite_simpson"``), used by the CLI, the bench and :class:`Solution`.
        uses_solver: whether the method hands an NLP to a solver (a direct transcription) or solves by itself (an
            indirect method, which refuses a solver).

    Every method also has a ``quadrature`` (an attribute or property): the label of the rule that integrates the
    dynamics and the cost (an integrator's label for shooting, ``"trapezoidal"``, ``"simpson"``).
    """

    label: ClassVar[str]
    quadrature: ClassVar[str]
    uses_solver: ClassVar[bool] = True

    @classmethod
    @abc.abstractmethod
    def on_grid(cls, intervals: int, **options: Any) -> "AbstractMethod":
        """This method with its controls on ``intervals`` uniform intervals (``intervals + 1`` control nodes).

        The same number means the same control grid for every method, so solutions compare node by node.

        Raises:
            ValueError: ``intervals`` < 1, or a grid this method cannot have.
        """

    @abc.abstractmethod
    def solve_problem(self, system: System, solver: Any, data: ProblemData, z0: Any = None) -> Solution:
        """Solve one problem (not re-simulated; :func:`~myriad.runtime.solve.solve` does that).

        Args:
            solver: the solver object, or None for this method's default; a method that takes no solver refuses one.
            data: the problem data.
            z0: a starting point in this method's variables, or None for its default.
        """

    @abc.abstractmethod
    def solve_problems(self, system: System, solver: Any, data: ProblemData) -> list[Solution]:
        """Solve a batch of problems (every leaf of ``data`` with a leading batch axis) as one vmapped program.

        Raises:
            TypeError: a solver that cannot run inside JAX (see
                :class:`~myriad.runtime.solvers.pure.AbstractPureSolver`).
        """
