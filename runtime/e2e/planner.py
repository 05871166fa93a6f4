r"""The unrolled planner: a fixed number K of extragradient steps on the model's Lagrangian, as one ``lax.scan``.

The solver's own loop (:mod:`myriad.runtime.solvers.extragradient.loop`) is a ``lax.while_loop``, which reverse mode
cannot differentiate. Here the same iteration, built from the same pieces (the box :mod:`~.extragradient.box`, the
augmented Lagrangian :mod:`~.extragradient.lagrangian`, the penalty schedule and the scales), runs a *fixed* number of
steps,

.. math::
    v_{k+1/2} = \Pi\big(v_k + T(G(v_k; \theta))\big), \qquad v_{k+1} = \Pi\big(v_k + T(G(v_{k+1/2}; \theta))\big),
    \qquad k = 0, \dots, K - 1,

with ``v = (p, lambda, mu)`` and the optax step rules ``T`` (their states are part of the carry), so that the planned
``z_K(theta)`` is an ordinary differentiable function of the model's parameters (through ``data.params``) and of the
warm start. Each step is wrapped in ``jax.checkpoint``: reverse mode keeps only the carry of every step and recomputes
one step's internals on the way back, so memory and time grow linearly in K and no Jacobian is ever formed (a
reverse pass is one vector-Jacobian product per step, the published code chained dense forward-mode Jacobians).

The carry (:class:`PlannerState`) is the whole solver state, so warm starting from the previous iterate continues
the solve where it stopped; :meth:`UnrolledPlanner.reset` starts afresh (duals 0, new optimiser states and new
scales measured at the start, as the solver does). From a reset and with the same configuration, K steps here
reproduce the solver's first K iterations (``tests/runtime/e2e/test_planner.py``).

The default primal rule is AMSGrad(0.1) with ``eps_root = 1e-16``: the solver's default rule, except that the square
root of the second moment is never taken at an exact 0, where its derivative is infinite (a gradient component that
is exactly zero, e.g. a control that nothing depends on, would otherwise give 0 * inf = NaN in reverse mode).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from ..nlp import NLP
from ..solvers.base import ScaledProblem, split_constraints
from ..solvers.extragradient import Extragradient
from ..solvers.extragradient.box import make_box
from ..solvers.extragradient.lagrangian import Lagrangian, Point
from ..solvers.extragradient.loop import optax_promotion, step_rules
from ..solvers.extragradient.penalty import PenaltySchedule
from ..solvers.extragradient.scaling import Scales, make_scales

__all__ = ["PlannerState", "UnrolledPlanner", "default_planner_solver"]


def default_planner_solver(**options: Any) -> Extragradient:
    """The solver configuration the unrolled planner uses by default (see the module docstring for ``eps_root``)."""
    return Extragradient(step=optax.amsgrad(0.1, eps_root=1e-16), **options)


class PlannerState(NamedTuple):
    """The whole extragradient state between steps (a pytree of arrays; the warm start of the next iteration).

    Attributes:
        p, duals: the primal parameters (``w = box.to_w(p)``, ``z = w * z_scale``) and ``(lambda, mu_u, mu_l)``.
        state_p, state_d: the primal and dual optax states.
        rho, v_ref: the penalty and the violation at its last check; k: steps taken since the last reset.
        scales: the objective, column and row scales measured at the last reset (held fixed in between).
        point: the Lagrangian's derivatives at ``(p, duals)`` for the parameters of the last step (recomputed at the
            start of every :meth:`UnrolledPlanner.run`, so new parameters are always used).
    """

    p: jax.Array
    duals: tuple
    state_p: Any
    state_d: Any
    rho: jax.Array
    v_ref: jax.Array
    k: jax.Array
    scales: Scales
    point: Point


class UnrolledPlanner:
    """K differentiable extragradient steps on one NLP (built once per NLP and solver configuration).

    Args:
        nlp: the transcribed problem (of a model's ``LearnedSystem``: its ``data.params`` hold theta).
        solver: an :class:`Extragradient` giving the step rules, penalty, bounds mode and scaling (its ``tol`` and
            ``max_iter`` are unused: the number of steps is the caller's); default :func:`default_planner_solver`.
    """

    def __init__(self, nlp: NLP, solver: Extragradient | None = None):
        solver = default_planner_solver() if solver is None else solver
        if not isinstance(solver, Extragradient):
            raise TypeError(f"UnrolledPlanner: the solver must be an Extragradient, got {type(solver).__name__}")
        problem = ScaledProblem.from_nlp(nlp)
        self.nlp, self.solver, self.problem = nlp, solver, problem
        self.m = problem.n_constraints
        self.scale = jnp.asarray(problem.scale)
        eq_idx, up_idx, lo_idx = split_constraints(problem.c_lower, problem.c_upper)
        self._sizes = (eq_idx.size, up_idx.size, lo_idx.size)
        self.penalty = PenaltySchedule(float(solver.penalty), float(solver.penalty_growth),
                                       float(solver.penalty_max), float(solver.tol))
        self.box = make_box(problem.w_lower, problem.w_upper, solver.bounds)
        self.lagrangian = Lagrangian(problem.objective, problem.constraints, self.m, eq_idx, up_idx, lo_idx,
                                     problem.c_lower, problem.c_upper, self.box, self.penalty)
        self.primal, self.dual = step_rules(solver.step, solver.dual_step)

    # ---- the state -------------------------------------------------------------------------------------------

    def reset(self, data: Any, z0: Any = None) -> PlannerState:
        """A fresh state at ``z0`` (default: the transcription's initial guess for ``data``), duals 0, scales
        measured there, exactly as the solver starts. Nothing of it is differentiated (the scales are constants)."""
        data = jax.lax.stop_gradient(data)
        z0 = jnp.asarray(self.nlp.initial_guess(data) if z0 is None else z0)
        box, solver = self.box, self.solver
        p0 = box.start(z0 / self.scale)
        duals0 = tuple(jnp.zeros(n, z0.dtype) for n in self._sizes)
        with optax_promotion():
            state_p, state_d = self.primal.init(p0), self.dual.init(duals0)
        rho = self.penalty.initial(z0.dtype)
        scales = make_scales(self.problem.objective, self.problem.constraints, box.to_w(p0), data, z0.dtype,
                             boxed=box.boxed, m=self.m, from_guess=solver.scaling == "guess",
                             scale_objective=bool(solver.scale_objective))
        scales = jax.lax.stop_gradient(scales)
        point = self.lagrangian.evaluate(p0, duals0, rho, data, scales)
        return PlannerState(p0, duals0, state_p, state_d, rho, point.violation, jnp.zeros((), jnp.int32), scales,
                            point)

    def z(self, state: PlannerState) -> jax.Array:
        """The planned decision vector ``z`` of a state (in the NLP's own variables)."""
        return self.box.to_w(state.p) * self.scale

    def kkt(self, state: PlannerState) -> jax.Array:
        """The KKT residual at the state's point (the solver's test; ``+inf`` at a non-finite point)."""
        return state.point.kkt

    # ---- the steps -------------------------------------------------------------------------------------------

    def _project_step(self, origin_p, origin_duals, state_p, state_d, at: Point, d):
        # The solver's projected optax step (loop.make_solve_fn's `step`): the primal rule acts on v = p / d.
        with optax_promotion():
            update_v, state_p = self.primal.update(at.grad_p * d, state_p, origin_p / d)
            update_d, state_d = self.dual.update(at.grad_duals, state_d, origin_duals)
        p = self.box.project(origin_p + d * update_v)
        lam, mu_u, mu_l = jax.tree.map(jnp.add, origin_duals, update_d)
        return p, (lam, jnp.maximum(mu_u, 0.0), jnp.maximum(mu_l, 0.0)), state_p, state_d

    def run(self, state: PlannerState, data: Any, steps: int, limit: Any = None) -> PlannerState:
        """``steps`` (static) extragradient steps from ``state`` on the problem of ``data``; differentiable in
        ``data`` and ``state`` by reverse and forward mode.

        ``limit`` (optional, may be traced): take only the first ``min(limit, steps)`` steps, the rest are the
        identity; one compiled program then serves every K up to ``steps`` (a sweep over K, at the cost of K =
        ``steps``)."""
        lagrangian, penalty = self.lagrangian, self.penalty
        scales = state.scales
        d = scales.column

        def step(st: PlannerState) -> PlannerState:
            p_half, duals_half, sp, sd = self._project_step(st.p, st.duals, st.state_p, st.state_d, st.point, d)
            point_half = lagrangian.evaluate(p_half, duals_half, st.rho, data, scales)
            p, duals, sp, sd = self._project_step(st.p, st.duals, sp, sd, point_half, d)
            point = lagrangian.evaluate(p, duals, st.rho, data, scales)
            rho, v_ref = penalty.update(st.k, st.rho, st.v_ref, point.violation)
            return PlannerState(p, duals, sp, sd, rho, v_ref, st.k + 1, scales, point)

        @jax.checkpoint
        def body(st: PlannerState, i):
            if limit is None:
                return step(st), None
            return jax.lax.cond(i < limit, step, lambda s: s, st), None

        # The carried point was evaluated with the previous parameters: re-evaluate it with this data.
        state = state._replace(point=lagrangian.evaluate(state.p, state.duals, state.rho, data, scales))
        state, _ = jax.lax.scan(body, state, jnp.arange(int(steps)))
        return state
