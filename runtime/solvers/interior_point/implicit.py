r"""Reverse-mode derivatives of a converged solve: the implicit function theorem on the KKT conditions.

At a solution ``w*`` of the NLP in ``w = z / z_scale`` with multipliers ``y`` (IPOPT's sign), on the *free* variables
``f`` (not held at a bound) and the *active* rows ``a`` (equalities, and inequality rows whose slack is held)

.. math::
    R(w, y; \theta) = \begin{pmatrix} [\nabla_w F + J^\top y]_f \\ c_a(w) \end{pmatrix} = 0,

while a held variable stays on its bound and an inactive row keeps ``y_i = 0``. "Held" is the interior-point
solution's own verdict: the bound multiplier exceeds the distance to the bound (``z_l > w - l``; at the barrier
solution ``z_l (w - l) = mu``, so the two sides are ``sqrt(mu)`` apart only for a degenerate bound). Differentiating
``R = 0``, ``M (dw_f, dy_a) = -dR/dtheta`` with

.. math::
    M = \begin{pmatrix} H_{ff} & J_{af}^\top \\ J_{af} & 0 \end{pmatrix},\qquad H = \nabla^2_{ww}(F + y^\top c),

so the cotangents ``(w_bar, y_bar)`` of the solution map pull back to ``theta_bar = -(dR/dtheta)^T v`` with
``M v = (w_bar_f, y_bar_a)`` (``M`` is symmetric). The objective ``F(z*(theta); theta)`` adds its explicit part.
Masked rows and columns are the identity, so shapes stay static under ``jit`` and ``vmap``.

A solve that did not converge never yields a silent gradient: its cotangents are NaN, and so are those of a KKT solve
with relative residual above ``1e-6`` (a singular ``M``: dependent active constraints, or zero curvature on a free
direction). Check ``status`` (or ``jnp.isfinite`` of the gradient).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp

from ...status import Status
from ..base import ScaledProblem
from .loop import InteriorPointSolution

__all__ = ["differentiable"]

SOLVE_RTOL = 1e-6


def _data_vjp(problem: ScaledProblem, data: Any, out: InteriorPointSolution, cot: InteriorPointSolution) -> Any:
    """``data_bar`` for the cotangents of ``z``, ``objective`` and ``multipliers`` (see the module docstring)."""
    s = jnp.asarray(problem.scale)
    w = out.z / s
    n, m = w.shape[0], problem.n_constraints
    f_fn, c_fn = problem.objective, problem.constraints
    free = ~(out.active_lower | out.active_upper)
    active = out.active_rows
    y = jnp.where(active, out.multipliers, 0.0) if m else jnp.zeros(0, w.dtype)

    def lagrangian(w_, dat):
        return f_fn(w_, dat) + (jnp.dot(y, c_fn(w_, dat)) if m else 0.0)

    # The objective's cotangent is a cotangent of w (through F(w)) plus an explicit term in data.
    grad_f_w, f_vjp = jax.vjp(lambda w_, dat: f_fn(w_, dat), w, data)
    del grad_f_w
    obj_w_bar, obj_data_bar = f_vjp(jnp.asarray(cot.objective, w.dtype))
    w_bar = cot.z * s + obj_w_bar

    hess = jax.jacfwd(jax.grad(lagrangian))(w, data)
    jac = jax.jacfwd(c_fn)(w, data) if m else jnp.zeros((0, n), w.dtype)
    keep = jnp.concatenate([free, active])
    big = jnp.block([[hess, jac.T], [jac, jnp.zeros((m, m), w.dtype)]])
    big = jnp.where(keep[:, None] & keep[None, :], big, 0.0) + jnp.diag(jnp.where(keep, 0.0, 1.0))
    y_bar = jnp.where(active, cot.multipliers, 0.0) if m else jnp.zeros(0, w.dtype)
    rhs = jnp.concatenate([jnp.where(free, w_bar, 0.0), y_bar])
    v = jnp.linalg.solve(big, rhs)
    residual = jnp.linalg.norm(big @ v - rhs)
    ok = jnp.isfinite(residual) & (residual <= SOLVE_RTOL * jnp.maximum(jnp.linalg.norm(rhs), 1e-300))

    def kkt_rows(dat):
        rows = [jnp.where(free, jax.grad(lagrangian)(w, dat), 0.0)]
        if m:
            rows.append(jnp.where(active, c_fn(w, dat), 0.0))
        return jnp.concatenate(rows)

    _, vjp = jax.vjp(kkt_rows, data)
    (data_bar,) = vjp(-v)
    good = ok & (out.status == int(Status.CONVERGED))
    return jax.tree.map(lambda a, b: jnp.where(good, a + b, jnp.nan), data_bar, obj_data_bar)


def differentiable(raw: Callable[[Any, Any], InteriorPointSolution],
                   problem: ScaledProblem) -> Callable[[Any, Any], InteriorPointSolution]:
    """``raw`` with a ``jax.custom_vjp``: reverse mode in ``data`` by the implicit function theorem; ``z0`` gets a
    zero cotangent (a converged solution does not depend on the start). Forward mode (``jax.jvp``) is not defined."""

    @jax.custom_vjp
    def solve(data, z0):
        return raw(data, z0)

    def fwd(data, z0):
        out = raw(data, z0)
        return out, (data, z0, out)

    def bwd(res, cot):
        data, z0, out = res
        return _data_vjp(problem, data, out, cot), jax.tree.map(jnp.zeros_like, z0)

    solve.defvjp(fwd, bwd)
    return solve
