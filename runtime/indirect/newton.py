r"""The Newton endgame: a semismooth Newton method on Pontryagin's conditions (stationary u* only).

Unknowns z = (u, theta): the controls at the N + 1 nodes and the unknown terminal costates of the fixed final
states. Pontryagin's conditions, each row in units of its variable's nominal scale, are

    F(u, theta) = ( (u - G(u; theta)) / s_u ,  (x_fixed(T; u) - x_final) / s_x ) = 0,

whose root is exactly the sweep's fixed point (same RK4 sweeps, :func:`.pontryagin.sweep_map`). Jacobian-vector
products come from forward-mode differentiation through both rollouts, the linear systems from GMRES
(``jax.scipy.sparse.linalg.gmres``); the step is projected into the control bounds and backtracked until ||F|| falls
(Armijo). u* is clipped, so F is only piecewise smooth: this is a semismooth Newton method (Ulbrich 2011), fast once
the active set is right.

The sweep globalises, Newton converges (:func:`sweep_then_newton`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
from jax.scipy.sparse.linalg import gmres

from .pontryagin import Problem, relative_change, sweep_map
from .relaxation import relax

if TYPE_CHECKING:
    from .sweep import ForwardBackwardSweep

__all__ = ["sweep_then_newton"]

# GMRES(50) restarted at most 10 times (<= 500 Jacobian-vector products, each about two sweeps' work) to a relative
# residual of 1e-8, far below what the quadratic convergence needs; backtracking halves the step at most 12 times
# and wants ||F|| to fall by the fraction 1e-4 of the step taken (Armijo).
_GMRES_RESTART, _GMRES_MAXITER, _GMRES_TOL = 50, 10, 1e-8
_MAX_HALVINGS, _ARMIJO = 12, 1e-4
# Sweep-then-Newton attempts, the switch 10 times smaller each time.
_NEWTON_ATTEMPTS = 4


def split(p: Problem, z: Any) -> tuple[Any, Any]:
    """z = (u.ravel(), theta) -> (u (N + 1, m), theta (k,))."""
    size = p.times.shape[0] * p.system.n_controls
    return z[:size].reshape(p.times.shape[0], p.system.n_controls), z[size:]


def residual(p: Problem, z: Any) -> Any:
    """Pontryagin's conditions F(u, theta), each row in units of its variable's nominal scale."""
    u, theta = split(p, z)
    new, xs = sweep_map(p, u, theta)
    return jnp.concatenate([((u - new) / p.su).ravel(), (xs[-1, p.fixed] - p.final) / p.sx[p.fixed]])


def solved(p: Problem, cfg: "ForwardBackwardSweep", z: Any, F: Any) -> Any:
    """The sweep's own stopping test at z: relative change <= tol and final-state residual <= shooting_tol."""
    u, _ = split(p, z)
    size = u.size
    change = relative_change(p, u - F[:size].reshape(u.shape) * p.su, u)
    return (change <= cfg.tol) & (jnp.max(jnp.abs(F[size:] * p.sx[p.fixed]), initial=0.0) <= cfg.shooting_tol)


def project(p: Problem, z: Any) -> Any:
    """z with its controls clipped into the control bounds (theta is free)."""
    u, theta = split(p, z)
    return jnp.concatenate([jnp.clip(u, p.u_lo, p.u_hi).ravel(), theta])


def direction(p: Problem, z: Any, F: Any) -> Any:
    """The Newton step d: F'(z) d = -F, F' applied by forward-mode differentiation through both rollouts."""
    _, jvp = jax.linearize(lambda z: residual(p, z), z)
    return gmres(jvp, -F, tol=_GMRES_TOL, restart=_GMRES_RESTART, maxiter=_GMRES_MAXITER)[0]


def newton(p: Problem, cfg: "ForwardBackwardSweep", z: Any) -> tuple[Any, Any, Any]:
    """Damped semismooth Newton from z: (z, steps, solved); z only moves on a sufficient decrease of ||F||.

    One loop whose every pass evaluates F once, at the trial point z + alpha d: accepted, it becomes the new z and
    gets a new direction (alpha = 1); rejected, alpha is halved. The first pass is the trial alpha = 0 against
    ||F|| = inf, so there is a single call site of F and of the direction (each compiled once)."""
    dtype = z.dtype
    int0 = jnp.asarray(0, dtype=jnp.int32)
    inf = jnp.asarray(jnp.inf, dtype=dtype)

    def cond(c):
        _, _, _, _, steps, halvings, ok = c
        return ~ok & (halvings <= _MAX_HALVINGS) & (steps < cfg.max_newton_iter)

    def body(c):
        z, F, d, alpha, steps, halvings, _ = c
        z_t = project(p, z + alpha * d)
        F_t = residual(p, z_t)
        decrease = jnp.linalg.norm(F_t) <= (1.0 - _ARMIJO * alpha) * jnp.linalg.norm(F)
        accept = jnp.all(jnp.isfinite(F_t)) & decrease
        ok = accept & solved(p, cfg, z_t, F_t)
        d = jax.lax.cond(accept & ~ok, lambda z, F: direction(p, z, F), lambda z, F: d, z_t, F_t)
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


def sweep_then_newton(p: Problem, cfg: "ForwardBackwardSweep", u: Any, omega: Any) -> tuple[Any, ...]:
    """Relaxed sweeps from the controls u until the relative change is below ``newton_switch``, then Newton; if Newton
    stalls, the sweep continues from Newton's best point to a 10 times smaller switch and Newton is tried again
    (``_NEWTON_ATTEMPTS`` in all). The sweeps run at theta = 0 (the free-final-state problem).

    Returns:
        (u, theta, omega, sweeps, newton_steps, reached): ``reached`` is True when the last attempt's sweep got below
        its switch (so Newton ran, and a failure is Newton's, not the sweep's).
    """
    dtype = u.dtype
    int0 = jnp.asarray(0, dtype=jnp.int32)
    false = jnp.asarray(False)

    # One loop, one call site of the sweep and of Newton, so each is compiled once.
    def cond(c):
        attempt, _, _, sweeps, _, reached, ok = c
        return ~ok & (attempt < _NEWTON_ATTEMPTS) & (sweeps < cfg.max_iter) & ((attempt == 0) | reached)

    def body(c):
        attempt, z, omega, sweeps, nits, _, _ = c
        u, theta = split(p, z)
        switch = jnp.maximum(cfg.newton_switch * 0.1 ** attempt.astype(dtype), cfg.tol)
        u, omega, it, change = relax(p, theta, u, omega, cfg.max_iter - sweeps, switch)
        z = jnp.concatenate([u.ravel(), theta])
        reached = change <= switch  # False for NaN too: Newton is not started from a diverged sweep
        skip = lambda z: (z, int0, false)  # noqa: E731
        z_n, nit, ok = jax.lax.cond(reached, lambda z: newton(p, cfg, z), skip, z)
        z = jnp.where(reached, z_n, z)
        return attempt + 1, z, omega, sweeps + it, nits + jnp.where(reached, nit, 0), reached, reached & ok

    theta = jnp.zeros(p.k, dtype=dtype)
    z0 = jnp.concatenate([u.ravel(), theta])
    init = (int0, z0, omega, int0, int0, false, false)
    _, z, omega, sweeps, newton_steps, reached, _ = jax.lax.while_loop(cond, body, init)
    u, theta = split(p, z)
    return u, theta, omega, sweeps, newton_steps, reached
