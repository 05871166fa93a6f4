r"""The one implicit-function rule: reverse-mode derivatives of a solved NLP from its KKT conditions.

At a solution ``w*`` of the NLP in ``w = z / z_scale`` with multipliers ``y`` (IPOPT's sign), on the *free* variables
``f`` (not on a bound) and the *active* rows ``a`` (equalities, and inequality rows at a bound)

.. math::
    R(w, y; \theta) = \begin{pmatrix} [\nabla_w F + J^\top y]_f \\ c_a(w) \end{pmatrix} = 0,

while a variable on its bound stays there (``dw_i / dtheta = 0``) and an inactive row keeps ``y_i = 0``.
Differentiating ``R = 0``, ``M (dw_f, dy_a) = -dR/dtheta`` with the symmetric KKT matrix

.. math::
    M = \begin{pmatrix} H_{ff} & J_{af}^\top \\ J_{af} & 0 \end{pmatrix},\qquad H = \nabla^2_{ww}(F + y^\top c),

so the cotangents ``(w_bar, y_bar)`` of the solution map pull back to ``theta_bar = -(dR/dtheta)^T v`` with
``M v = (w_bar_f, y_bar_a)``: one factorisation of ``M`` and one VJP of ``R``; nothing of the solver's iterations is
stored. Where the NLP has a stage structure (collocation, multiple shooting) ``M`` is assembled and factorised stage
by stage, as the interior point's Newton step is (:mod:`.interior_point.banded`), so a gradient costs time and memory
linear in the number of stages; otherwise (or with ``stages=False``, the reference) it is one dense Hessian (a
``vmap`` of Hessian-vector products) and one ``jnp.linalg.solve`` of size n + m. The objective ``F(z*(theta); theta)``
adds its explicit part. Masked rows and columns are the identity, so shapes stay static under ``jit`` and ``vmap``.

Where the rule linearises (:class:`Active`: the free variables, the active rows and ``y``) is the solver's to say:
the interior point reports its own verdict (a bound multiplier larger than the gap to its bound) and multipliers;
a solver that reports none (the extragradient, whose projection puts a variable exactly on its bound) gets
:func:`estimated_active`: distances to the bounds and least-squares multipliers, independent of the solver's own
multiplier convention.

A solve that did not converge never yields a silent gradient: its cotangents are NaN, and so are those of a KKT solve
with relative residual above ``SOLVE_RTOL`` (a singular ``M``: dependent active constraints, or zero curvature on a
free direction).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from .base import ScaledProblem

__all__ = ["ACTIVE_TOL", "Active", "SOLVE_RTOL", "differentiable", "estimated_active", "kkt_vjp"]

# The KKT solve is accepted when ||M v - rhs|| <= this times ||rhs|| (else the cotangents are NaN).
SOLVE_RTOL = 1e-6
# estimated_active: a variable within this distance of its bound (in the scaled w) counts as on it; an inequality
# row within this much of its bound as active.
ACTIVE_TOL = 1e-7


class Active(NamedTuple):
    """Where the rule linearises a solution: ``y`` (m,) the multipliers (0 off the active rows), ``free`` (n,) the
    variables not on a bound, ``active`` (m,) the rows held at a bound (bool arrays)."""

    y: jax.Array
    free: jax.Array
    active: jax.Array


def estimated_active(problem: ScaledProblem, data: Any, w: jax.Array) -> Active:
    """:class:`Active` of a solution ``w`` from the solution alone: variables within ``ACTIVE_TOL`` of a bound are on
    it, rows within ``ACTIVE_TOL`` (relative) of a bound are active, and ``y`` minimises ``||[grad F + J^T y]_f||``."""
    m = problem.n_constraints
    lo, hi = jnp.asarray(problem.w_lower), jnp.asarray(problem.w_upper)
    free = ~((w <= lo + ACTIVE_TOL) | (w >= hi - ACTIVE_TOL))
    if not m:
        return Active(jnp.zeros(0, w.dtype), free, jnp.zeros(0, bool))
    g = jax.grad(problem.objective)(w, data)
    c_fn = problem.constraints
    c_lo, c_up = jnp.asarray(problem.c_lower), jnp.asarray(problem.c_upper)
    c, jac = c_fn(w, data), jax.jacfwd(c_fn)(w, data)
    near = lambda b: jnp.abs(c - b) <= ACTIVE_TOL * (1.0 + jnp.abs(jnp.where(jnp.isfinite(b), b, 0.0)))  # noqa: E731
    active = (c_lo == c_up) | (jnp.isfinite(c_lo) & near(c_lo)) | (jnp.isfinite(c_up) & near(c_up))
    a_t = jnp.where(free[:, None] & active[None, :], jac.T, 0.0)
    y = jnp.linalg.lstsq(a_t, -jnp.where(free, g, 0.0))[0]
    return Active(jnp.where(active, y, 0.0), free, active)


def kkt_vjp(problem: ScaledProblem, data: Any, w: jax.Array, at: Active, w_bar: jax.Array,
            y_bar: jax.Array | None = None, stages: bool = True) -> tuple[Any, jax.Array]:
    """``(data_bar, ok)``: the pull-back of the cotangents ``w_bar`` (of the scaled solution ``w``) and ``y_bar`` (of
    the multipliers; None: 0) to ``data`` (see the module docstring); ``ok`` is False when the KKT solve was
    inaccurate (the caller turns the cotangents into NaN then). ``stages``: solve stage by stage where the NLP has
    a stage structure (else, or with False, the dense reference)."""
    n, m = w.shape[0], problem.n_constraints
    f_fn, c_fn = problem.objective, problem.constraints
    free, active, y = at.free, at.active, at.y

    def lagrangian(w_, dat):
        return f_fn(w_, dat) + (jnp.dot(y, c_fn(w_, dat)) if m else 0.0)

    y_bar = jnp.zeros(m, w.dtype) if y_bar is None or not m else jnp.where(active, y_bar, 0.0)
    rhs = jnp.concatenate([jnp.where(free, w_bar, 0.0), y_bar])
    if stages and problem.stage_structure is not None and m:
        v, residual = _stage_solve(problem, data, w, at, rhs[:n], rhs[n:])
    else:
        hess = jax.jacfwd(jax.grad(lagrangian))(w, data)
        jac = jax.jacfwd(c_fn)(w, data) if m else jnp.zeros((0, n), w.dtype)
        keep = jnp.concatenate([free, active])
        big = jnp.block([[hess, jac.T], [jac, jnp.zeros((m, m), w.dtype)]])
        big = jnp.where(keep[:, None] & keep[None, :], big, 0.0) + jnp.diag(jnp.where(keep, 0.0, 1.0))
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
    return data_bar, ok


def differentiable(raw: Callable[[Any, Any], Any], problem: ScaledProblem, active_of: Callable[[Any, Any], Active],
                   converged_of: Callable[[Any], jax.Array], multipliers: bool = False) -> Callable[[Any, Any], Any]:
    """``raw`` (a pure solve ``(data, z0) -> output`` whose output has a field ``z``, and optionally ``objective``)
    with a ``jax.custom_vjp``: reverse mode in ``data`` by :func:`kkt_vjp` at ``active_of(data, output)``; NaN
    cotangents unless ``converged_of(output)``. With ``multipliers``, the output's ``multipliers`` are
    ``active_of``'s ``y`` and their cotangent is pulled back too (else it is ignored). ``z0`` gets a zero cotangent (a
    converged solution does not depend on the start). Forward mode (``jax.jvp``) is not defined."""
    scale = jnp.asarray(problem.scale)

    @jax.custom_vjp
    def solve(data, z0):
        return raw(data, z0)

    def fwd(data, z0):
        out = raw(data, z0)
        return out, (data, z0, out)

    def bwd(res, cot):
        data, z0, out = res
        w = out.z / scale
        w_bar, explicit = cot.z * scale, None
        if hasattr(cot, "objective"):  # F(z*(theta); theta): a cotangent of w plus an explicit term in data
            _, f_vjp = jax.vjp(lambda w_, dat: problem.objective(w_, dat), w, data)
            obj_w_bar, explicit = f_vjp(jnp.asarray(cot.objective, w.dtype))
            w_bar = w_bar + obj_w_bar
        y_bar = cot.multipliers if multipliers else None
        data_bar, ok = kkt_vjp(problem, data, w, active_of(data, out), w_bar, y_bar)
        good = ok & converged_of(out)
        if explicit is None:
            data_bar = jax.tree.map(lambda a: jnp.where(good, a, jnp.nan), data_bar)
        else:
            data_bar = jax.tree.map(lambda a, b: jnp.where(good, a + b, jnp.nan), data_bar, explicit)
        return data_bar, jax.tree.map(jnp.zeros_like, z0)

    solve.defvjp(fwd, bwd)
    return solve


def _stage_solve(problem: ScaledProblem, data: Any, w: jax.Array, at: Active, rhs_w: jax.Array,
                 rhs_y: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(v, ||M v - rhs||)`` with ``M`` assembled and factorised stage by stage (the interior point's block
    tridiagonal factorisation, :mod:`.interior_point.banded`): cost and memory linear in the number of stages, where
    the dense ``M`` costs ``O(n^3)``."""
    from .interior_point import banded, stage_blocks  # here: the interior point imports this module

    index = stage_blocks.StageIndex.from_structure(problem.stage_structure)
    _, _, _, blocks = stage_blocks.stage_derivatives(problem.evaluate, index)(w, at.y, data)
    dw, dy, residual = banded.Banded(index, index.n, index.m).solve_restricted(blocks, at.free, at.active, rhs_w,
                                                                               rhs_y)
    return jnp.concatenate([dw, dy]), residual
