"""The forward-backward sweep: the indirect method of Lenhart & Workman, with shooting on fixed final states."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..integrators import RK4, rollout, rollout_with_cost
from ..system import OptimalControlUnavailable, System
from ._common import control_scale, default_data, final_value_rows, guess_controls, state_scale

__all__ = ["ForwardBackwardSweep", "SweepResult", "SweepState"]

_RK4 = RK4()

# status codes of SweepState.status
CONVERGED, MAX_ITER, SHOOTING_FAILED, NON_FINITE, STATE_BOUNDS_VIOLATED = 0, 1, 2, 3, 4


class SweepState(NamedTuple):
    """The jittable, vmappable output of :meth:`ForwardBackwardSweep.run` (arrays only)."""

    times: Any  # (N + 1,)
    states: Any  # (N + 1, n)
    controls: Any  # (N + 1, m)
    costates: Any  # (N + 1, n)
    cost: Any  # J = phi(x(T)) + int L dt (RK4 with the running cost as an extra state)
    defect: Any  # (n,) x(T) - required final values; NaN where x_i(T) is free
    status: Any  # 0 converged, 1 sweep hit max_iter, 2 shooting failed, 3 non-finite, 4 state bounds violated
    iterations: Any  # sweeps in all (including the finite-difference sweeps of the shooting Jacobian)
    shooting_iterations: Any  # quasi-Newton steps on the fixed components of lambda(T)
    change: Any  # the last sweep's relative control change
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
        iterations: sweeps in all; shooting_iterations: quasi-Newton steps on lambda(T).
        bound_violation: the worst state-bound violation, relative to the state's nominal scale.
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


@dataclasses.dataclass(frozen=True)
class ForwardBackwardSweep:
    """The forward-backward sweep method (FBSM) on a uniform grid of N intervals.

    Pontryagin's conditions in minimisation form, with H = L + lambda . f:

        x' = f(x, u, t),                 x(0) = x0
        lambda' = -dH/dx(x, u, lambda, t),  lambda_i(T) = dphi/dx_i(x(T))  for free x_i(T)
        u(t) = argmin_{u in U} H(x, u, lambda, t)          (``system.optimal_control``)

    One sweep, from the current controls u^j at the N + 1 nodes (linearly interpolated, as everywhere):

        1. x^j      = RK4 forward from x0 with u^j;
        2. lambda^j = RK4 backward from lambda(T) with (x^j, u^j) interpolated linearly (Lenhart's averages);
        3. u*       = u*(x^j, lambda^j, t) at the nodes;
        4. u^{j+1}  = u^j + omega (u* - u^j)        (omega = ``relaxation``; omega = 1/2 is Lenhart's average).

    The sweep stops when, for every control component, max_k |u*_k - u^j_k| <= tol max(max_k |u*_k|, s_u) with s_u
    the control's nominal scale (x and lambda are functions of u, so this is the fixed-point residual of the whole
    iteration). The returned states and costates are recomputed from the returned controls.

    Fixed final states: for each state with a required final value, lambda_i(T) = theta_i is unknown. An outer
    quasi-Newton (Broyden) iteration solves r(theta) = x_fixed(T; theta) - x_final = 0, each evaluation a converged
    sweep warm-started from the accepted controls; the first Jacobian is by forward differences (one extra sweep per
    fixed state), then Broyden's update, so with one fixed state this is the secant method of Lenhart's labs. The
    iteration starts from theta = 0 and stops early if the sweep at the current theta does not converge.

    State bounds are not part of Pontryagin's conditions as used here (no state-constraint multipliers), so the
    sweep cannot enforce them; it checks them instead, and a converged sweep whose trajectory leaves the bounds by
    more than ``bound_tol`` (relative to the state's nominal scale) is reported as not converged (status 4), e.g.
    Tumour, whose budget y <= A the unconstrained extremal overspends. Control bounds are respected: u* is clipped.

    Accuracy: the trajectories are O(h^2) (RK4 itself is O(h^4), but a curved control is interpolated linearly);
    the cost, stationary at the optimum, converges faster (O(h^4) on the linear-quadratic test problem).

    Everything runs in one ``jax.jit`` (``lax.while_loop``), so ``run`` can be vmapped over ``data``.

    Attributes:
        intervals: N.
        relaxation: omega in (0, 1], the weight of the new control in the convex update.
        tol: the relative fixed-point tolerance of the sweep.
        max_iter: the most sweeps per inner solve.
        shooting_tol: absolute tolerance on the required final values.
        max_shooting_iter: the most quasi-Newton steps.
        bound_tol: tolerance on state-bound violations, relative to the state's nominal scale.

    References:
        S. Lenhart and J. T. Workman, *Optimal Control Applied to Biological Models*, Chapman & Hall/CRC, 2007,
        ch. 4 (the sweep) and Lab 13 (the secant iteration for a fixed final state).
    """

    intervals: int = 1000
    relaxation: float = 0.5
    tol: float = 1e-10
    max_iter: int = 2000
    shooting_tol: float = 1e-9
    max_shooting_iter: int = 50
    bound_tol: float = 1e-6

    def __post_init__(self):
        if self.intervals < 1:
            raise ValueError(f"ForwardBackwardSweep: intervals must be at least 1, got {self.intervals}")
        if not 0.0 < self.relaxation <= 1.0:
            raise ValueError(f"ForwardBackwardSweep: relaxation must lie in (0, 1], got {self.relaxation}")
        if self.tol <= 0.0 or self.shooting_tol <= 0.0:
            raise ValueError("ForwardBackwardSweep: tol and shooting_tol must be positive")
        if self.max_iter < 1 or self.max_shooting_iter < 0:
            raise ValueError("ForwardBackwardSweep: max_iter must be >= 1 and max_shooting_iter >= 0")

    def run(self, system: System, data: dict) -> SweepState:
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
            A :class:`SweepResult`; ``converged`` is True only if the sweep reached ``tol``, every required final
            value is met to ``shooting_tol`` and the trajectory keeps to the state bounds (to ``bound_tol``).

        Raises:
            OptimalControlUnavailable: if ``system.optimal_control_kind == "none"``.
        """
        _check_available(system)
        s = _run(self, system, default_data(system, params, x0))
        status, its, shoots = int(s.status), int(s.iterations), int(s.shooting_iterations)
        viol = np.asarray(s.bound_violation)
        worst = int(np.argmax(viol))
        messages = {
            CONVERGED: f"converged in {its} sweeps ({shoots} shooting steps)",
            MAX_ITER: f"the sweep did not converge in {self.max_iter} iterations "
            f"(relative control change {float(s.change):.3g} > tol {self.tol:g}); try a smaller relaxation",
            SHOOTING_FAILED: f"shooting on the fixed final states did not converge in {shoots} steps "
            f"(residual {float(s.residual):.3g} > {self.shooting_tol:g})",
            NON_FINITE: f"the sweep diverged (non-finite values after {its} sweeps); try a smaller relaxation",
            STATE_BOUNDS_VIOLATED: f"the sweep converged in {its} sweeps, but the trajectory violates the bounds of "
            f"state {system.state_names[worst]!r} by {viol[worst]:.3g} (relative to its scale); the sweep does not "
            f"enforce state constraints, use a direct transcription",
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
        )


def _check_available(system: System) -> None:
    if system.optimal_control_kind == "none":
        raise OptimalControlUnavailable(
            f"{system.name}: the forward-backward sweep needs the optimal control u*(x, lambda, t), which the compiler "
            f"could not characterise: {system.optimal_control_note or '(no note)'}"
        )


@functools.partial(jax.jit, static_argnums=(0, 1))
def _run(cfg: ForwardBackwardSweep, system: System, data: dict) -> SweepState:
    params, x0 = data["params"], jnp.asarray(data["x0"])
    N, n = cfg.intervals, system.n_states
    T = float(system.horizon)
    h = T / N
    times = jnp.asarray(np.linspace(0.0, T, N + 1))
    fixed, final = final_value_rows(system)
    su = jnp.asarray(control_scale(system))

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

    def sweep(theta, u):
        """Inner fixed-point iteration for a given theta: returns (u, sweeps, change)."""

        def cond(c):
            _, it, change = c
            return (it < cfg.max_iter) & (change > cfg.tol)  # a NaN change stops it too

        def body(c):
            u, it, _ = c
            xs = forward(u)
            new = u_star(xs, backward(xs, u, theta), times)
            change = jnp.max(jnp.max(jnp.abs(new - u), axis=0) / jnp.maximum(jnp.max(jnp.abs(new), axis=0), su))
            return u + cfg.relaxation * (new - u), it + 1, change

        init = (u, jnp.asarray(0, dtype=jnp.int32), jnp.asarray(jnp.inf, dtype=x0.dtype))
        return jax.lax.while_loop(cond, body, init)

    def residual(theta, u):
        u, it, change = sweep(theta, u)
        return forward(u)[-1, fixed] - final, u, it, change

    u_init = jnp.asarray(guess_controls(system, N + 1))
    k = fixed.size
    theta = jnp.zeros(k, dtype=x0.dtype)
    shoots = jnp.asarray(0, dtype=jnp.int32)
    if not k:
        r, u, iters, change = residual(theta, u_init)
    else:
        # One loop, one call site of the inner sweep (so it is compiled once). Iteration 0 evaluates r(theta_0);
        # iterations 1..k evaluate r(theta + delta_j e_j) without moving the base, and Broyden's update from J = 0
        # then sets column j to the forward difference (r_j - r) / delta_j exactly; from iteration k + 1 on, each
        # step d = -J^-1 r is accepted and J gets Broyden's ("good") rank-one update
        #     J <- J + (r_new - r - J d) d^T / (d^T d),
        # which with k = 1 is the secant method.
        eye = jnp.eye(k, dtype=x0.dtype)

        def cond(c):
            i, _, r, _, _, _, shoots, change = c
            # Stop as soon as the sweep at the base point fails: residuals of an unconverged sweep are noise, and
            # Broyden steps on them only burn max_iter sweeps each.
            base_ok = (i == 0) | (change <= cfg.tol)
            searching = (shoots < cfg.max_shooting_iter) & (jnp.max(jnp.abs(r)) > cfg.shooting_tol)
            return base_ok & ((i <= k) | searching)

        def body(c):
            i, theta, r, J, u, iters, shoots, change = c
            newton = i > k
            e = eye[jnp.clip(i - 1, 0, k - 1)]
            # The identity stands in for J while it is still being built, so the unused solve stays finite.
            newton_step = -jnp.linalg.solve(jnp.where(newton, J, eye), r)
            step = jnp.where(newton, newton_step, 1e-3 * jnp.maximum(1.0, jnp.abs(theta)) * e)
            d = jnp.where(i == 0, 0.0, step)
            r_new, u_new, it, change_new = residual(theta + d, u)
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
            )

        inf = jnp.asarray(jnp.inf, dtype=x0.dtype)
        zero = jnp.asarray(0, dtype=jnp.int32)
        init = (zero, theta, jnp.full(k, inf), jnp.zeros((k, k), x0.dtype), u_init, zero, shoots, inf)
        _, theta, r, _, u, iters, shoots, change = jax.lax.while_loop(cond, body, init)

    xs, cost = rollout_with_cost(_RK4, f, lambda x, u, t: system.running_cost(x, u, t, params), x0, 0.0, h, u)
    lams = backward(xs, u, theta)
    res = jnp.max(jnp.abs(r)) if k else jnp.asarray(0.0, dtype=x0.dtype)
    finite = jnp.isfinite(change) & jnp.all(jnp.isfinite(xs)) & jnp.all(jnp.isfinite(lams))
    arrays = system.arrays()
    below = jnp.asarray(arrays["x_lower"]) - xs
    above = xs - jnp.asarray(arrays["x_upper"])
    violation = jnp.max(jnp.maximum(jnp.maximum(below, above), 0.0), axis=0) / jnp.asarray(state_scale(system))
    status = jnp.select(
        [~finite, change > cfg.tol, res > cfg.shooting_tol, jnp.max(violation) > cfg.bound_tol],
        [NON_FINITE, MAX_ITER, SHOOTING_FAILED, STATE_BOUNDS_VIOLATED],
        CONVERGED,
    )
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
        change=change,
        residual=res,
        bound_violation=violation,
    )
