r"""The two planners of end-to-end learning, each a plan differentiable in the model's parameters: the unrolled one
(K extragradient iterations on the model's Lagrangian, as one ``lax.scan``) and the implicit one (a converged solve,
differentiated by the implicit function theorem on its KKT conditions).

The solver's own loop is a ``lax.while_loop``, which reverse mode cannot differentiate. Here the solver's iteration
itself (:meth:`Extragradient.stepper`'s ``iterate``, not a copy of it) runs a *fixed* number of steps,

.. math::
    v_{k+1/2} = \Pi\big(v_k + T(G(v_k; \theta))\big), \qquad v_{k+1} = \Pi\big(v_k + T(G(v_{k+1/2}; \theta))\big),
    \qquad k = 0, \dots, K - 1,

with ``v = (p, lambda, mu)`` and the optax step rules ``T``, so that the planned ``z_K(theta)`` is an ordinary
differentiable function of the model's parameters and of the warm start. Each step is wrapped in ``jax.checkpoint``:
reverse mode keeps only the carry of every step and recomputes one step's internals on the way back, so memory and
time grow linearly in K and no Jacobian is ever formed (the published code chained dense forward-mode Jacobians).
The carry is the whole solver state, so warm starting continues the solve where it stopped.

The default primal rule is the solver's, AMSGrad(0.1), with ``eps_root = 1e-16``: the square root of the second
moment is then never taken at an exact 0, where its derivative is infinite (a gradient component that is exactly
zero, e.g. a control that nothing depends on, would otherwise give 0 * inf = NaN in reverse mode).

The implicit rule is the solvers' one (:mod:`myriad.runtime.solvers.implicit`), reached through the solver's
``differentiable_solve``; :func:`make_implicit_solve` only takes the learner's arguments ``(params, x0, z0)``. A solve
that did not converge, or an inaccurate KKT solve (a singular KKT matrix), gives NaN cotangents, never a silent
gradient; the learner checks ``converged`` (``E2EConfig.on_failure``).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax

from ..data import ProblemData
from ..nlp import NLP
from ..solvers.extragradient import Extragradient, ExtragradientState
from ..solvers.interior_point import InteriorPoint
from ..status import Status

__all__ = ["ImplicitSolve", "PlannerState", "UnrolledPlanner", "default_planner_solver", "make_implicit_solve"]

PlannerState = ExtragradientState  # the planner's carry is the solver's state


def default_planner_solver(**options: Any) -> Extragradient:
    """The solver configuration the unrolled planner uses by default (see the module docstring for ``eps_root``)."""
    return Extragradient(step=optax.amsgrad(0.1, eps_root=1e-16), **options)


class UnrolledPlanner:
    """K differentiable extragradient steps on one NLP (of a model's ``LearnedSystem``), with the step rules, penalty,
    bounds mode and scaling of ``solver``, an :class:`Extragradient` (default :func:`default_planner_solver`; its
    ``tol`` and ``max_iter`` are unused: the number of steps is the caller's)."""

    def __init__(self, nlp: NLP, solver: Extragradient | None = None):
        solver = default_planner_solver() if solver is None else solver
        if not isinstance(solver, Extragradient):
            raise TypeError(f"UnrolledPlanner: the solver must be an Extragradient, got {type(solver).__name__}")
        self.nlp, self.solver = nlp, solver
        self.stepper = solver.stepper(nlp)

    def reset(self, data: Any, z0: Any = None) -> PlannerState:
        """A fresh state at ``z0`` (default: the transcription's initial guess for ``data``), duals 0, scales
        measured there, exactly as the solver starts. Nothing of it is differentiated (the scales are constants)."""
        data = jax.lax.stop_gradient(data)
        z0 = jnp.asarray(self.nlp.initial_guess(data) if z0 is None else z0)
        state = self.stepper.begin(data, z0)
        return state._replace(scales=jax.lax.stop_gradient(state.scales))

    def z(self, state: PlannerState) -> jax.Array:
        """The planned decision vector ``z`` of a state (in the NLP's own variables)."""
        return self.stepper.z(state)

    def kkt(self, state: PlannerState) -> jax.Array:
        """The KKT residual at the state's point (the solver's test; ``+inf`` at a non-finite point)."""
        return state.point.kkt

    def run(self, state: PlannerState, data: Any, steps: int, limit: Any = None) -> PlannerState:
        """``steps`` (static) extragradient steps from ``state`` on the problem of ``data``, differentiable in both;
        ``limit`` (may be traced): only the first ``min(limit, steps)``, so one program serves every K up to
        ``steps``."""
        iterate = self.stepper.iterate

        @jax.checkpoint
        def body(st: PlannerState, i):
            if limit is None:
                return iterate(data, st), None
            return jax.lax.cond(i < limit, lambda s: iterate(data, s), lambda s: s, st), None

        # The carried point was evaluated with the previous parameters: re-evaluate it with this data.
        state, _ = jax.lax.scan(body, self.stepper.refresh(data, state), jnp.arange(int(steps)))
        return state


class ImplicitSolve(NamedTuple):
    """A converged solve: ``z`` carries the implicit derivative; ``converged``, ``iterations`` and ``kkt`` do not."""

    z: jax.Array
    converged: jax.Array
    iterations: jax.Array
    violation: jax.Array
    warm: Any = None  # the interior point's primal-dual warm start for the next solve (None: the extragradient's)


def make_implicit_solve(nlp: NLP, solver: Extragradient | InteriorPoint | None = None
                        ) -> Callable[[Any, Any, Any], ImplicitSolve]:
    """``(params, x0, z0) -> ImplicitSolve``: ``solver``'s pure solve of ``nlp`` from ``z0``, differentiable in
    ``params`` and ``x0`` by the implicit function theorem (reverse mode); the start (the NLP's variables, or the
    interior point's primal-dual ``WarmStart``) is a warm start only and gets a zero cotangent. The default solver is
    an :class:`Extragradient` with ``tol=1e-9`` and 20,000 iterations: the implicit derivative is only as accurate as
    the solution."""
    solver = Extragradient(tol=1e-9, max_iter=20_000) if solver is None else solver
    if not isinstance(solver, (Extragradient, InteriorPoint)):
        raise TypeError(f"make_implicit_solve: expected an Extragradient or an InteriorPoint, got "
                        f"{type(solver).__name__}")
    raw = solver.differentiable_solve(nlp)

    def solve(params, x0, z0):
        out = raw(ProblemData(params, x0), jax.lax.stop_gradient(z0))
        # The extragradient says whether it converged, the interior point gives its status and a warm start.
        converged = out.converged if hasattr(out, "converged") else out.status == int(Status.CONVERGED)
        warm = getattr(out, "warm", None)
        return ImplicitSolve(out.z, converged, out.iterations, out.violation,
                             None if warm is None else jax.lax.stop_gradient(warm))

    return solve
