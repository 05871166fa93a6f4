r"""Shooting on fixed final states around converged sweeps (bang-bang u*, or ``newton=False``).

For each state with a required final value, lambda_i(T) = theta_i is unknown. A quasi-Newton (Broyden) iteration
solves

    r(theta) = x_fixed(T; theta) - x_final = 0,

each evaluation a converged relaxed sweep (:func:`.relaxation.relax`) at theta, warm-started from the accepted
controls. The first Jacobian is by forward differences (one extra sweep per fixed state, step
1e-3 max(1, |theta_j|)), then Broyden's ("good") rank-one update

    J <- J + (r_new - r - J d) d^T / (d^T d),

so with one fixed state this is the secant method of Lenhart & Workman's Lab 13. It starts from theta = 0 and stops
early if the sweep at the current theta does not converge (the residuals of an unconverged sweep are noise).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp

from .pontryagin import Problem, forward
from .relaxation import relax

if TYPE_CHECKING:
    from .sweep import ForwardBackwardSweep

__all__ = ["sweep_and_shoot"]


def _residual(p: Problem, cfg: "ForwardBackwardSweep", theta: Any, u: Any, omega: Any) -> tuple[Any, ...]:
    """r(theta), from a relaxed sweep run to ``tol`` from u: (r, u, sweeps, change, omega)."""
    u, omega, it, change = relax(p, theta, u, omega, cfg.max_iter, cfg.tol)
    return forward(p, u)[-1, p.fixed] - p.final, u, it, change, omega


def sweep_and_shoot(p: Problem, cfg: "ForwardBackwardSweep", u: Any, omega: Any) -> tuple[Any, ...]:
    """Relaxed sweeps from u, with Broyden's method on theta when some final states are fixed.

    Returns:
        (u, theta, r, omega, sweeps, shooting_steps, change): r the final-state residual (k,), change the relative
        change of the last sweep at the accepted theta.
    """
    dtype = u.dtype
    k = p.k
    int0 = jnp.asarray(0, dtype=jnp.int32)
    inf = jnp.asarray(jnp.inf, dtype=dtype)
    theta = jnp.zeros(k, dtype=dtype)
    if not k:
        r, u, sweeps, change, omega = _residual(p, cfg, theta, u, omega)
        return u, theta, r, omega, sweeps, int0, change

    # One loop, one call site of the inner sweep (so it is compiled once). Iteration 0 evaluates r(theta_0);
    # iterations 1..k evaluate r(theta + delta_j e_j) without moving the base, and Broyden's update from J = 0 then
    # sets column j to the forward difference (r_j - r) / delta_j exactly; from iteration k + 1 on, each step
    # d = -J^-1 r is accepted and J gets Broyden's update.
    eye = jnp.eye(k, dtype=dtype)
    omega0 = omega

    def cond(c):
        i, _, r, _, _, _, shoots, change, _ = c
        base_ok = (i == 0) | (change <= cfg.tol)  # stop as soon as the sweep at the base point fails
        searching = (shoots < cfg.max_shooting_iter) & (jnp.max(jnp.abs(r)) > cfg.shooting_tol)
        return base_ok & ((i <= k) | searching)

    def body(c):
        i, theta, r, J, u, sweeps, shoots, change, omega = c
        newton = i > k
        e = eye[jnp.clip(i - 1, 0, k - 1)]
        # The identity stands in for J while it is still being built, so the unused solve stays finite.
        newton_step = -jnp.linalg.solve(jnp.where(newton, J, eye), r)
        step = jnp.where(newton, newton_step, 1e-3 * jnp.maximum(1.0, jnp.abs(theta)) * e)
        d = jnp.where(i == 0, 0.0, step)
        # Every evaluation restarts the step control from the configured omega.
        r_new, u_new, it, change_new, omega_new = _residual(p, cfg, theta + d, u, omega0)
        dd = jnp.dot(d, d)
        J = jnp.where(i == 0, J, J + jnp.outer(r_new - r - J @ d, d) / jnp.where(i == 0, 1.0, dd))
        accept = (i == 0) | newton
        return (
            i + 1,
            jnp.where(accept, theta + d, theta),
            jnp.where(accept, r_new, r),
            J,
            jnp.where(accept, u_new, u),
            sweeps + it,
            shoots + newton.astype(shoots.dtype),
            jnp.where(accept, change_new, change),
            jnp.where(accept, omega_new, omega),
        )

    init = (int0, theta, jnp.full(k, inf), jnp.zeros((k, k), dtype), u, int0, int0, inf, omega)
    _, theta, r, _, u, sweeps, shoots, change, omega = jax.lax.while_loop(cond, body, init)
    return u, theta, r, omega, sweeps, shoots, change
