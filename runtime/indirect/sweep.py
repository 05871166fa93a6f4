r"""The forward-backward sweep: the indirect method of Lenhart & Workman, with a step control on its relaxation
(:mod:`.relaxation`), a Newton endgame on Pontryagin's conditions (:mod:`.newton`) and shooting on fixed final states
(:mod:`.shooting`), all on Pontryagin's maps (:mod:`.pontryagin`)."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, ClassVar

import jax.numpy as jnp
import numpy as np

from ..data import ProblemData, default_data, require_float64
from ..method import AbstractMethod
from ..solution import Solution
from ..solvers.pure import AbstractPureSolver
from ..status import Status
from ..system import OptimalControlUnavailable, System
from ..transcriptions.nlp_parts import guess_controls
from .newton import sweep_then_newton
from .pontryagin import cost_and_trajectories, optimal_controls, problem, relative_change
from .result import SweepCode, SweepResult, SweepState, message, outcome, to_solution
from .shooting import sweep_and_shoot

__all__ = ["ForwardBackwardSweep"]


@dataclasses.dataclass(frozen=True)
class ForwardBackwardSweep(AbstractMethod, AbstractPureSolver):
    r"""The forward-backward sweep method (FBSM) on a uniform grid of N intervals, on Pontryagin's conditions in
    minimisation form (:mod:`.pontryagin`).

    One sweep, from the current controls u^j at the N + 1 nodes (linearly interpolated, as everywhere):

        1. x^j      = RK4 forward from x0 with u^j;
        2. lambda^j = RK4 backward from lambda(T) with (x^j, u^j) interpolated linearly (Lenhart's averages);
        3. u*       = u*(x^j, lambda^j, t) at the nodes;                  (steps 1-3: u* = G(u^j))
        4. u^{j+1}  = u^j + omega (u* - u^j)        (omega = ``relaxation``; omega = 1/2 is Lenhart's average).

    It converges when the relative change (:func:`.pontryagin.relative_change`) is at most ``tol``; the returned
    states and costates are recomputed from the returned controls. Unstable dynamics can make Lenhart's 1/2 diverge:
    hence the step control on omega (:mod:`.relaxation`) and, where u* is stationary and ``newton=True``, Newton's
    method on Pontryagin's conditions once the change is below ``newton_switch`` (:mod:`.newton`). With a bang-bang
    u* or ``newton=False``, the unknown terminal costates of fixed final states are found by Broyden's method around
    converged sweeps (:mod:`.shooting`). Measurements: docs/notes/sweep-convergence.md.

    State bounds are not part of Pontryagin's conditions as used here (no state-constraint multipliers), so the
    sweep cannot enforce them; it checks them instead, and a converged sweep whose trajectory leaves the bounds by
    more than ``bound_tol`` (relative to the state's nominal scale) is reported as STATE_BOUNDS_VIOLATED (e.g.
    Tumour, whose budget y <= A the unconstrained extremal overspends). Control bounds are respected: u* is clipped.

    Accuracy: the trajectories are O(h^2) (RK4 itself is O(h^4), but a curved control is interpolated linearly);
    the cost, stationary at the optimum, converges faster (O(h^4) on the linear-quadratic test problem).

    Interfaces (README.md in this folder): an :class:`~myriad.runtime.method.AbstractMethod` that refuses an NLP
    solver, and an :class:`~myriad.runtime.solvers.pure.AbstractPureSolver` whose problem is the system, ``z0`` the
    initial controls (N + 1, m) (default: :meth:`start`).

    Attributes:
        intervals: N.
        relaxation: the initial omega in (0, 1], the weight of the new control in the convex update.
        tol: the relative fixed-point tolerance of the sweep.
        max_iter: the most relaxed sweeps in all (with a bang-bang u* or newton=False: per inner solve).
        shooting_tol: absolute tolerance on the required final values.
        max_shooting_iter: the most quasi-Newton steps (bang-bang u* or newton=False).
        bound_tol: tolerance on state-bound violations, relative to the state's nominal scale.
        newton: finish with Newton's method where u* is stationary.
        newton_switch: the relative change at which the sweep hands over to Newton.
        max_newton_iter: the most Newton steps per attempt.

    References:
        S. Lenhart and J. T. Workman, *Optimal Control Applied to Biological Models*, Chapman & Hall/CRC, 2007,
        ch. 4 (the sweep) and Lab 13 (the secant iteration for a fixed final state).
        M. McAsey, L. Mou and W. Han, Convergence of the forward-backward sweep method in optimal control,
        *Comput. Optim. Appl.* 53 (2012) 207-226 (convergence only for small horizons or Lipschitz constants).
        M. Ulbrich, *Semismooth Newton Methods for Variational Inequalities and Constrained Optimization Problems in
        Function Spaces*, SIAM, 2011 (Newton on u - P(u*(u)) = 0 with a projection P).
    """

    label: ClassVar[str] = "fbsm"
    quadrature: ClassVar[str] = "rk4"
    uses_solver: ClassVar[bool] = False  # solves Pontryagin's conditions itself: solve() and the CLI refuse a solver

    intervals: int = 1000
    relaxation: float = 0.5
    tol: float = 1e-10
    max_iter: int = 50_000
    shooting_tol: float = 1e-9
    max_shooting_iter: int = 50
    bound_tol: float = 1e-6
    newton: bool = True
    newton_switch: float = 0.1
    max_newton_iter: int = 50

    def __post_init__(self):
        if self.intervals < 1:
            raise ValueError(f"ForwardBackwardSweep: intervals must be at least 1, got {self.intervals}")
        if not 0.0 < self.relaxation <= 1.0:
            raise ValueError(f"ForwardBackwardSweep: relaxation must lie in (0, 1], got {self.relaxation}")
        if self.tol <= 0.0 or self.shooting_tol <= 0.0:
            raise ValueError("ForwardBackwardSweep: tol and shooting_tol must be positive")
        if self.max_iter < 1 or self.max_shooting_iter < 0 or self.max_newton_iter < 0:
            raise ValueError(
                "ForwardBackwardSweep: max_iter must be >= 1, max_shooting_iter and max_newton_iter >= 0"
            )
        if not self.newton_switch > 0.0:
            raise ValueError(f"ForwardBackwardSweep: newton_switch must be positive, got {self.newton_switch}")

    # ---- AbstractMethod ----------------------------------------------------------------------------------------

    @classmethod
    def on_grid(cls, intervals: int, **options) -> "ForwardBackwardSweep":
        return cls(intervals=intervals, **options)

    def solve_problem(self, system: System, solver: Any, data: ProblemData, z0: Any = None) -> Solution:
        """One sweep as a :class:`Solution` (``z0``: initial controls (N + 1, m)); refuses a solver (ValueError)."""
        _refuse_solver(solver)
        return to_solution(system, self._solve_single(system, data, z0), self.label, self.quadrature)

    def solve_problems(self, system: System, solver: Any, data: ProblemData) -> list[Solution]:
        """A batch of sweeps as one vmapped program (:meth:`solve_batch`), one Solution and status per member."""
        _refuse_solver(solver)
        return [to_solution(system, r, self.label, self.quadrature) for r in self.solve_batch(system, data)]

    # ---- the sweep's own entry points --------------------------------------------------------------------------

    def solve(self, system: System, params: dict | None = None, x0: Any = None, z0: Any = None) -> SweepResult:
        """Run the sweep (``params``: overrides of the spec's; ``x0``: default the spec's; ``z0``: see :meth:`start`).

        Returns:
            A :class:`SweepResult`, ``converged`` only for a fixed point of the sweep to ``tol`` that meets every
            required final value to ``shooting_tol`` and keeps to the state bounds (to ``bound_tol``).

        Raises:
            OptimalControlUnavailable: if ``system.optimal_control_kind == "none"``.
        """
        require_float64("ForwardBackwardSweep.solve")
        return self._solve_single(system, default_data(system, params, x0), z0)

    # ---- AbstractPureSolver (the problem is the system) ---------------------------------------------------------

    def pure_solve(self, system: System) -> Callable[[ProblemData, Any], SweepState]:
        # Holding the system is harmless: it is stateless, and jit's cache keeps static systems alive just the same.
        _check_available(system)
        return lambda data, z0: _sweep(self, system, data, z0)

    def start(self, system: System, data: Any, z0: Any = None) -> np.ndarray:
        """``z0`` as float64 controls (N + 1, m) (ValueError: another shape), or the default: the middle of the
        control bounds where both are finite, else 0 clipped into the bounds, at every node."""
        shape = (self.intervals + 1, system.n_controls)
        if z0 is None:
            return np.asarray(guess_controls(system, shape[0]), dtype=np.float64)
        z0 = np.asarray(z0, dtype=np.float64)
        if z0.shape != shape:
            raise ValueError(f"ForwardBackwardSweep: z0 (the initial controls) has shape {z0.shape}, expected {shape}")
        return z0

    def report(self, system: System, out: SweepState, data: Any, compile_seconds: float,
               solve_seconds: float) -> SweepResult:
        s = SweepState(*(np.asarray(a) for a in out))
        status = Status(int(s.status))
        return SweepResult(
            times=s.times, states=s.states, controls=s.controls, costates=s.costates, cost=float(s.cost),
            defect=s.defect, converged=status.success, iterations=int(s.iterations),
            shooting_iterations=int(s.shooting_iterations), message=message(self, system, s),
            bound_violation=float(s.bound_violation.max(initial=0.0)), newton_iterations=int(s.newton_iterations),
            relaxation=float(s.relaxation), status=status, solver_code=int(s.solver_code),
            compile_seconds=compile_seconds, solve_seconds=solve_seconds,
        )


def _sweep(cfg: ForwardBackwardSweep, system: System, data: ProblemData, z0: Any) -> SweepState:
    """The pure sweep: the phases of the sweep from the controls z0, then the trajectories and the outcome."""
    p = problem(system, data, cfg.intervals)
    dtype = p.x0.dtype
    int0 = jnp.asarray(0, dtype=jnp.int32)
    u = jnp.asarray(z0, dtype=dtype)
    omega = jnp.asarray(cfg.relaxation, dtype=dtype)
    use_newton = cfg.newton and system.optimal_control_kind == "stationary"
    if use_newton:
        u, theta, omega, iters, newton_its, reached = sweep_then_newton(p, cfg, u, omega)
        shoots = int0
    else:
        u, theta, r, omega, iters, shoots, change = sweep_and_shoot(p, cfg, u, omega)
        newton_its = int0

    xs, lams, cost = cost_and_trajectories(p, u, theta)
    if use_newton:
        # The returned controls' own fixed-point residual, whichever phase produced them.
        change = relative_change(p, optimal_controls(p, xs, lams), u)
        r = xs[-1, p.fixed] - p.final
    res = jnp.max(jnp.abs(r)) if p.k else jnp.asarray(0.0, dtype=dtype)
    finite = jnp.isfinite(change) & jnp.all(jnp.isfinite(xs)) & jnp.all(jnp.isfinite(lams))
    arrays = system.arrays()
    below = jnp.asarray(arrays["x_lower"]) - xs
    above = xs - jnp.asarray(arrays["x_upper"])
    violation = jnp.max(jnp.maximum(jnp.maximum(below, above), 0.0), axis=0) / p.sx
    unsolved = (change > cfg.tol) | (res > cfg.shooting_tol)
    if use_newton:
        # Newton was reached but stalled, or the sweep ran out of sweeps before reaching it.
        failures = [(~finite, SweepCode.NON_FINITE), (unsolved & reached, SweepCode.NEWTON_FAILED),
                    (unsolved, SweepCode.MAX_ITER)]
    else:
        failures = [(~finite, SweepCode.NON_FINITE), (change > cfg.tol, SweepCode.MAX_ITER),
                    (res > cfg.shooting_tol, SweepCode.SHOOTING_FAILED)]
    status, code = outcome(failures, jnp.max(violation) > cfg.bound_tol)
    return SweepState(
        times=p.times, states=xs, controls=u, costates=lams, cost=cost,
        defect=xs[-1] - jnp.asarray(system.final_values), status=status, solver_code=code, iterations=iters,
        shooting_iterations=shoots, newton_iterations=newton_its, relaxation=omega, change=change, residual=res,
        bound_violation=violation,
    )


def _refuse_solver(solver: Any) -> None:
    if solver is not None:
        raise ValueError(f"ForwardBackwardSweep solves Pontryagin's conditions itself and takes no NLP solver, got "
                         f"{type(solver).__name__}; pass solver=None, or a direct transcription to use the solver")


def _check_available(system: System) -> None:
    # Pontryagin's conditions as compiled have no multipliers for path constraints and no transversality condition
    # for a free final time: the sweep would solve another problem and call it this one's.
    system.require_schema1_features("the forward-backward sweep (fbsm); use a direct transcription")
    if system.optimal_control_kind == "none":
        raise OptimalControlUnavailable(
            f"{system.name}: the forward-backward sweep needs the optimal control u*(x, lambda, t), which the compiler "
            f"could not characterise: {system.optimal_control_note or '(no note)'}"
        )
