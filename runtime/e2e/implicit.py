r"""Implicit gradients: differentiate a *converged* plan by the implicit function theorem on its KKT conditions.

In the NLP's scaled variables ``w = z / s`` (``s = nlp.z_scale``), a solution ``w*`` of
``min F(w; theta) s.t. c(w; theta) in [c_l, c_u], w in [l, u]`` with multipliers ``y`` satisfies, on the *free*
variables ``f`` (those not on a bound) and the *active* rows ``a`` (equalities, and inequality rows at a bound),

.. math::
    R(w, y; \theta) = \begin{pmatrix} [\nabla_w F + J^\top y]_f \\ c_a - b_a \end{pmatrix} = 0,

while a variable on its bound stays there (``dw_i / dtheta = 0``) and an inactive row has ``y_i = 0``. Differentiating,
``M (dw_f, dy_a) = -dR/dtheta`` with the symmetric KKT matrix

.. math::
    M = \begin{pmatrix} H_{ff} & J_{af}^\top \\ J_{af} & 0 \end{pmatrix}, \qquad
    H = \nabla^2_{ww} (F + y^\top c),

so the vector-Jacobian product of a cotangent ``z_bar`` is ``theta_bar = -(dR/dtheta)^T v`` with ``M v = (s z_bar)_f``:
one dense Hessian (a ``vmap`` of Hessian-vector products: one program, not n), one ``jnp.linalg.solve`` of size
n + m and one VJP of ``R``; nothing of the solver's iterations is stored. The masked rows and columns (fixed variables,
inactive rows) are replaced by the identity, so all shapes are static under ``jit``. The multipliers are
re-estimated by least squares on the free variables (``min ||[grad F + J^T y]_f||``), so the rule does not depend on
the solver's own multiplier convention.

A solve that did not converge never yields a silent gradient: the backward pass returns NaN for every cotangent
then, and also when the KKT solve is inaccurate (a singular ``M``: active constraints that are not linearly
independent, or a free direction of zero curvature). The learner checks ``converged`` and skips the step or falls
back to unrolling (``E2EConfig.on_failure``).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from ..data import ProblemData
from ..nlp import NLP
from ..solvers.base import ScaledProblem
from ..solvers.extragradient import Extragradient
from ..solvers.interior_point import InteriorPoint
from ..status import Status

__all__ = ["ImplicitSolve", "kkt_vjp", "make_implicit_solve"]

# A variable within this distance of its bound (in the scaled w) counts as on it; an inequality row within this much
# of its bound as active. The extragradient's projection puts a variable exactly on its bound.
ACTIVE_TOL = 1e-7
# The KKT solve is accepted when ||M v - rhs|| <= this times ||rhs|| (else the cotangents are NaN).
SOLVE_RTOL = 1e-6


class ImplicitSolve(NamedTuple):
    """A converged solve: ``z`` carries the implicit derivative; ``converged``, ``iterations`` and ``kkt`` do not."""

    z: jax.Array
    converged: jax.Array
    iterations: jax.Array
    violation: jax.Array
    warm: Any = None  # the interior point's primal-dual warm start for the next solve (None: the extragradient's)


def kkt_vjp(problem: ScaledProblem, data: ProblemData, z: Any, z_bar: Any) -> tuple[Any, Any, jax.Array]:
    """``(params_bar, x0_bar, ok)``: the implicit-function VJP of the solution map at a solution ``z`` (see the module
    docstring); ``ok`` is False when the KKT solve was inaccurate (its cotangents are then NaN)."""
    s = jnp.asarray(problem.scale)
    w, w_bar = z / s, z_bar * s
    n, m = w.shape[0], problem.n_constraints
    lo, hi = jnp.asarray(problem.w_lower), jnp.asarray(problem.w_upper)
    free = ~((w <= lo + ACTIVE_TOL) | (w >= hi - ACTIVE_TOL))
    f, c_fn = problem.objective, problem.constraints
    g = jax.grad(f)(w, data)
    if m:
        c_lo, c_up = jnp.asarray(problem.c_lower), jnp.asarray(problem.c_upper)
        c, jac = c_fn(w, data), jax.jacfwd(c_fn)(w, data)
        near = lambda b: jnp.abs(c - b) <= ACTIVE_TOL * (1.0 + jnp.abs(jnp.where(jnp.isfinite(b), b, 0.0)))  # noqa: E731
        active = (c_lo == c_up) | (jnp.isfinite(c_lo) & near(c_lo)) | (jnp.isfinite(c_up) & near(c_up))
        a_t = jnp.where(free[:, None] & active[None, :], jac.T, 0.0)
        y = jnp.linalg.lstsq(a_t, -jnp.where(free, g, 0.0))[0]
        y = jnp.where(active, y, 0.0)
    else:
        active = jnp.zeros(0, bool)
        jac = jnp.zeros((0, n), w.dtype)
        y = jnp.zeros(0, w.dtype)

    def lagrangian(w_, dat):
        return f(w_, dat) + (jnp.dot(y, c_fn(w_, dat)) if m else 0.0)

    hess = jax.jacfwd(jax.grad(lagrangian))(w, data)
    keep = jnp.concatenate([free, active])
    big = jnp.block([[hess, jac.T], [jac, jnp.zeros((m, m), w.dtype)]])
    big = jnp.where(keep[:, None] & keep[None, :], big, 0.0) + jnp.diag(jnp.where(keep, 0.0, 1.0))
    rhs = jnp.concatenate([jnp.where(free, w_bar, 0.0), jnp.zeros(m, w.dtype)])
    v = jnp.linalg.solve(big, rhs)
    residual = jnp.linalg.norm(big @ v - rhs)
    ok = jnp.isfinite(residual) & (residual <= SOLVE_RTOL * jnp.maximum(jnp.linalg.norm(rhs), 1e-300))

    def kkt_rows(params, x0):
        dat = ProblemData(params, x0)
        rows = [jnp.where(free, jax.grad(lagrangian)(w, dat), 0.0)]
        if m:
            rows.append(jnp.where(active, c_fn(w, dat), 0.0))
        return jnp.concatenate(rows)

    _, vjp = jax.vjp(kkt_rows, data.params, data.x0)
    params_bar, x0_bar = vjp(-v)
    nan = lambda t: jnp.where(ok, t, jnp.nan)  # noqa: E731
    return jax.tree.map(nan, params_bar), nan(x0_bar), ok


def make_implicit_solve(nlp: NLP, solver: Extragradient | InteriorPoint | None = None
                        ) -> Callable[[Any, Any, Any], ImplicitSolve]:
    """``(params, x0, z0) -> ImplicitSolve``: the solver's pure solve from ``z0``, differentiable in ``params`` and
    ``x0`` by the implicit function theorem (reverse mode, ``jax.custom_vjp``); the start gets a zero cotangent.

    Args:
        nlp: the problem; solver: an :class:`Extragradient` run to its tolerance (default ``tol=1e-9``, 20,000
            iterations: the implicit derivative is only as accurate as the solution), or an :class:`InteriorPoint`,
            whose pure solve carries its own implicit rule (:mod:`~myriad.runtime.solvers.interior_point.implicit`,
            the same equations with the solver's multipliers and active sets).

    A non-converged solve returns NaN cotangents (never a silent gradient); check ``converged``.
    """
    solver = Extragradient(tol=1e-9, max_iter=20_000) if solver is None else solver
    if isinstance(solver, InteriorPoint):
        return _interior_point_solve(nlp, solver)
    if not isinstance(solver, Extragradient):
        raise TypeError(f"make_implicit_solve: expected an Extragradient or an InteriorPoint, got "
                        f"{type(solver).__name__}")
    raw = solver.pure_solve(nlp)
    problem = ScaledProblem.from_nlp(nlp)

    def forward(params, x0, z0):
        out = raw(ProblemData(params, x0), z0)
        return ImplicitSolve(out.z, out.converged, out.iterations, out.violation)

    @jax.custom_vjp
    def solve(params, x0, z0):
        return forward(params, x0, z0)

    def fwd(params, x0, z0):
        out = forward(params, x0, z0)
        return out, (params, x0, out.z, out.converged)

    def bwd(res, cotangents):
        params, x0, z, converged = res
        params_bar, x0_bar, _ = kkt_vjp(problem, ProblemData(params, x0), z, cotangents.z)
        nan = lambda t: jnp.where(converged, t, jnp.nan)  # noqa: E731
        return jax.tree.map(nan, params_bar), nan(x0_bar), jnp.zeros_like(z)

    solve.defvjp(fwd, bwd)
    return solve




def _interior_point_solve(nlp: NLP, solver: InteriorPoint) -> Callable[[Any, Any, Any], ImplicitSolve]:
    # The interior point's pure solve is differentiable already (NaN cotangents unless converged); the start (the
    # NLP's variables or a primal-dual WarmStart) is a warm start only, so it gets a zero cotangent.
    raw = solver.pure_solve(nlp)

    def solve(params, x0, z0):
        out = raw(ProblemData(params, x0), jax.lax.stop_gradient(z0))
        return ImplicitSolve(out.z, out.status == int(Status.CONVERGED), out.iterations, out.violation,
                             jax.lax.stop_gradient(out.warm))

    return solve
