"""The single entry point: ``solve(system, transcription=..., solver=...)`` and its batched twin.

    solve(system, transcription=MultipleShooting(intervals=20), solver=Ipopt(tol=1e-8))

A :class:`Solution` carries two evaluations that must never be mixed (see the environment reference): ``cost`` and
``defect`` are those of the discretised problem itself (the NLP's quadrature and final state; in the published
setting, Heun on the 100-step grid), and ``simulated_cost`` / ``simulated_defect`` re-simulate the solution's
controls (linearly interpolated) in the true dynamics with the adaptive integrator.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .integrators import INTEGRATORS, Adaptive
from .loader import load
from .nlp import NLP
from .simulate import simulate
from .solvers import SOLVERS, Extragradient, Ipopt
from .solvers.base import AbstractNLPSolver
from .system import System
from .transcriptions import INDIRECT, TRANSCRIPTIONS, AbstractTranscription, ForwardBackwardSweep, SingleShooting
from .transcriptions import default_data
from .transcriptions._common import check_structural_params

__all__ = ["Solution", "solve", "solve_batch", "transcribe", "label"]


@dataclasses.dataclass(frozen=True)
class Solution:
    """A solved (or failed) trajectory optimisation. ``converged`` is False for any failed or unfinished solve.

    Attributes:
        system: the system's name.
        transcription, solver, integrator: labels of the method used.
        times, states, controls: the trajectory on the transcription's grid (NumPy, float64).
        cost: the objective of the discretised problem (minimisation form).
        defect: x_i(T) − required value for each state with a required final value (state order); empty if none.
        converged: the solver converged within tolerance to a point within its constraint tolerance.
        status, message, iterations, constraint_violation: what the solver said.
        simulated_cost, simulated_defect: the controls re-simulated with the adaptive integrator (NaN if skipped).
        simulated_bound_violation: the largest state-bound violation along that re-simulation, relative to the
            bound's magnitude (at least 1): a discretisation can respect bounds at its nodes only.
        compile_seconds, solve_seconds: tracing/compilation vs. the solve itself.
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
    status: Any
    message: str
    iterations: int
    constraint_violation: float
    simulated_cost: float = math.nan
    simulated_defect: list[float] = dataclasses.field(default_factory=list)
    simulated_bound_violation: float = math.nan
    compile_seconds: float = 0.0
    solve_seconds: float = 0.0

    @property
    def max_defect(self) -> float:
        return max((abs(d) for d in self.defect), default=0.0)

    def record(self) -> dict:
        """A JSON-ready dict (no arrays), one record of the bench's JSON."""
        return {
            "system": self.system, "transcription": self.transcription, "solver": self.solver,
            "integrator": self.integrator, "cost": _num(self.cost), "defect": [_num(d) for d in self.defect],
            "converged": bool(self.converged), "status": str(self.status), "message": self.message,
            "iterations": int(self.iterations), "constraint_violation": _num(self.constraint_violation),
            "simulated_cost": _num(self.simulated_cost), "simulated_defect": [_num(d) for d in self.simulated_defect],
            "simulated_bound_violation": _num(self.simulated_bound_violation),
            "compile_seconds": round(self.compile_seconds, 4), "solve_seconds": round(self.solve_seconds, 4),
        }


def _num(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None  # JSON has no NaN/inf


def label(obj: Any) -> str:
    """The registry name of a transcription, solver or integrator object (``"hermite_simpson"``, ``"ipopt"``)."""
    for table in (TRANSCRIPTIONS, INDIRECT, SOLVERS, INTEGRATORS):
        for name, cls in table.items():
            if type(obj) is cls:
                return name
    return type(obj).__name__


@functools.lru_cache(maxsize=256)
def transcribe(system: System, transcription: AbstractTranscription) -> NLP:
    """The NLP for (system, transcription), built once: solvers cache their compiled functions per NLP object."""
    return transcription.transcribe(system)


@functools.lru_cache(maxsize=256)
def _unravel(nlp: NLP):
    # Jitted once per NLP: an eager unravel would re-trace its scan (a fresh closure) on every solve.
    return jax.jit(nlp.unravel)


def _integrator_label(transcription) -> str:
    integ = getattr(transcription, "integrator", None)
    if integ is not None:
        return label(integ)
    return {"trapezoidal": "trapezoidal", "hermite_simpson": "simpson", "fbsm": "rk4"}.get(label(transcription), "-")


def _resimulate(system: System, times, controls, data) -> tuple[float, list[float], float]:
    """Cost, defect and relative state-bound violation of the controls (linearly interpolated), adaptive integrator."""
    times = np.asarray(times)
    controls = np.asarray(controls)
    grid = np.linspace(0.0, system.horizon, times.shape[0])
    if not np.allclose(times, grid, rtol=0, atol=1e-9 * max(1.0, system.horizon)):
        grid = np.linspace(0.0, system.horizon, 4 * times.shape[0])
        controls = np.stack([np.interp(grid, times, controls[:, j]) for j in range(controls.shape[1])], 1)
    sim = simulate(system, controls, data["params"], data["x0"], integrator=Adaptive())
    mask = system.final_mask
    a = system.arrays()
    xs = np.asarray(sim.states)
    with np.errstate(invalid="ignore"):
        over = np.maximum(np.maximum(a["x_lower"] - xs, xs - a["x_upper"]), 0.0)
        size = np.maximum(1.0, np.where(np.isfinite(a["x_upper"]), np.abs(a["x_upper"]), np.abs(a["x_lower"])))
    over = np.where(np.isnan(over), np.inf, over) / np.where(np.isfinite(size), size, 1.0)
    return float(sim.cost), [float(d) for d in np.asarray(sim.defect)[mask]], float(over.max(initial=0.0))


def solve(
    system: System | str,
    transcription: AbstractTranscription | ForwardBackwardSweep | None = None,
    solver: AbstractNLPSolver | None = None,
    *,
    params: dict | None = None,
    x0: Any = None,
    z0: Any = None,
    resimulate: bool = True,
) -> Solution:
    """Solve one optimal-control problem.

    Args:
        system: a system object or a name/path for :func:`myriad.runtime.load`.
        transcription: how to discretise (default: the published setting, ``SingleShooting(controls=100)`` with
            Heun), or a :class:`ForwardBackwardSweep` for the indirect method (``solver`` is then unused).
        solver: the NLP solver (default ``Ipopt()``).
        params: parameter values overriding the spec's (a partial dict is fine).
        x0: the initial state (default: the spec's).
        z0: a starting point for the NLP (default: the transcription's guess).
        resimulate: also evaluate the controls with the adaptive integrator.

    Returns:
        A :class:`Solution`; check ``converged`` (a failed solve is returned, never reported as a success).
    """
    system = load(system) if isinstance(system, str) else system
    transcription = SingleShooting() if transcription is None else transcription
    data = default_data(system, params, x0)
    mask = system.final_mask
    if isinstance(transcription, ForwardBackwardSweep):
        t0 = time.perf_counter()
        r = transcription.solve(system, data["params"], data["x0"])
        jax.block_until_ready(r.states)
        elapsed = time.perf_counter() - t0
        sol = Solution(
            system=system.name, transcription="fbsm", solver="sweep", integrator="rk4",
            times=np.asarray(r.times), states=np.asarray(r.states), controls=np.asarray(r.controls),
            cost=float(r.cost), defect=[float(d) for d in np.asarray(r.defect)[mask]], converged=bool(r.converged),
            status="converged" if r.converged else "not_converged", message=r.message, iterations=int(r.iterations),
            constraint_violation=max((abs(float(d)) for d in np.asarray(r.defect)[mask]), default=0.0),
            solve_seconds=elapsed,
        )
    else:
        solver = Ipopt() if solver is None else solver
        nlp = transcribe(system, transcription)
        sol = _solution(system, transcription, solver, nlp, solver.solve(nlp, data, z0), data)
    if resimulate:
        cost, defect, violation = _resimulate(system, sol.times, sol.controls, data)
        sol = dataclasses.replace(sol, simulated_cost=cost, simulated_defect=defect,
                                  simulated_bound_violation=violation)
    return sol


def solve_batch(
    system: System | str,
    transcription: AbstractTranscription | None = None,
    solver: Extragradient | None = None,
    *,
    params: dict | None = None,
    x0: Any = None,
) -> list[Solution]:
    """Solve a batch of problems that differ in parameters and/or initial state as one vmapped program.

    Args:
        system: the system (or its name/path).
        transcription: default ``SingleShooting()``.
        solver: a solver with ``solve_batch`` (default ``Extragradient()``).
        params: dict of arrays with a leading batch axis (names not given keep the spec's value).
        x0: (B, n_states) initial states, or None for the spec's.

    Returns:
        One :class:`Solution` per problem (not re-simulated: call :func:`solve` for a single one to get that).
    """
    system = load(system) if isinstance(system, str) else system
    transcription = SingleShooting() if transcription is None else transcription
    solver = Extragradient() if solver is None else solver
    sizes = {int(np.shape(v)[0]) for v in (params or {}).values()}
    if x0 is not None:
        sizes.add(int(np.shape(x0)[0]))
    if len(sizes) != 1:
        raise ValueError(f"solve_batch needs one batch size across params and x0, got {sorted(sizes) or 'none'}")
    (batch,) = sizes
    check_structural_params(system, params or {})
    base = default_data(system)
    p = {k: jnp.broadcast_to(v, (batch,)) for k, v in base["params"].items()}
    p.update({k: jnp.asarray(v, dtype=jnp.float64) for k, v in (params or {}).items()})
    xs = jnp.broadcast_to(base["x0"], (batch, system.n_states)) if x0 is None else jnp.asarray(x0, jnp.float64)
    data = {"params": p, "x0": xs}
    nlp = transcribe(system, transcription)
    results = solver.solve_batch(nlp, data)
    host = jax.device_get(data)  # slice on the host: per-problem device slicing dominated small batches
    return [_solution(system, transcription, solver, nlp, res, jax.tree_util.tree_map(lambda a: a[i], host))
            for i, res in enumerate(results)]


def _solution(system: System, transcription, solver, nlp: NLP, res, data) -> Solution:
    """A Solution from an NLP result: the trajectory on the transcription's grid and the discretised defect."""
    times, states, controls = (np.asarray(a) for a in _unravel(nlp)(jnp.asarray(res.z), data))
    defect = (states[-1] - np.asarray(system.final_values))[system.final_mask]
    return Solution(
        system=system.name, transcription=label(transcription), solver=label(solver),
        integrator=_integrator_label(transcription), times=times, states=states, controls=controls,
        cost=float(res.objective), defect=[float(d) for d in defect], converged=bool(res.success),
        status=res.status, message=res.message, iterations=int(res.iterations),
        constraint_violation=float(res.constraint_violation), compile_seconds=float(res.compile_seconds),
        solve_seconds=float(res.solve_seconds),
    )
