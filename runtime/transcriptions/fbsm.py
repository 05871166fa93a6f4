"""The forward-backward sweep: the indirect method of Lenhart & Workman, with a step control on its relaxation, a
Newton endgame on Pontryagin's conditions, and shooting on fixed final states."""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.sparse.linalg import gmres

from ..integrators import RK4, rollout, rollout_with_cost
from ..system import OptimalControlUnavailable, System
from ..data import ProblemData, default_data
from ..method import AbstractMethod
from ..solution import Solution
from ..status import Status
from ._common import control_scale, final_value_rows, guess_controls, state_scale

__all__ = ["ForwardBackwardSweep", "SweepResult", "SweepState"]

_RK4 = RK4()

# status codes of SweepState.status
CONVERGED, MAX_ITER, SHOOTING_FAILED, NON_FINITE, STATE_BOUNDS_VIOLATED, NEWTON_FAILED = 0, 1, 2, 3, 4, 5

# Newton steps: GMRES(50) restarted at most 10 times (<= 500 Jacobian-vector products, each about two sweeps'
# work) to a relative residual of 1e-8, far below what the quadratic convergence needs; backtracking halves the step
# at most 12 times and wants ||F|| to fall by the fraction 1e-4 of the step taken (Armijo).
_GMRES_RESTART, _GMRES_MAXITER, _GMRES_TOL = 50, 10, 1e-8
_MAX_HALVINGS, _ARMIJO = 12, 1e-4
# Sweep-then-Newton attempts, the switch 10 times smaller each time.
_NEWTON_ATTEMPTS = 4


class SweepState(NamedTuple):
    """The jittable, vmappable output of :meth:`ForwardBackwardSweep.run` (arrays only)."""

    times: Any  # (N + 1,)
    states: Any  # (N + 1, n)
    controls: Any  # (N + 1, m)
    costates: Any  # (N + 1, n)
    cost: Any  # J = phi(x(T)) + int L dt (RK4 with the running cost as an extra state)
    defect: Any  # (n,) x(T) - required final values; NaN where x_i(T) is free
    status: Any  # 0 converged, 1 out of sweeps, 2 shooting failed, 3 non-finite, 4 state bounds violated,
    # 5 Newton stalled
    iterations: Any  # relaxed sweeps in all (including the finite-difference sweeps of the shooting Jacobian)
    shooting_iterations: Any  # quasi-Newton steps on the fixed components of lambda(T) (bang-bang u* only)
    newton_iterations: Any  # Newton steps on Pontryagin's conditions (stationary u* only)
    relaxation: Any  # omega after the step control
    change: Any  # the relative control change u* - u of the returned controls (Newton) or of the last sweep
    residual: Any  # max |x_i(T) - x_final,i| over the fixed states (0 when none)
    bound_violation: Any  # (n,) max over the nodes of the state-bound violation, in units of the state's scale


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """What :meth:`ForwardBackwardSweep.solve` returns: arrays plus a human-readable outcome.

    Attributes:
        times, states, controls, costates: the trajectories at the N + 1 nodes.
        cost: J in minimisation form (RK4 with the running cost as an extra state, plus phi).
        defect: (n,) x(T) - x_final, NaN where x_i(T) is free.
        converged: see :meth:`ForwardBackwardSweep.solve`; ``message`` says why not.
        iterations: relaxed sweeps in all; shooting_iterations: quasi-Newton steps on lambda(T) (bang-bang u*);
            newton_iterations: Newton steps on Pontryagin's conditions (stationary u*).
        bound_violation: the worst state-bound violation, relative to the state's nominal scale.
        relaxation: omega as the step control left it.
    """

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


@dataclasses.dataclass(frozen=True)
class ForwardBackwardSweep(AbstractMethod):
    """The forward-backward sweep method (FBSM) on a uniform grid of N intervals.

    Pontryagin's conditions in minimisation form, with H = L + lambda . f:

        x' = f(x, u, t),                 x(0) = x0
        lambda' = -dH/dx(x, u, lambda, t),  lambda_i(T) = dphi/dx_i(x(T))  for free x_i(T)
        u(t) = argmin_{u in U} H(x, u, lambda, t)          (``system.optimal_control``)

    One sweep, from the current controls u^j at the N + 1 nodes (linearly interpolated, as everywhere):

        1. x^j      = RK4 forward from x0 with u^j;
        2. lambda^j = RK4 backward from lambda(T) with (x^j, u^j) interpolated linearly (Lenhart's averages);
        3. u*       = u*(x^j, lambda^j, t) at the nodes;                  (steps 1-3: u* = G(u^j))
        4. u^{j+1}  = u^j + omega (u* - u^j)        (omega = ``relaxation``; omega = 1/2 is Lenhart's average).

    Its convergence measure is the relative change: for every control component, max_k |u*_k - u^j_k| <=
    tol max(max_k |u*_k|, s_u), s_u the control's nominal scale (x and lambda are functions of u, so this is the
    fixed-point residual of the whole iteration). The returned states and costates are recomputed from the returned
    controls.

    Why the sweep alone can fail. Near a fixed point the error obeys e^{j+1} = (I + omega (G' - I)) e^j. Where H is
    quadratic in u with curvature R and no control bound is active, u* - u = -R^-1 dJ/du (the sweep is a gradient
    descent on the cost as a function of u), so G' = -R^-1 M, M the part of the cost's Hessian that comes through the
    states (M >= 0 for linear dynamics): where its eigenvalues mu are real and <= 0, the sweep converges iff
    omega < 2 / (1 + |mu|_max), at the rate 1 - omega per sweep in the directions where mu ~ 0. Unstable dynamics
    amplify a control perturbation in x forward and again in lambda backward, so |mu|_max grows roughly like e^{2cT},
    c the growth rate: on Van der Pol (c = a/2 at the origin, T = 10) it is 3.5e2, 1.8e4 and 3.2e5 at the solution
    for a = 0.5, 1 and 1.5, so Lenhart's omega = 1/2 diverges, and at a = 1 a stable omega ~ 1e-4 needs ~2e4 sweeps
    per decade of the change.

    Step control. An omega beyond the limit multiplies the dominant error mode by 1 - omega (1 + |mu|) < -1 per
    sweep, so successive corrections u* - u point apart; omega is halved whenever their inner product is negative,
    and never raised. Once omega < 1 / (1 + |mu|) no mode changes sign any more, so (for the linearisation) omega
    ends within a factor 4 below the stability limit, found without estimating mu.

    Newton endgame (stationary u*, ``newton=True``). Once the change is below ``newton_switch``, Newton's method
    solves Pontryagin's conditions as one system in the controls and the unknown terminal costates theta:

        F(u, theta) = ( (u - G(u; theta)) / s_u ,  (x_fixed(T; u) - x_final) / s_x ) = 0,

    the root being exactly the sweep's fixed point (same RK4 sweeps). Jacobian-vector products come from forward-mode
    differentiation through both rollouts, the linear systems from GMRES; the step is projected into the control
    bounds and backtracked until ||F|| decreases (Armijo). u* is clipped, so F is only piecewise smooth: this is a
    semismooth Newton method, fast once the active set is right. If Newton stalls, the sweep continues from Newton's
    best point to a 10 times smaller switch and Newton is tried again (4 attempts in all).

    Fixed final states: for each state with a required final value, lambda_i(T) = theta_i is unknown. With a
    stationary u*, theta is part of Newton's unknowns (the sweep phase runs at theta = 0, the free-final-state
    problem, whose solution is the starting point). With a bang-bang u* (piecewise constant in lambda, so F has no
    useful derivative) or ``newton=False``, an outer quasi-Newton (Broyden) iteration solves r(theta) =
    x_fixed(T; theta) - x_final = 0, each evaluation a converged sweep warm-started from the accepted controls; the
    first Jacobian is by forward differences (one extra sweep per fixed state), then Broyden's update, so with one
    fixed state this is the secant method of Lenhart's labs. That iteration starts from theta = 0 and stops early if
    the sweep at the current theta does not converge.

    State bounds are not part of Pontryagin's conditions as used here (no state-constraint multipliers), so the
    sweep cannot enforce them; it checks them instead, and a converged sweep whose trajectory leaves the bounds by
    more than ``bound_tol`` (relative to the state's nominal scale) is reported as not converged (status 4), e.g.
    Tumour, whose budget y <= A the unconstrained extremal overspends. Control bounds are respected: u* is clipped.

    Accuracy: the trajectories are O(h^2) (RK4 itself is O(h^4), but a curved control is interpolated linearly);
    the cost, stationary at the optimum, converges faster (O(h^4) on the linear-quadratic test problem).

    Everything runs in one ``jax.jit`` (``lax.while_loop``), so ``run`` can be vmapped over ``data``.

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

    @classmethod
    def on_grid(cls, intervals: int, **options) -> "ForwardBackwardSweep":
        return cls(intervals=intervals, **options)

    def solve_problem(self, system: System, solver: Any, data: ProblemData, z0: Any = None) -> Solution:
        _refuse_solver(solver)
        if z0 is not None:
            raise ValueError("ForwardBackwardSweep: starts from the middle of the control bounds; it takes no z0")
        t0 = time.perf_counter()
        r = self.solve(system, data.params, data.x0)
        jax.block_until_ready(r.states)
        return _sweep_solution(system, r, time.perf_counter() - t0)

    def solve_problems(self, system: System, solver: Any, data: ProblemData) -> list[Solution]:
        _refuse_solver(solver)
        raise NotImplementedError("ForwardBackwardSweep: batched solves are not available yet")

    def run(self, system: System, data: ProblemData) -> SweepState:
        """The sweep as a pure, jitted function of ``data = {"params": ..., "x0": ...}`` (vmappable).

        Raises:
            OptimalControlUnavailable: if the system has no characterised u* (``optimal_control_kind == "none"``).
        """
        _check_available(system)
        return _run(self, system, data)

    def solve(self, system: System, params: dict | None = None, x0: Any = None) -> SweepResult:
        """Run the sweep and describe the outcome.

        Args:
            system: the system; it must provide ``costate_dynamics``, ``optimal_control`` and ``terminal_costate``.
            params: parameter overrides (defaults: the spec's values).
            x0: initial state (default: the spec's).

        Returns:
            A :class:`SweepResult`; ``converged`` is True only if the controls are a fixed point of the sweep to
            ``tol``, every required final value is met to ``shooting_tol`` and the trajectory keeps to the state
            bounds (to ``bound_tol``).

        Raises:
            OptimalControlUnavailable: if ``system.optimal_control_kind == "none"``.
        """
        _check_available(system)
        s = _run(self, system, default_data(system, params, x0))
        status, its, shoots = int(s.status), int(s.iterations), int(s.shooting_iterations)
        newton, omega, change = int(s.newton_iterations), float(s.relaxation), float(s.change)
        viol = np.asarray(s.bound_violation)
        worst = int(np.argmax(viol))
        steps = f"{its} sweeps" + (f" and {newton} Newton steps" if newton else f" ({shoots} shooting steps)")
        stepped = "" if omega == self.relaxation else f"; the step control lowered the relaxation to {omega:.3g}"
        uses_newton = self.newton and system.optimal_control_kind == "stationary"
        messages = {
            CONVERGED: f"converged in {steps}{stepped}",
            MAX_ITER: f"the sweep did not converge in {steps} (relative control change {change:.3g} > "
            f"{'the Newton switch' if uses_newton else 'tol'}){stepped}",
            SHOOTING_FAILED: f"shooting on the fixed final states did not converge in {shoots} steps "
            f"(residual {float(s.residual):.3g} > {self.shooting_tol:g})",
            NON_FINITE: f"the sweep diverged (non-finite values after {its} sweeps)",
            STATE_BOUNDS_VIOLATED: f"the sweep converged in {steps}, but the trajectory violates the bounds of "
            f"state {system.state_names[worst]!r} by {viol[worst]:.3g} (relative to its scale); the sweep does not "
            f"enforce state constraints, use a direct transcription",
            NEWTON_FAILED: f"Newton's method on Pontryagin's conditions did not converge ({steps}; relative control "
            f"change {change:.3g}, final-state residual {float(s.residual):.3g}){stepped}",
        }
        return SweepResult(
            times=s.times,
            states=s.states,
            controls=s.controls,
            costates=s.costates,
            cost=float(s.cost),
            defect=s.defect,
            converged=status == CONVERGED,
            iterations=its,
            shooting_iterations=shoots,
            message=f"{system.name}: {messages[status]}",
            bound_violation=float(viol.max(initial=0.0)),
            newton_iterations=newton,
            relaxation=omega,
        )


def _refuse_solver(solver: Any) -> None:
    if solver is not None:
        raise ValueError(f"ForwardBackwardSweep solves Pontryagin's conditions itself and takes no NLP solver, got "
                         f"{type(solver).__name__}; pass solver=None, or a direct transcription to use the solver")


def _sweep_solution(system: System, r: "SweepResult", seconds: float) -> Solution:
    mask = system.final_mask
    defect = [float(d) for d in np.asarray(r.defect)[mask]]
    status = Status.CONVERGED if r.converged else Status.NOT_CONVERGED
    return Solution(
        system=system.name, transcription=ForwardBackwardSweep.label, solver="sweep",
        integrator=ForwardBackwardSweep.quadrature, times=np.asarray(r.times), states=np.asarray(r.states),
        controls=np.asarray(r.controls), cost=float(r.cost), defect=defect, converged=bool(r.converged),
        status=status, message=r.message, iterations=int(r.iterations),
        constraint_violation=max((abs(d) for d in defect), default=0.0), solve_seconds=seconds,
    )


def _check_available(system: System) -> None:
    if system.optimal_control_kind == "none":
        raise OptimalControlUnavailable(
            f"{system.name}: the forward-backward sweep needs the optimal control u*(x, lambda, t), which the compiler "
            f"could not characterise: {system.optimal_control_note or '(no note)'}"
        )


@functools.partial(jax.jit, static_argnums=(0, 1))
def _run(cfg: ForwardBackwardSweep, system: System, data: dict) -> SweepState:
    params, x0 = data.params, jnp.asarray(data.x0)
    N, n, m = cfg.intervals, system.n_states, system.n_controls
    T = float(system.horizon)
    h = T / N
    times = jnp.asarray(np.linspace(0.0, T, N + 1))
    fixed, final = final_value_rows(system)
    k = fixed.size
    su = jnp.asarray(control_scale(system))
    sx = jnp.asarray(state_scale(system))
    arrays = system.arrays()
    u_lo, u_hi = jnp.asarray(arrays["u_lower"]), jnp.asarray(arrays["u_upper"])
    dtype = x0.dtype
    int0 = jnp.asarray(0, dtype=jnp.int32)
    inf = jnp.asarray(jnp.inf, dtype=dtype)

    f = lambda x, u, t: system.dynamics(x, u, t, params)  # noqa: E731
    # lambda' = g(lambda, (x, u), t): (x, u) enter as a linearly interpolated "control" of the backward rollout.
    g = lambda lam, xu, t: system.costate_dynamics(xu[:n], xu[n:], lam, t, params)  # noqa: E731
    u_star = jax.vmap(lambda x, lam, t: system.optimal_control(x, lam, t, params))

    def forward(u):
        return rollout(_RK4, f, x0, 0.0, h, u)

    def backward(xs, u, theta):
        lam_T = jnp.asarray(system.terminal_costate(xs[-1], T, params)).at[fixed].set(theta)
        xu = jnp.concatenate([xs, u], axis=1)[::-1]
        return rollout(_RK4, g, lam_T, T, -h, xu)[::-1]

    def sweep_map(u, theta):
        """G(u) (steps 1-3 of a sweep), and the states x(u) it went through."""
        xs = forward(u)
        return u_star(xs, backward(xs, u, theta), times), xs

    def relative_change(new, u):
        return jnp.max(jnp.max(jnp.abs(new - u), axis=0) / jnp.maximum(jnp.max(jnp.abs(new), axis=0), su))

    def relax(theta, u, omega, budget, stop_at):
        """Relaxed sweeps from u until the change is <= stop_at or ``budget`` sweeps are done.

        Returns (u, omega, sweeps, change), change being the last sweep's, measured at its input; a NaN stops it."""

        def cond(c):
            _, _, _, it, change = c
            return (it < budget) & (change > stop_at)

        def body(c):
            u, d_prev, omega, it, _ = c
            new, _ = sweep_map(u, theta)
            d = new - u
            # With omega beyond 2 / (1 + |mu|), mu the most negative eigenvalue of G', that eigenvector's component is
            # multiplied by 1 - omega (1 - mu) < -1 per sweep: it grows and flips sign, so successive corrections
            # point apart. Halving at each such flip ends below the limit, and at the latest once omega < 1 / (1 + |mu|)
            # (no mode flips any more): within a factor 4 below the limit.
            omega = jnp.where(jnp.vdot(d, d_prev) < 0.0, 0.5 * omega, omega)
            return u + omega * d, d, omega, it + 1, relative_change(new, u)

        init = (u, jnp.zeros_like(u), omega, int0, inf)
        u, _, omega, it, change = jax.lax.while_loop(cond, body, init)
        return u, omega, it, change

    u_init = jnp.asarray(guess_controls(system, N + 1), dtype=dtype)
    omega0 = jnp.asarray(cfg.relaxation, dtype=dtype)
    theta = jnp.zeros(k, dtype=dtype)
    shoots = newton_its = int0
    use_newton = cfg.newton and system.optimal_control_kind == "stationary"

    if use_newton:
        size = (N + 1) * m

        def split(z):
            return z[:size].reshape(N + 1, m), z[size:]

        def residual(z):
            """Pontryagin's conditions F(u, theta) = 0, each row in units of its variable's nominal scale."""
            u, theta = split(z)
            new, xs = sweep_map(u, theta)
            return jnp.concatenate([((u - new) / su).ravel(), (xs[-1, fixed] - final) / sx[fixed]])

        def solved(z, F):
            u, _ = split(z)
            change = relative_change(u - F[:size].reshape(N + 1, m) * su, u)
            return (change <= cfg.tol) & (jnp.max(jnp.abs(F[size:] * sx[fixed]), initial=0.0) <= cfg.shooting_tol)

        def project(z):
            u, theta = split(z)
            return jnp.concatenate([jnp.clip(u, u_lo, u_hi).ravel(), theta])

        def direction(z, F):
            """The Newton step d: F'(z) d = -F, F' applied by forward-mode differentiation through both rollouts."""
            _, jvp = jax.linearize(residual, z)
            return gmres(jvp, -F, tol=_GMRES_TOL, restart=_GMRES_RESTART, maxiter=_GMRES_MAXITER)[0]

        def newton(z):
            """Damped semismooth Newton from z: (z, steps, solved); z only moves on a sufficient decrease of ||F||.

            One loop whose every pass evaluates F once, at the trial point z + alpha d: accepted, it becomes the
            new z and gets a new direction (alpha = 1); rejected, alpha is halved. The first pass is the trial
            alpha = 0 against ||F|| = inf, so there is a single call site of F and of the direction."""

            def cond(c):
                _, _, _, _, steps, halvings, ok = c
                return ~ok & (halvings <= _MAX_HALVINGS) & (steps < cfg.max_newton_iter)

            def body(c):
                z, F, d, alpha, steps, halvings, _ = c
                z_t = project(z + alpha * d)
                F_t = residual(z_t)
                decrease = jnp.linalg.norm(F_t) <= (1.0 - _ARMIJO * alpha) * jnp.linalg.norm(F)
                accept = jnp.all(jnp.isfinite(F_t)) & decrease
                ok = accept & solved(z_t, F_t)
                d = jax.lax.cond(accept & ~ok, direction, lambda z, F: d, z_t, F_t)
                return (
                    jnp.where(accept, z_t, z),
                    jnp.where(accept, F_t, F),
                    d,
                    jnp.where(accept, 1.0, 0.5 * alpha),
                    steps + accept.astype(steps.dtype),
                    jnp.where(accept, 0, halvings + 1),
                    ok,
                )

            no_step = jnp.zeros_like(z)
            init = (z, jnp.full(z.shape, inf), no_step, jnp.zeros((), dtype), int0 - 1, int0, jnp.asarray(False))
            z, _, _, _, steps, _, ok = jax.lax.while_loop(cond, body, init)
            return z, jnp.maximum(steps, 0), ok

        # The sweep globalises, Newton converges: the sweep runs until its change is below newton_switch, then
        # Newton; if Newton stalls, the sweep goes on from Newton's best point to a 10 times smaller switch and Newton
        # is tried again. One loop, one call site of each, so each is compiled once.
        def cond(c):
            attempt, _, _, sweeps, _, reached, ok = c
            return ~ok & (attempt < _NEWTON_ATTEMPTS) & (sweeps < cfg.max_iter) & ((attempt == 0) | reached)

        def body(c):
            attempt, z, omega, sweeps, nits, _, _ = c
            u, theta = split(z)
            switch = jnp.maximum(cfg.newton_switch * 0.1 ** attempt.astype(dtype), cfg.tol)
            u, omega, it, change = relax(theta, u, omega, cfg.max_iter - sweeps, switch)
            z = jnp.concatenate([u.ravel(), theta])
            reached = change <= switch  # False for NaN too: Newton is not started from a diverged sweep
            skip = lambda z: (z, int0, jnp.asarray(False))  # noqa: E731
            z_n, nit, ok = jax.lax.cond(reached, newton, skip, z)
            z = jnp.where(reached, z_n, z)
            return attempt + 1, z, omega, sweeps + it, nits + jnp.where(reached, nit, 0), reached, reached & ok

        z0 = jnp.concatenate([u_init.ravel(), theta])
        init = (int0, z0, omega0, int0, int0, jnp.asarray(False), jnp.asarray(False))
        _, z, omega, iters, newton_its, reached, _ = jax.lax.while_loop(cond, body, init)
        u, theta = split(z)
    else:

        def residual(theta, u):
            u, omega, it, change = relax(theta, u, omega0, cfg.max_iter, cfg.tol)
            return forward(u)[-1, fixed] - final, u, it, change, omega

        if not k:
            r, u, iters, change, omega = residual(theta, u_init)
        else:
            # One loop, one call site of the inner sweep (so it is compiled once). Iteration 0 evaluates r(theta_0);
            # iterations 1..k evaluate r(theta + delta_j e_j) without moving the base, and Broyden's update from J = 0
            # then sets column j to the forward difference (r_j - r) / delta_j exactly; from iteration k + 1 on, each
            # step d = -J^-1 r is accepted and J gets Broyden's ("good") rank-one update
            #     J <- J + (r_new - r - J d) d^T / (d^T d),
            # which with k = 1 is the secant method.
            eye = jnp.eye(k, dtype=dtype)

            def cond(c):
                i, _, r, _, _, _, shoots, change, _ = c
                # Stop as soon as the sweep at the base point fails: residuals of an unconverged sweep are noise, and
                # Broyden steps on them only burn max_iter sweeps each.
                base_ok = (i == 0) | (change <= cfg.tol)
                searching = (shoots < cfg.max_shooting_iter) & (jnp.max(jnp.abs(r)) > cfg.shooting_tol)
                return base_ok & ((i <= k) | searching)

            def body(c):
                i, theta, r, J, u, iters, shoots, change, omega = c
                newton = i > k
                e = eye[jnp.clip(i - 1, 0, k - 1)]
                # The identity stands in for J while it is still being built, so the unused solve stays finite.
                newton_step = -jnp.linalg.solve(jnp.where(newton, J, eye), r)
                step = jnp.where(newton, newton_step, 1e-3 * jnp.maximum(1.0, jnp.abs(theta)) * e)
                d = jnp.where(i == 0, 0.0, step)
                r_new, u_new, it, change_new, omega_new = residual(theta + d, u)
                dd = jnp.dot(d, d)
                J = jnp.where(i == 0, J, J + jnp.outer(r_new - r - J @ d, d) / jnp.where(i == 0, 1.0, dd))
                accept = (i == 0) | newton
                return (
                    i + 1,
                    jnp.where(accept, theta + d, theta),
                    jnp.where(accept, r_new, r),
                    J,
                    jnp.where(accept, u_new, u),
                    iters + it,
                    shoots + newton.astype(shoots.dtype),
                    jnp.where(accept, change_new, change),
                    jnp.where(accept, omega_new, omega),
                )

            r0 = jnp.full(k, inf)
            init = (int0, theta, r0, jnp.zeros((k, k), dtype), u_init, int0, shoots, inf, omega0)
            _, theta, r, _, u, iters, shoots, change, omega = jax.lax.while_loop(cond, body, init)

    xs, cost = rollout_with_cost(_RK4, f, lambda x, u, t: system.running_cost(x, u, t, params), x0, 0.0, h, u)
    lams = backward(xs, u, theta)
    if use_newton:
        # The returned controls' own fixed-point residual, whichever phase produced them.
        change = relative_change(u_star(xs, lams, times), u)
        r = xs[-1, fixed] - final
    res = jnp.max(jnp.abs(r)) if k else jnp.asarray(0.0, dtype=dtype)
    finite = jnp.isfinite(change) & jnp.all(jnp.isfinite(xs)) & jnp.all(jnp.isfinite(lams))
    below = jnp.asarray(arrays["x_lower"]) - xs
    above = xs - jnp.asarray(arrays["x_upper"])
    violation = jnp.max(jnp.maximum(jnp.maximum(below, above), 0.0), axis=0) / sx
    unsolved = (change > cfg.tol) | (res > cfg.shooting_tol)
    if use_newton:
        # Newton was reached but stalled, or the sweep ran out of sweeps before reaching it.
        failure = [~finite, unsolved & reached, unsolved]
        codes = [NON_FINITE, NEWTON_FAILED, MAX_ITER]
    else:
        failure = [~finite, change > cfg.tol, res > cfg.shooting_tol]
        codes = [NON_FINITE, MAX_ITER, SHOOTING_FAILED]
    status = jnp.select([*failure, jnp.max(violation) > cfg.bound_tol], [*codes, STATE_BOUNDS_VIOLATED], CONVERGED)
    defect = xs[-1] - jnp.asarray(system.final_values)
    return SweepState(
        times=times,
        states=xs,
        controls=u,
        costates=lams,
        cost=cost[-1] + system.terminal_cost(xs[-1], T, params),
        defect=defect,
        status=status,
        iterations=iters,
        shooting_iterations=shoots,
        newton_iterations=newton_its,
        relaxation=omega,
        change=change,
        residual=res,
        bound_violation=violation,
    )
