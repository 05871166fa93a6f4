r"""The barrier problem's variables, bounds and derivatives: the NLP with slacks, in the scaled ``w = z / z_scale``.

Every non-equality row ``i`` gets a slack ``s_i`` (``c_I(w) - s = 0``, ``c^l_I <= s <= c^u_I``), so the solver sees

.. math::
    \min_x\ \sigma F(w) \quad\text{s.t.}\quad g(x) = D \begin{pmatrix} c_E(w) - c^l_E \\ c_I(w) - s \end{pmatrix} = 0,
    \qquad x^l \le x = (w, s) \le x^u,

with only equalities and bounds (Wächter & Biegler 2006, eq. 1). ``sigma`` and the row scales ``D`` are IPOPT's
gradient-based scaling at the start (``min(1, 100 / ||gradient||_inf)``): changes of units only, so the solution,
the violation and the reported multipliers (divided back) are those of the NLP as given.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..base import ScaledProblem, split_constraints
from .kkt import uses_nullspace
from .riccati import Riccati, StageHessian, chain
from .stage_problem import StageProblem

__all__ = ["Layout", "Point"]

# IPOPT's nlp_scaling_max_gradient: rows (and the objective) whose gradient exceeds this at the start are scaled down.
MAX_GRADIENT = 100.0


class Point(NamedTuple):
    """First and second derivatives of the scaled barrier problem at ``x`` (slacks included)."""

    f: jax.Array  # sigma F(w)
    grad: jax.Array  # (n_x,) d(sigma F)/dx (zero on the slacks)
    g: jax.Array  # (m,) the scaled equality residuals
    jac: jax.Array  # (m, n_x) dg/dx
    hess: Any  # (n_x, n_x) Hessian of sigma F + lambda^T g (zero on the slacks: they enter linearly), or its stages
    objective: jax.Array  # F(w), unscaled
    violation: jax.Array  # the NLP's own constraint violation (rows as given, infinity norm)


class Layout:
    """The static shape of the barrier problem for one scaled NLP (host arrays; nothing here is traced).

    Attributes:
        n, m: NLP variables and constraints; n_s: slacks (non-equality rows); n_x = n + n_s.
        rows: the NLP's rows in the solver's order (equalities first, then the slack rows).
        riccati: the stage-wise Newton step (:class:`~.riccati.Riccati`) when asked for and the NLP allows it
            (:meth:`stagewise`), else None (dense Hessian, :mod:`.kkt`).
        x_lower, x_upper: bounds of ``x = (w, s)`` with 0 where infinite; has_lower, has_upper: which are finite.
    """

    def __init__(self, problem: ScaledProblem, kkt: str = "dense"):
        self.problem = problem
        self.n, self.m = problem.n_variables, problem.n_constraints
        c_lo, c_up = problem.c_lower, problem.c_upper
        eq, _, _ = split_constraints(c_lo, c_up)
        ineq = np.setdiff1d(np.arange(self.m), eq)
        self.eq, self.ineq = eq, ineq
        self.rows = np.concatenate([eq, ineq]).astype(np.int64)
        self.n_s = int(ineq.size)
        self.n_x = self.n + self.n_s
        lo = np.concatenate([problem.w_lower, c_lo[ineq]])
        hi = np.concatenate([problem.w_upper, c_up[ineq]])
        self.has_lower, self.has_upper = np.isfinite(lo), np.isfinite(hi)
        self.x_lower, self.x_upper = np.where(self.has_lower, lo, 0.0), np.where(self.has_upper, hi, 0.0)
        # Right-hand sides of the equality rows (slack rows have none: the slack carries the bound).
        self.b = np.concatenate([c_lo[eq], np.zeros(self.n_s)])
        self.slack_sign = np.concatenate([np.zeros(eq.size), -np.ones(self.n_s)])
        if kkt == "riccati" and not self.stagewise(problem):
            raise ValueError("InteriorPoint(kkt='riccati'): the NLP has no stage-wise derivatives whose steps read "
                             "the decisions as a chain (single shooting without path rows, slacks or free time)")
        self.riccati = Riccati(problem.stage_index, self.n, self.n_s) if kkt == "riccati" else None
        if kkt == "banded" and not StageProblem.applies(problem):
            raise ValueError("InteriorPoint(kkt='banded'): the NLP has no stage structure (collocation and multiple "
                             "shooting have one; single shooting takes kkt='riccati' or 'dense')")
        self.stage = StageProblem(self) if kkt == "banded" else None
        self.banded = self.stage.banded if self.stage is not None else None

    @staticmethod
    def stagewise(problem: ScaledProblem) -> bool:
        """Whether the stage-wise (Riccati) Newton step applies: stage derivatives whose steps read the decisions as
        a chain, and few rows (the dense method's own choice for many is the null-space method)."""
        if problem.stages is None or chain(problem.stage_index, problem.n_variables) is None:
            return False
        n_s = len(np.setdiff1d(np.arange(problem.n_constraints), split_constraints(problem.c_lower,
                                                                                   problem.c_upper)[0]))
        return not uses_nullspace(problem.n_variables + n_s, problem.n_constraints)

    # ---- the start ---------------------------------------------------------------------------------------------

    def push_inside(self, x: jax.Array) -> jax.Array:
        """IPOPT's bound push: at least ``min(1e-2 max(1, |bound|), 1e-2 (upper - lower))`` inside each finite bound."""
        lo, hi, hl, hu = self.x_lower, self.x_upper, self.has_lower, self.has_upper
        width = np.where(hl & hu, hi - lo, np.inf)
        p_lo = np.minimum(1e-2 * np.maximum(1.0, np.abs(lo)), 1e-2 * width)
        p_hi = np.minimum(1e-2 * np.maximum(1.0, np.abs(hi)), 1e-2 * width)
        x = jnp.where(hl, jnp.maximum(x, lo + p_lo), x)
        return jnp.where(hu, jnp.minimum(x, hi - p_hi), x)

    def start(self, w0: jax.Array, data: Any) -> jax.Array:
        """``x0``: ``w0`` and ``c_I(w0)`` pushed inside their bounds (one forward evaluation)."""
        w0 = self.push_inside(jnp.concatenate([w0, jnp.zeros(self.n_s, w0.dtype)]))[: self.n]
        _, c = self.problem.evaluate(w0, data)
        return self.push_inside(jnp.concatenate([w0, jnp.reshape(c, (-1,))[self.ineq]]))

    def scaling(self, grad_f: jax.Array, jac_c: jax.Array) -> tuple[jax.Array, jax.Array]:
        """IPOPT's gradient-based ``(sigma, row_scale)`` from the unscaled derivatives at the start."""
        sigma = jnp.minimum(1.0, MAX_GRADIENT / jnp.maximum(jnp.max(jnp.abs(grad_f), initial=0.0), 1e-300))
        if not self.m:
            row_max = jnp.zeros(0, grad_f.dtype)
        elif self.stage is not None:
            row_max = self.stage.row_max(jac_c)
        else:
            row_max = jnp.max(jnp.abs(jac_c), axis=1, initial=0.0)[self.rows]
        row_scale = jnp.minimum(1.0, MAX_GRADIENT / jnp.maximum(row_max, 1e-300))
        return jax.lax.stop_gradient(sigma), jax.lax.stop_gradient(row_scale)

    def residual(self, x: jax.Array, c: jax.Array, row_scale: jax.Array) -> jax.Array:
        """``g(x) = D (c_rows - b + slack_sign * s)`` from ``c = c(w)`` (the NLP's row order)."""
        s = jnp.concatenate([jnp.zeros(self.eq.size, x.dtype), x[self.n:]])
        return row_scale * (c[self.rows] - self.b + self.slack_sign * s)

    def values(self, x: jax.Array, data: Any, sigma: jax.Array, row_scale: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(sigma F, g)`` at ``x``: what a line-search trial needs."""
        f, c = self.problem.evaluate(x[: self.n], data)
        return sigma * f, self.residual(x, jnp.reshape(c, (-1,)), row_scale)

    def violation(self, x: jax.Array, c: jax.Array) -> jax.Array:
        """The NLP's constraint violation at ``w = x[:n]`` (rows as given; bounds hold by the barrier)."""
        if not self.m:
            return jnp.zeros((), x.dtype)
        lo, hi = self.problem.c_lower, self.problem.c_upper
        over = jnp.where(np.isfinite(hi), c - np.where(np.isfinite(hi), hi, 0.0), 0.0)
        under = jnp.where(np.isfinite(lo), np.where(np.isfinite(lo), lo, 0.0) - c, 0.0)
        return jnp.max(jnp.concatenate([jnp.zeros(1, x.dtype), over, under]))

    def derivatives(self, w: jax.Array, y: jax.Array, data: Any, objective_weight: Any = 1.0) -> tuple:
        """``(F, c, dF/dw, dc/dw, Hessian of s F + y^T c)`` at ``w``, unscaled, ``y`` in the NLP's row order, ``s`` the
        ``objective_weight`` (IPOPT's ``obj_factor``: 0 in the restoration phase; the gradient is ``F``'s whatever it).

        One program (half the rollouts to compile of a first-order and a Hessian program): the JVPs of ``(F, c,
        grad_w(s F + y^T c))`` along the ``n`` unit vectors, unless the transcription gives them itself."""
        if self.stage is not None:  # block-tridiagonal (banded.py): the blocks by colour seeds
            return self.stage.derivatives(w, y, data, objective_weight)
        # The Hessian as its stages (riccati.py), or the transcription's own.
        given = self.problem.stages if self.riccati is not None else self.problem.derivatives
        if given is not None:
            f, c, grad_f, jac_c, hess = given(w, y, data, objective_weight)
            return f, jnp.reshape(c, (-1,)), grad_f, jnp.reshape(jac_c, (-1, self.n)), hess
        evaluate = self.problem.evaluate

        def lagrangian(w_):
            f_, c_ = evaluate(w_, data)
            c_ = jnp.reshape(c_, (-1,))
            return objective_weight * f_ + (jnp.dot(y, c_) if self.m else 0.0), (f_, c_)

        def outputs(w_):
            (_, (f_, c_)), grad_l = jax.value_and_grad(lagrangian, has_aux=True)(w_)
            return f_, c_, grad_l

        eye = jnp.eye(self.n, dtype=w.dtype)
        (f, c, _), (grad_f, jac_t, hess) = jax.vmap(lambda v: jax.jvp(outputs, (w,), (v,)), out_axes=(None, 0))(eye)
        return f, c, grad_f, jac_t.T, 0.5 * (hess + hess.T)

    def point(self, x: jax.Array, f: jax.Array, c: jax.Array, grad_f: jax.Array, jac_c: jax.Array,
              hess: jax.Array, sigma: jax.Array, row_scale: jax.Array) -> Point:
        """The scaled barrier problem's derivatives at ``x`` from the NLP's (``hess`` of ``F + y^T c`` with
        ``y = D lambda / sigma`` scattered to the NLP's rows)."""
        n, n_s = self.n, self.n_s
        grad = jnp.concatenate([sigma * grad_f, jnp.zeros(n_s, x.dtype)])
        g = self.residual(x, c, row_scale)
        if self.stage is not None:
            hess_x, jac_x = self.stage.scaled(hess, sigma, row_scale)
            return Point(sigma * f, grad, g, jac_x, hess_x, f, self.violation(x, c))
        if self.m:
            jac_w = row_scale[:, None] * jac_c[self.rows]
            jac_s = row_scale[:, None] * self.slack_sign[:, None] * np.eye(self.m)[:, self.eq.size:]
            jac_x = jnp.concatenate([jac_w, jac_s], axis=1)
        else:
            jac_x = jnp.zeros((0, self.n_x), x.dtype)
        if self.riccati is not None:
            g_rows = row_scale[:, None] * hess.g_c[self.rows]
            hess_x = StageHessian(hess.a, hess.b, sigma * hess.w, sigma * hess.g_yy, g_rows)
        elif n_s:
            hess_x = jnp.zeros((self.n_x, self.n_x), x.dtype).at[:n, :n].set(sigma * hess)
        else:
            hess_x = sigma * hess
        return Point(sigma * f, grad, g, jac_x, hess_x, f, self.violation(x, c))

    def multipliers(self, lam: jax.Array, sigma: jax.Array, row_scale: jax.Array) -> jax.Array:
        """The NLP's multipliers (its row order, unscaled objective) of the solver's ``lam``."""
        if not self.m:
            return jnp.zeros(0, lam.dtype)
        return jnp.zeros(self.m, lam.dtype).at[self.rows].set(row_scale * lam / sigma)
