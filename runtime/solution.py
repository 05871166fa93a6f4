"""What a solve returns: :class:`Solution`, and the re-simulation that checks it in the continuous dynamics.

A :class:`Solution` carries two evaluations that must never be mixed: ``cost`` and ``defect`` are those of the
discretised problem itself (the NLP's quadrature and final state; in the published setting, Heun on the 100-step
grid), and ``simulated_cost`` / ``simulated_defect`` re-simulate the solution's controls (linearly interpolated)
in the true dynamics with the adaptive integrator.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .data import ProblemData
from .integrators import Adaptive
from .simulate import simulate
from .status import Status
from .system import System

__all__ = ["Solution", "json_number", "resimulate"]


@dataclasses.dataclass(frozen=True)
class Solution:
    """A solved (or failed) trajectory optimisation. ``converged`` is False for any failed or unfinished solve.

    Attributes:
        system: the system's name.
        transcription, solver, integrator: labels of the method used (the integrator is the transcription's
            quadrature: an integrator's label for shooting, ``"trapezoidal"`` or ``"simpson"`` for collocation).
        times, states, controls: the trajectory on the transcription's grid (NumPy, float64).
        cost: the objective of the discretised problem (minimisation form).
        defect: x_i(T) − required value for each state with a required final value (state order); empty if none.
        converged: the solver converged within tolerance to a point within its constraint tolerance.
        status: the outcome (:class:`~myriad.runtime.status.Status`); ``solver_code`` and ``message`` are the
            solver's own code and words for it.
        iterations, constraint_violation: what the solver said.
        simulated_cost, simulated_defect: the controls re-simulated with the adaptive integrator (NaN if skipped).
        simulated_bound_violation: the largest state-bound violation along that re-simulation, relative to the
            bound's magnitude (at least 1): a discretisation can respect bounds at its nodes only.
        compile_seconds, solve_seconds: tracing/compilation vs. the solve itself.
        error_estimate: the relative local error of the dynamics, max over the grid's intervals and the states
            (:mod:`~myriad.runtime.transcriptions.error`); NaN where not computed (the indirect sweep).
        interval_errors: (N,) that error on each interval of the method's grid (max over states), or None.
    """

    system: str
    transcription: str
    solver: str
    integrator: str
    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    cost: float
    defect: list[float]
    converged: bool
    status: Status
    message: str
    iterations: int
    constraint_violation: float
    simulated_cost: float = math.nan
    simulated_defect: list[float] = dataclasses.field(default_factory=list)
    simulated_bound_violation: float = math.nan
    compile_seconds: float = 0.0
    solve_seconds: float = 0.0
    solver_code: int = 0
    error_estimate: float = math.nan
    interval_errors: np.ndarray | None = None

    @property
    def max_defect(self) -> float:
        return max((abs(d) for d in self.defect), default=0.0)

    def record(self) -> dict:
        """A JSON-ready dict (no arrays), one record of the bench's JSON."""
        return {
            "system": self.system, "transcription": self.transcription, "solver": self.solver,
            "integrator": self.integrator, "cost": json_number(self.cost),
            "defect": [json_number(d) for d in self.defect],
            "converged": bool(self.converged), "status": str(self.status), "solver_code": int(self.solver_code),
            "message": self.message,
            "iterations": int(self.iterations), "constraint_violation": json_number(self.constraint_violation),
            "simulated_cost": json_number(self.simulated_cost),
            "simulated_defect": [json_number(d) for d in self.simulated_defect],
            "simulated_bound_violation": json_number(self.simulated_bound_violation),
            "error_estimate": json_number(self.error_estimate),
            "compile_seconds": round(self.compile_seconds, 4), "solve_seconds": round(self.solve_seconds, 4),
        }


def json_number(v) -> float | None:
    """``v`` as a float, or None where it is not finite (JSON has no NaN or inf)."""
    v = float(v)
    return v if math.isfinite(v) else None  # JSON has no NaN/inf


def resimulate(system: System, times, controls, data: ProblemData) -> tuple[float, list[float], float]:
    """Cost, defect and relative state-bound violation of the controls (linearly interpolated), adaptive integrator."""
    times = np.asarray(times)
    controls = np.asarray(controls)
    grid = np.linspace(0.0, system.horizon, times.shape[0])
    if not np.allclose(times, grid, rtol=0, atol=1e-9 * max(1.0, system.horizon)):
        grid = np.linspace(0.0, system.horizon, 4 * times.shape[0])
        controls = np.stack([np.interp(grid, times, controls[:, j]) for j in range(controls.shape[1])], 1)
    sim = simulate(system, controls, data.params, data.x0, integrator=Adaptive())
    mask = system.final_mask
    a = system.arrays()
    xs = np.asarray(sim.states)
    with np.errstate(invalid="ignore"):
        over = np.maximum(np.maximum(a["x_lower"] - xs, xs - a["x_upper"]), 0.0)
        size = np.maximum(1.0, np.where(np.isfinite(a["x_upper"]), np.abs(a["x_upper"]), np.abs(a["x_lower"])))
    over = np.where(np.isnan(over), np.inf, over) / np.where(np.isfinite(size), size, 1.0)
    return float(sim.cost), [float(d) for d in np.asarray(sim.defect)[mask]], float(over.max(initial=0.0))
