r"""One iteration of Algorithm 2 as one jit-compiled program: plan on the model, imitate the expert, update theta.

With ``tr`` the learned leaves (the model's trainable parameters and any learned cost weights) and ``D(tr)`` the
model NLP's data, the plan ``z`` is K planner steps from a warm state (unrolled) or a solve to tolerance (implicit),
and ``tr <- tr + optax_update(d loss(z, D(tr)) / d tr)`` (README.md in this folder, "One iteration"). Every input is
an array (the reset flag and the loss's weights too), so the program is traced once per (model, NLP, configuration,
shapes); ``TRACES`` counts the traces.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from ..data import ProblemData
from ..nlp import NLP
from ..solvers.adjoint import Implicit
from ..solvers.extragradient import optax_promotion
from ..solvers.interior_point import InteriorPoint
from .config import E2EConfig
from .planner import UnrolledPlanner, make_implicit_solve

__all__ = ["Carry", "MIN_STEP_SCALE", "Metrics", "Program", "TRACES", "USED", "loss_weights"]

TRACES = {"iteration": 0}
# How each iteration got its gradient (Metrics.used).
USED = ("unrolled", "implicit", "fallback_unrolled", "skipped", "backtracked")
SKIPPED, BACKTRACKED = USED.index("skipped"), USED.index("backtracked")
# on_failure="backtrack": a step whose model the planner cannot solve is taken again this much shorter; every
# converged solve lets the next step grow by RECOVER (slower than the cut, so the failed length is not retried at
# once), up to the optimiser's own step.
BACKTRACK, RECOVER = 0.5, 1.25
# Below this fraction of the optimiser's step the run stops: every nearby model is one the planner cannot solve.
MIN_STEP_SCALE = 2.0**-20


class Carry(NamedTuple):
    """What one iteration hands the next, one type whatever the adjoint (a field the adjoint does not use is None)."""

    plan: Any = None  # unrolled: the planner's warm state
    z: Any = None  # implicit: where the next solve starts
    warm: Any = None  # implicit with the interior point: its primal-dual warm start
    good: Any = None  # implicit: the last (train, opt_state) whose plan converged
    has_good: Any = None  # ... and whether there is one
    scale: Any = None  # the fraction of the optimiser's step the next update takes (1 unless backtracking cut it)


class Metrics(NamedTuple):
    """What one iteration reports (host arrays after ``device_get``)."""

    loss: jax.Array  # the imitation loss at the plan of this iteration's parameters (before the update)
    grad_norm: jax.Array
    kkt: jax.Array  # the planner's KKT residual (unrolled) or the solve's violation (implicit)
    converged: jax.Array  # implicit: the solve converged; unrolled: True
    used: jax.Array  # index into USED
    iterations: jax.Array  # implicit: the solve's iterations; unrolled: K
    step_scale: jax.Array  # the fraction of the optimiser's step taken (below 1 after backtracking)
    finite: jax.Array
    controls: jax.Array  # the plan on the model's grid (N + 1, m) and its states under the model (N + 1, n)
    states: jax.Array


class Program:
    """The compiled iteration and the pieces around it, for one model, NLP (the transcription of
    ``model.as_system(theta)``), configuration and expert (on the NLP's grid)."""

    def __init__(self, model: Any, nlp: NLP, config: E2EConfig, expert_controls: Any, expert_states: Any):
        self.model, self.nlp, self.config = model, nlp, config
        self.planner = UnrolledPlanner(nlp, config.planner)
        self.implicit = isinstance(config.adjoint, Implicit)
        self.isolve = make_implicit_solve(nlp, config.implicit_solver) if self.implicit else None
        # The interior point restarts from the last solve's point *and* multipliers (a primal-dual warm start): from
        # the point alone it re-centres from mu = 0.1, often slower than from the initial guess.
        ip = self.implicit and isinstance(config.implicit_solver, InteriorPoint)
        self.cold = config.implicit_solver.cold_start(nlp) if ip else None
        opt = config.optimizer
        self.optimizer = optax.adam(opt) if isinstance(opt, float) else opt
        self.expert = (jnp.asarray(expert_controls), jnp.asarray(expert_states))
        self.iteration = jax.jit(self._iteration)

    # ---- the learned leaves and the problem data -------------------------------------------------------------

    def data(self, train: Any, frozen: Any, consts: Any) -> ProblemData:
        """``D(tr)``: ``{"spec": p[cost <- tr.cost], "model": theta(tr.model)}`` and x0, the model NLP's data."""
        theta = self.model.combine(train["model"], frozen["model"])
        return ProblemData({"spec": {**consts["spec"], **train["cost"]}, "model": theta}, consts["x0"])

    def loss(self, z: Any, data: ProblemData, weights: Any) -> tuple[jax.Array, tuple]:
        """``w_u mean ||u - u*||^2 + w_x mean ||x - x*||^2`` with ``weights = (w_u, w_x)`` (:func:`loss_weights`): an
        input, so the three modes share one compiled program; a term of weight 0 is left out, not multiplied."""
        _, states, controls = self.nlp.unravel(z, data)
        u_star, x_star = self.expert
        on_u = jnp.mean(jnp.sum((controls - u_star) ** 2, axis=-1))
        on_x = jnp.mean(jnp.sum((states - x_star) ** 2, axis=-1))
        w_u, w_x = weights[0], weights[1]
        value = jnp.where(w_u > 0, w_u * on_u, 0.0) + jnp.where(w_x > 0, w_x * on_x, 0.0)
        return value, (controls, states)

    def init_opt(self, train: Any) -> Any:
        with optax_promotion():
            return self.optimizer.init(train)

    def init_carry(self, train: Any, frozen: Any, consts: Any) -> Carry:
        """The planner's starting state (unrolled), or (implicit) the starting point with what backtracking needs:
        the last parameters and optimiser state whose plan converged, and the step's scale."""
        data = self.data(train, frozen, consts)
        one = jnp.asarray(1.0, jnp.float64)
        if self.implicit:
            z = jnp.asarray(self.nlp.initial_guess(data))
            return Carry(z=z, warm=None if self.cold is None else self.cold(data, z),
                         good=(train, self.init_opt(train)), has_good=jnp.asarray(False), scale=one)
        return Carry(plan=self.planner.reset(data), scale=one)

    # ---- the gradients ---------------------------------------------------------------------------------------

    def _unrolled(self, train, frozen, consts, state):
        def objective(tr):
            data = self.data(tr, frozen, consts)
            new = self.planner.run(state, data, self.config.adjoint.unroll)
            value, plan = self.loss(self.planner.z(new), data, consts["loss"])
            return value, (new, plan)

        (value, (new, plan)), grad = jax.value_and_grad(objective, has_aux=True)(train)
        return value, grad, new, plan

    def _implicit(self, train, frozen, consts, z0, warm=None):
        def objective(tr):
            data = self.data(tr, frozen, consts)
            sol = self.isolve(data.params, data.x0, z0 if warm is None else warm)
            value, plan = self.loss(sol.z, data, consts["loss"])
            return value, (sol, plan)

        (value, (sol, plan)), grad = jax.value_and_grad(objective, has_aux=True)(train)
        finite = jnp.isfinite(value) & _all_finite(grad)
        ok = sol.converged & finite
        z_next = jnp.where(jnp.all(jnp.isfinite(sol.z)), sol.z, z0)
        if self.config.on_failure == "backtrack":  # the next solve starts where the last converged one ended
            return value, grad, jnp.where(ok, sol.z, z0), plan, sol, ok, jnp.where(ok, 1, BACKTRACKED)
        if self.config.on_failure == "skip":
            return value, grad, z_next, plan, sol, ok, jnp.where(ok, 1, SKIPPED)

        def fallback(_):
            data = jax.lax.stop_gradient(self.data(train, frozen, consts))
            v, g, new, p = self._unrolled(train, frozen, consts, self.planner.reset(data, z_next))
            return v, g, self.planner.z(new), p

        value, grad, z_next, plan = jax.lax.cond(ok, lambda _: (value, grad, z_next, plan), fallback, None)
        return value, grad, z_next, plan, sol, jnp.asarray(True), jnp.where(ok, 1, 2)

    # ---- the iteration ---------------------------------------------------------------------------------------

    def _iteration(self, train, opt_state, carry, frozen, consts, reset):
        TRACES["iteration"] += 1
        scale = jnp.asarray(1.0, jnp.float64)
        data = jax.lax.stop_gradient(self.data(train, frozen, consts))
        if self.implicit:
            start = jnp.asarray(self.nlp.initial_guess(data))
            z0 = jnp.where(reset, start, carry.z)
            warm = None
            if self.cold is not None:  # a cond, not a select: the cold start costs a model evaluation
                warm = jax.lax.cond(reset, lambda: self.cold(data, start), lambda: carry.warm)
            value, grad, z_next, plan, sol, ok, used = self._implicit(train, frozen, consts, z0, warm)
            kkt, converged, iterations, scale = sol.violation, sol.converged, sol.iterations, carry.scale
        else:
            state = jax.lax.cond(reset, lambda: self.planner.reset(data), lambda: carry.plan)
            value, grad, state, plan = self._unrolled(train, frozen, consts, state)
            carry = carry._replace(plan=state)
            kkt, converged, ok, used = self.planner.kkt(state), jnp.asarray(True), jnp.asarray(True), 0
            iterations = jnp.asarray(self.config.adjoint.unroll)
        # A gradient the implicit mode refused (a solve that did not converge) is a skip, not a failure: the run
        # stops only at a non-finite loss, or a non-finite gradient that would have been used.
        finite = jnp.isfinite(value) & (~ok | _all_finite(grad))
        apply = ok & finite & _all_finite(grad)
        with optax_promotion():
            updates, new_opt = self.optimizer.update(grad, opt_state, train)
        new_train = optax.apply_updates(train, jax.tree.map(lambda u: (scale * u).astype(u.dtype), updates))
        keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(apply, a, b), new, old)  # noqa: E731
        norm = optax.tree.norm(grad)
        next_train, next_opt = keep(new_train, train), keep(new_opt, opt_state)
        if self.implicit:
            back = (used == BACKTRACKED) & carry.has_good  # a failed solve with somewhere to go back to
            finite = finite | back  # a non-finite plan there is what backtracking is for, not a reason to stop
            used = jnp.where(used == BACKTRACKED, jnp.where(back, BACKTRACKED, SKIPPED), used)
            pick = lambda when, a, b: jax.tree.map(lambda x, y: jnp.where(when, x, y), a, b)  # noqa: E731
            next_train, next_opt = pick(back, carry.good, (next_train, next_opt))
            # The next warm start: this solve's end if it converged, else the start it was given.
            warm_next = None if warm is None else pick(sol.converged, sol.warm, warm)
            carry = Carry(z=z_next, warm=warm_next, good=pick(apply, (train, opt_state), carry.good),
                          has_good=carry.has_good | apply,
                          scale=jnp.where(apply, jnp.minimum(1.0, RECOVER * scale), jnp.where(back, BACKTRACK * scale,
                                                                                              scale)))
        metrics = Metrics(value, norm, kkt, converged, jnp.where(apply | (used == BACKTRACKED), used, SKIPPED),
                          iterations, scale, finite, *plan)
        return next_train, next_opt, carry, metrics


def loss_weights(loss: str) -> jax.Array:
    """``(w_u, w_x)`` of an ``E2EConfig.loss``: the controls' and the states' terms."""
    return jnp.asarray([float(loss in ("controls", "both")), float(loss in ("states", "both"))], jnp.float64)


def _all_finite(tree: Any) -> jax.Array:
    leaves = jax.tree.leaves(tree)
    return jnp.all(jnp.asarray([jnp.all(jnp.isfinite(a)) for a in leaves])) if leaves else jnp.asarray(True)
