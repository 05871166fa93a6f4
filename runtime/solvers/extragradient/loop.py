r"""The pure solve: Korpelevich's extragradient iteration with optax step rules, as one ``lax.while_loop``.

Writing ``v = (p, lambda, mu)`` and ``G(v) = (grad_p L, -grad_lambda L, -grad_mu L)`` (see :mod:`.lagrangian`), one
iteration is

.. math::
    v_{k+1/2} = \Pi\big(v_k + T(G(v_k))\big), \qquad v_{k+1} = \Pi\big(v_k + T(G(v_{k+1/2}))\big)

with the optax step rules ``T`` (primal and dual) in place of a fixed step: the gradient is evaluated at the
extrapolated point but the step is taken from the original point, which damps the rotation that makes plain
descent-ascent cycle around saddle points. ``Pi`` projects ``mu`` onto ``mu >= 0`` and ``p`` onto its box (see
:mod:`.box`). The optimiser states are threaded through both half-steps (restarting the look-ahead from the previous
state measured worse). The loop stops when the KKT residual is at most ``tol``, at ``max_iter``, or at a non-finite
point. Measurements: docs/notes/extragradient-tuning.md.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from ..base import ScaledProblem, split_constraints
from .box import make_box
from .lagrangian import Lagrangian, Point
from .penalty import PenaltySchedule
from .scaling import make_scales

if TYPE_CHECKING:
    from .solver import Extragradient

__all__ = ["ExtragradientSolution", "make_solve_fn", "optax_promotion", "step_rules"]


class ExtragradientSolution(NamedTuple):
    """What the jit-compiled ``solve_fn(data, z0)`` returns (every field gains a batch axis under ``vmap``).

    Attributes:
        z: the final iterate (n_variables,), in the original variables.
        multipliers: constraint multipliers (n_constraints,) in IPOPT's convention, ``dF/dz + (dc/dz)^T y`` = bound
            terms: the augmented-Lagrangian estimates ``lambda + rho h`` and ``max(0, mu + rho g)`` (signed).
        iterations: extragradient iterations taken (each costs two gradient evaluations).
        converged: KKT residual and constraint violation both at most ``tol`` (and everything finite).
        violation: the largest constraint or bound violation at ``z``.
    """

    z: jax.Array
    multipliers: jax.Array
    iterations: jax.Array
    converged: jax.Array
    violation: jax.Array


def optax_promotion():
    """Standard dtype promotion for optax's own arithmetic only.

    NOTE: optax mixes Python floats with its int32 step counter (``b1 ** count`` in adam's bias correction), which
    ``jax_numpy_dtype_promotion="strict"`` (our test setting) rejects. The context applies while tracing the step
    rules only; the NLP's functions stay under whatever promotion the caller set.
    """
    return jax.numpy_dtype_promotion("standard")


def step_rules(step: Any, dual_step: Any) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
    """The primal and dual rules: given transformations as they are, learning rates as ``optax.amsgrad(step)`` and
    plain ascent ``optax.sgd(dual_step)``."""
    primal = step if isinstance(step, optax.GradientTransformation) else optax.amsgrad(float(step))
    dual = dual_step if isinstance(dual_step, optax.GradientTransformation) else optax.sgd(float(dual_step))
    return primal, dual


def make_solve_fn(problem: ScaledProblem, solver: Extragradient) -> Callable[[Any, Any], ExtragradientSolution]:
    """Build the pure ``(data, z0) -> ExtragradientSolution`` for one scaled problem. All indices are static."""
    m = problem.n_constraints
    scale = jnp.asarray(problem.scale)
    eq_idx, up_idx, lo_idx = split_constraints(problem.c_lower, problem.c_upper)
    tol, max_iter = float(solver.tol), int(solver.max_iter)
    penalty = PenaltySchedule(float(solver.penalty), float(solver.penalty_growth), float(solver.penalty_max), tol)
    box = make_box(problem.w_lower, problem.w_upper, solver.bounds)
    lagrangian = Lagrangian(problem.objective, problem.constraints, m, eq_idx, up_idx, lo_idx, problem.c_lower,
                            problem.c_upper, box, penalty)
    primal, dual = step_rules(solver.step, solver.dual_step)

    def project_duals(duals):
        lam, mu_u, mu_l = duals
        return lam, jnp.maximum(mu_u, 0.0), jnp.maximum(mu_l, 0.0)

    def step(origin_p, origin_duals, state_p, state_d, at: Point, d):
        """One projected optax step from ``origin`` along the gradients ``at`` a (possibly other) point.

        The primal rule acts on ``v = p / d``: it sees the gradient ``d * grad_p`` and its step ``dv`` is ``d * dv`` in
        ``p``. For AMSGrad, whose steps are about ``lr`` whatever the gradient's size, that makes a variable's steps
        proportional to its magnitude ``d``.
        """
        with optax_promotion():
            update_v, state_p = primal.update(at.grad_p * d, state_p, origin_p / d)
            update_d, state_d = dual.update(at.grad_duals, state_d, origin_duals)
        p = box.project(origin_p + d * update_v)
        duals = project_duals(jax.tree.map(jnp.add, origin_duals, update_d))
        return p, duals, state_p, state_d

    def solve(data, z0) -> ExtragradientSolution:
        z0 = jnp.asarray(z0)
        p0 = box.start(z0 / scale)
        duals0 = (jnp.zeros(eq_idx.size, z0.dtype), jnp.zeros(up_idx.size, z0.dtype), jnp.zeros(lo_idx.size, z0.dtype))
        with optax_promotion():
            states0 = primal.init(p0), dual.init(duals0)
        rho_init = penalty.initial(z0.dtype)
        scales = make_scales(problem.objective, problem.constraints, box.to_w(p0), data, z0.dtype, boxed=box.boxed,
                             m=m, from_guess=solver.scaling == "guess", scale_objective=bool(solver.scale_objective))
        d = scales.column
        point0 = lagrangian.evaluate(p0, duals0, rho_init, data, scales)
        init = (jnp.zeros((), jnp.int32), p0, duals0, *states0, point0, rho_init, point0.violation)

        def cond(carry):
            k, *_, point, _, _ = carry
            # A non-finite point has kkt = +inf: stop there rather than iterate on NaNs.
            return (k < max_iter) & (point.kkt > tol) & jnp.isfinite(point.kkt)

        def body(carry):
            k, p, duals, state_p, state_d, point, rho, v_ref = carry
            # NOTE: the optimiser states are threaded through both half-steps; restarting the second from the old
            # state measured worse (docs/notes/extragradient-tuning.md).
            # Look ahead from (p, duals) with the gradient there ...
            p_half, duals_half, state_p, state_d = step(p, duals, state_p, state_d, point, d)
            # ... and step from (p, duals) again with the gradient at the look-ahead point.
            point_half = lagrangian.evaluate(p_half, duals_half, rho, data, scales)
            p, duals, state_p, state_d = step(p, duals, state_p, state_d, point_half, d)
            point = lagrangian.evaluate(p, duals, rho, data, scales)
            rho, v_ref = penalty.update(k, rho, v_ref, point.violation)
            return k + 1, p, duals, state_p, state_d, point, rho, v_ref

        k, p, _, _, _, point, _, _ = jax.lax.while_loop(cond, body, init)
        return ExtragradientSolution(
            z=box.to_w(p) * scale,
            multipliers=point.multipliers / scales.sigma,  # back to the unscaled objective's multipliers
            iterations=k,
            converged=point.kkt <= tol,
            violation=point.violation,
        )

    return solve
