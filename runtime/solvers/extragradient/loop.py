r"""The iteration: Korpelevich's extragradient step with optax step rules (``Extragradient``'s docstring has the
mathematics), as a stepper (:class:`ExtragradientStepper`) whose ``lax.while_loop`` is the pure solve. ``Pi`` projects
``mu`` onto ``mu >= 0`` and ``p`` onto its box (:mod:`.box`). The loop stops when the KKT residual is at most ``tol``,
at ``max_iter``, or at a non-finite point.

The same stepper is the end-to-end learner's unrolled planner (a ``lax.scan`` of :meth:`ExtragradientStepper.iterate`,
:mod:`myriad.runtime.e2e.planner`), so a planner step is a solver iteration by construction, not by copy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from ..base import ScaledProblem, split_constraints
from ..stepper import Stepper
from .box import make_box
from .lagrangian import Lagrangian, Point
from .penalty import PenaltySchedule
from .scaling import Scales, make_scales

if TYPE_CHECKING:
    from .solver import Extragradient

__all__ = ["ExtragradientSolution", "ExtragradientState", "ExtragradientStepper", "optax_promotion", "step_rules"]


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
    """Standard dtype promotion while tracing the step rules only: optax mixes Python floats with its int32 step
    counter (``b1 ** count`` in adam's bias correction), which ``jax_numpy_dtype_promotion="strict"`` (our test
    setting) rejects; the NLP's functions stay under whatever promotion the caller set."""
    return jax.numpy_dtype_promotion("standard")


def step_rules(step: Any, dual_step: Any) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
    """The primal and dual rules: given transformations as they are, learning rates as ``optax.amsgrad(step)`` and
    plain ascent ``optax.sgd(dual_step)``."""
    primal = step if isinstance(step, optax.GradientTransformation) else optax.amsgrad(float(step))
    dual = dual_step if isinstance(dual_step, optax.GradientTransformation) else optax.sgd(float(dual_step))
    return primal, dual


class ExtragradientState(NamedTuple):
    """The whole solver state between iterations (warm-starting from it continues the solve): the primal parameters
    ``p`` (``w = box.to_w(p)``), ``duals = (lambda, mu_u, mu_l)``, their optax states, the penalty ``rho`` and the
    violation ``v_ref`` at its last check, ``k`` iterations, the scales measured at :meth:`begin`, and the
    Lagrangian's derivatives at ``(p, duals)``."""

    p: jax.Array
    duals: tuple
    state_p: Any
    state_d: Any
    rho: jax.Array
    v_ref: jax.Array
    k: jax.Array
    scales: Scales
    point: Point


class ExtragradientStepper:
    """The extragradient solve of one scaled problem and configuration, its iteration apart (built once per pair;
    nothing jitted, all sizes static): a :class:`~..stepper.Stepper` (:attr:`stepper`), and :meth:`iterate`, one
    iteration whatever the state (the unrolled planner runs past convergence), whose ``while_loop`` is :meth:`solve`.
    """

    def __init__(self, problem: ScaledProblem, solver: Extragradient):
        m = problem.n_constraints
        self.problem, self.m = problem, m
        self.scale = jnp.asarray(problem.scale)
        eq_idx, up_idx, lo_idx = split_constraints(problem.c_lower, problem.c_upper)
        self.sizes = (eq_idx.size, up_idx.size, lo_idx.size)
        self.tol, self.max_iter = float(solver.tol), int(solver.max_iter)
        self.from_guess, self.scale_objective = solver.scaling == "guess", bool(solver.scale_objective)
        self.penalty = PenaltySchedule(float(solver.penalty), float(solver.penalty_growth), float(solver.penalty_max),
                                       self.tol)
        self.box = make_box(problem.w_lower, problem.w_upper, solver.bounds)
        self.lagrangian = Lagrangian(problem.objective, problem.constraints, m, eq_idx, up_idx, lo_idx,
                                     problem.c_lower, problem.c_upper, self.box, self.penalty)
        self.primal, self.dual = step_rules(solver.step, solver.dual_step)
        self.stepper = Stepper(self.begin, self.step, self.running, self.end)
        # NOTE: the loop steps with `iterate`, not `step`: it never steps a stopped state, and the select in `step`
        # changed XLA's fusion of the loop body and the last bits of the iterates (measured on Van der Pol).
        self._loop = Stepper(self.begin, self.iterate, self.running, self.end)

    def begin(self, data: Any, z0: Any) -> ExtragradientState:
        """The state at ``z0``: duals 0, fresh optimiser states, the scales measured there."""
        z0 = jnp.asarray(z0)
        box = self.box
        p0 = box.start(z0 / self.scale)
        duals0 = tuple(jnp.zeros(size, z0.dtype) for size in self.sizes)
        with optax_promotion():
            state_p, state_d = self.primal.init(p0), self.dual.init(duals0)
        rho = self.penalty.initial(z0.dtype)
        scales = make_scales(self.problem.objective, self.problem.constraints, box.to_w(p0), data, z0.dtype,
                             boxed=box.boxed, m=self.m, from_guess=self.from_guess,
                             scale_objective=self.scale_objective)
        point = self.lagrangian.evaluate(p0, duals0, rho, data, scales)
        return ExtragradientState(p0, duals0, state_p, state_d, rho, point.violation, jnp.zeros((), jnp.int32),
                                  scales, point)

    def _project(self, origin_p, origin_duals, state_p, state_d, at: Point, d):
        """One projected optax step from ``origin`` along the gradients ``at`` a (possibly other) point.

        The primal rule acts on ``v = p / d``: it sees the gradient ``d * grad_p`` and its step ``dv`` is ``d * dv`` in
        ``p``. For AMSGrad, whose steps are about ``lr`` whatever the gradient's size, that makes a variable's steps
        proportional to its magnitude ``d``.
        """
        with optax_promotion():
            update_v, state_p = self.primal.update(at.grad_p * d, state_p, origin_p / d)
            update_d, state_d = self.dual.update(at.grad_duals, state_d, origin_duals)
        p = self.box.project(origin_p + d * update_v)
        lam, mu_u, mu_l = jax.tree.map(jnp.add, origin_duals, update_d)
        return p, (lam, jnp.maximum(mu_u, 0.0), jnp.maximum(mu_l, 0.0)), state_p, state_d

    def iterate(self, data: Any, st: ExtragradientState) -> ExtragradientState:
        """One extragradient iteration from ``st``, whether or not it has stopped."""
        scales, rho = st.scales, st.rho
        d = scales.column
        # NOTE: the optimiser states are threaded through both half-steps; restarting the second from the old
        # state measured worse (docs/notes/extragradient-tuning.md).
        # Look ahead from (p, duals) with the gradient there ...
        p_half, duals_half, state_p, state_d = self._project(st.p, st.duals, st.state_p, st.state_d, st.point, d)
        # ... and step from (p, duals) again with the gradient at the look-ahead point.
        point_half = self.lagrangian.evaluate(p_half, duals_half, rho, data, scales)
        p, duals, state_p, state_d = self._project(st.p, st.duals, state_p, state_d, point_half, d)
        point = self.lagrangian.evaluate(p, duals, rho, data, scales)
        rho, v_ref = self.penalty.update(st.k, rho, st.v_ref, point.violation)
        return ExtragradientState(p, duals, state_p, state_d, rho, v_ref, st.k + 1, scales, point)

    def step(self, data: Any, st: ExtragradientState) -> ExtragradientState:
        """:meth:`iterate` while :meth:`running`; a stopped state stays as it is (the :class:`Stepper` contract, which
        a batch queue relies on)."""
        go = self.running(st)
        return jax.tree.map(lambda new, old: jnp.where(go, new, old), self.iterate(data, st), st)

    def running(self, st: ExtragradientState) -> jax.Array:
        # A non-finite point has kkt = +inf: stop there rather than iterate on NaNs.
        kkt = st.point.kkt
        return (st.k < self.max_iter) & (kkt > self.tol) & jnp.isfinite(kkt)

    def end(self, data: Any, st: ExtragradientState) -> ExtragradientSolution:
        point = st.point
        return ExtragradientSolution(
            z=self.z(st),
            multipliers=point.multipliers / st.scales.sigma,  # back to the unscaled objective's multipliers
            iterations=st.k,
            converged=point.kkt <= self.tol,
            violation=point.violation,
        )

    def solve(self, data: Any, z0: Any) -> ExtragradientSolution:
        """The pure solve ``(data, z0) -> ExtragradientSolution``: one ``lax.while_loop`` of :meth:`iterate`."""
        return self._loop.solve(data, z0)

    def refresh(self, data: Any, st: ExtragradientState) -> ExtragradientState:
        """``st`` with its point re-evaluated for ``data`` (a warm state carried over from other data)."""
        return st._replace(point=self.lagrangian.evaluate(st.p, st.duals, st.rho, data, st.scales))

    def z(self, st: ExtragradientState) -> jax.Array:
        """The iterate in the NLP's own variables."""
        return self.box.to_w(st.p) * self.scale
