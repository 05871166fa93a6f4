"""What the sweep returns: the pure output :class:`SweepState`, the host-side :class:`SweepResult` and
:class:`~myriad.runtime.solution.Solution`, and the map from the sweep's own outcome codes to
:class:`~myriad.runtime.status.Status`."""

from __future__ import annotations

import dataclasses
import enum
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..solution import Solution
from ..status import Status
from ..system import System

__all__ = ["SweepCode", "SweepResult", "SweepState", "STATUS", "outcome", "message", "to_solution"]


class SweepCode(enum.IntEnum):
    """The sweep's own outcome codes (``solver_code``), kept beside the :class:`Status` they map to."""

    CONVERGED = 0
    MAX_ITER = 1  # out of sweeps (before Newton could take over, or in an inner solve of the shooting)
    SHOOTING_FAILED = 2  # Broyden on the fixed final states did not converge
    NON_FINITE = 3
    STATE_BOUNDS_VIOLATED = 4  # converged, but the trajectory leaves the state bounds the sweep cannot enforce
    NEWTON_FAILED = 5  # Newton was reached but stalled


STATUS: dict[SweepCode, Status] = {
    SweepCode.CONVERGED: Status.CONVERGED,
    SweepCode.MAX_ITER: Status.ITERATION_LIMIT,
    SweepCode.SHOOTING_FAILED: Status.NOT_CONVERGED,
    SweepCode.NON_FINITE: Status.NOT_FINITE,
    SweepCode.STATE_BOUNDS_VIOLATED: Status.STATE_BOUNDS_VIOLATED,
    SweepCode.NEWTON_FAILED: Status.NOT_CONVERGED,
}


class SweepState(NamedTuple):
    """The pure, jittable, vmappable output of the sweep (arrays only; every field gains a batch axis under vmap)."""

    times: Any  # (N + 1,)
    states: Any  # (N + 1, n)
    controls: Any  # (N + 1, m)
    costates: Any  # (N + 1, n)
    cost: Any  # J = phi(x(T)) + int L dt (RK4 with the running cost as an extra state)
    defect: Any  # (n,) x(T) - required final values; NaN where x_i(T) is free
    status: Any  # the outcome as a runtime Status (int32)
    solver_code: Any  # the sweep's own code (a SweepCode)
    iterations: Any  # relaxed sweeps in all (including the finite-difference sweeps of the shooting Jacobian)
    shooting_iterations: Any  # quasi-Newton steps on the fixed components of lambda(T) (bang-bang u* only)
    newton_iterations: Any  # Newton steps on Pontryagin's conditions (stationary u* only)
    relaxation: Any  # omega after the step control
    change: Any  # the relative control change u* - u of the returned controls (Newton) or of the last sweep
    residual: Any  # max |x_i(T) - x_final,i| over the fixed states (0 when none)
    bound_violation: Any  # (n,) max over the nodes of the state-bound violation, in units of the state's scale


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """What :meth:`ForwardBackwardSweep.solve` returns: one member's :class:`SweepState` on the host (the worst
    ``bound_violation`` over the states), whether ``status`` is CONVERGED, the outcome in words (``message``), and
    compilation vs. the solve itself (batch members: the batch's shares)."""

    times: Any
    states: Any
    controls: Any
    costates: Any
    cost: float
    defect: Any
    converged: bool
    iterations: int
    shooting_iterations: int
    message: str
    bound_violation: float = 0.0
    newton_iterations: int = 0
    relaxation: float = 0.5
    status: Status = Status.NOT_CONVERGED
    solver_code: int = -1
    compile_seconds: float = 0.0
    solve_seconds: float = 0.0


def outcome(failures: list[tuple[Any, SweepCode]], bounds_violated: Any) -> tuple[Any, Any]:
    """(status, solver_code) as int32 arrays inside the trace: the first failure that holds, else a state-bound
    violation, else CONVERGED."""
    conditions = [*(f for f, _ in failures), bounds_violated]
    codes = [*(int(c) for _, c in failures), int(SweepCode.STATE_BOUNDS_VIOLATED)]
    code = jnp.select(conditions, codes, int(SweepCode.CONVERGED))
    table = jnp.asarray([int(STATUS[c]) for c in SweepCode], dtype=jnp.int32)
    return table[code], code


def message(sweep: Any, system: System, s: SweepState) -> str:
    """The sweep's words for one member's outcome (``s`` on the host); ``sweep`` is the ForwardBackwardSweep."""
    code, its, shoots = SweepCode(int(s.solver_code)), int(s.iterations), int(s.shooting_iterations)
    newton, omega, change = int(s.newton_iterations), float(s.relaxation), float(s.change)
    viol = np.asarray(s.bound_violation)
    worst = int(np.argmax(viol))
    steps = f"{its} sweeps" + (f" and {newton} Newton steps" if newton else f" ({shoots} shooting steps)")
    stepped = "" if omega == sweep.relaxation else f"; the step control lowered the relaxation to {omega:.3g}"
    uses_newton = sweep.newton and system.optimal_control_kind == "stationary"
    if code is SweepCode.CONVERGED:
        text = f"converged in {steps}{stepped}"
    elif code is SweepCode.MAX_ITER:
        text = (f"the sweep did not converge in {steps} (relative control change {change:.3g} > "
                f"{'the Newton switch' if uses_newton else 'tol'}){stepped}")
    elif code is SweepCode.SHOOTING_FAILED:
        text = (f"shooting on the fixed final states did not converge in {shoots} steps "
                f"(residual {float(s.residual):.3g} > {sweep.shooting_tol:g})")
    elif code is SweepCode.NON_FINITE:
        text = f"the sweep diverged (non-finite values after {its} sweeps)"
    elif code is SweepCode.STATE_BOUNDS_VIOLATED:
        text = (f"the sweep converged in {steps}, but the trajectory violates the bounds of state "
                f"{system.state_names[worst]!r} by {viol[worst]:.3g} (relative to its scale); the sweep does not "
                f"enforce state constraints, use a direct transcription")
    else:
        text = (f"Newton's method on Pontryagin's conditions did not converge ({steps}; relative control change "
                f"{change:.3g}, final-state residual {float(s.residual):.3g}){stepped}")
    return f"{system.name}: {text}"


def to_solution(system: System, r: SweepResult, transcription: str, quadrature: str) -> Solution:
    """A :class:`Solution` (not re-simulated) from a :class:`SweepResult`."""
    defect = [float(d) for d in np.asarray(r.defect)[system.final_mask]]
    return Solution(
        system=system.name, transcription=transcription, solver="sweep", integrator=quadrature,
        times=np.asarray(r.times), states=np.asarray(r.states), controls=np.asarray(r.controls), cost=float(r.cost),
        defect=defect, converged=bool(r.converged), status=r.status, solver_code=int(r.solver_code),
        message=r.message, iterations=int(r.iterations),
        constraint_violation=max((abs(d) for d in defect), default=0.0),
        compile_seconds=r.compile_seconds, solve_seconds=r.solve_seconds,
    )
