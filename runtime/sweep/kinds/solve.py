"""``solve``: one trajectory optimisation, as ``myriad solve`` does it (the settings are
:class:`~myriad.runtime.solve_config.SolveConfig`'s fields), optionally from a start state drawn from the task's seed
(``x0_std`` > 0).
"""

from __future__ import annotations

from typing import Any, ClassVar

from ...solve_config import SolveConfig
from ...system import System
from .base import AbstractKind, Outcome, refuse_unsupported

__all__ = ["Solve"]


class Solve(AbstractKind):
    """One ``SolveConfig.solve(system)``; a success is a converged solve."""

    name: ClassVar[str] = "solve"
    Settings: ClassVar[type] = SolveConfig
    columns: ClassVar[tuple[str, ...]] = ("cost", "max_defect", "iterations", "solver_status", "simulated_cost")

    def check_system(self, system: System, settings: dict[str, Any]) -> None:
        method, _ = self.config(settings, seed=0).build()
        if not method.uses_solver:  # the indirect methods; every direct transcription enforces both
            refuse_unsupported(system, f"solve with {method.label}")

    def run(self, system: System, settings: dict[str, Any], seed: int) -> Outcome:
        config = self.config(settings, seed)
        x0 = config.x0(system)
        sol = config.solve(system)
        fields = sol.record()
        del fields["system"], fields["message"]  # the task's own fields (the system as given: a name or a path)
        fields["solver_status"] = fields.pop("status")
        fields["max_defect"] = sol.max_defect
        if x0 is not None:
            fields["x0"] = x0.tolist()
        return Outcome(success=bool(sol.converged), message=sol.message, fields=fields)
