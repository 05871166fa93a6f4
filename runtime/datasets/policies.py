"""The policies that record demonstrations: the optimal plan, the plan with action noise, MPC, uniform random
(README.md in this folder: policies; why the optimal plan is played open loop)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..data import ProblemData
from ..rl.env import Env
from ..rl.mpc import MPC
from ..solvers import InteriorPoint

__all__ = ["POLICIES", "PolicySettings", "plan_actions", "optimal_controls"]

POLICIES = ("optimal", "noisy", "mpc", "random")


@dataclasses.dataclass(frozen=True)
class PolicySettings:
    """The policies' settings.

    Attributes:
        noise: ``noisy``: the action noise's standard deviation as a fraction of each action's range (hi - lo), added
            to the optimal plan's actions at every step, then clipped to the action bounds.
        replan_every: ``mpc``: re-plan every this many steps (``rl.mpc.MPC``'s ``replan_every``).
    """

    noise: float = 0.1
    replan_every: int = 10

    def __post_init__(self):
        if isinstance(self.noise, bool) or not isinstance(self.noise, (int, float)) or not 0.0 <= self.noise < np.inf:
            raise ValueError(f"PolicySettings: noise must be a finite number >= 0, got {self.noise!r}")
        if isinstance(self.replan_every, bool) or not isinstance(self.replan_every, int) or self.replan_every < 1:
            raise ValueError(f"PolicySettings: replan_every must be a positive int, got {self.replan_every!r}")


def _limit(env: Env) -> int:
    o = env.options
    return o.steps if o.max_steps is None else o.max_steps


def _to_actions(env: Env, controls: np.ndarray) -> np.ndarray:
    """Controls (..., m) as the env's actions: the inverse of ``Env.control``'s affine map when normalised."""
    if not env.options.normalize_actions:
        return np.asarray(controls, np.float64)
    lo, hi = env.control_bounds
    return np.clip(2.0 * (np.asarray(controls, np.float64) - lo) / (hi - lo) - 1.0, -1.0, 1.0)


def optimal_controls(env: Env, data: ProblemData) -> tuple[np.ndarray, dict[str, Any]]:
    """Each episode's optimal controls (E, N, m) for its start state and parameters, and the solves' record.

    The problem is the MPC's planning problem from step 0 (``rl.mpc``: single shooting on the env's own grid,
    zero-order hold, integrator, substeps and terminal penalty, so its objective is exactly the episode's cost
    J = -return), all episodes solved as one batch by the pure-JAX interior point from the transcriptions' default
    guess."""
    mpc = MPC(env)
    episodes = data.x0.shape[0]
    guess = jnp.broadcast_to(jnp.asarray(mpc.initial_plan()), (episodes, *mpc.initial_plan().shape))
    plan_data = ProblemData({"model": data.params, "k": jnp.zeros((episodes,), jnp.int32), "prev": guess}, data.x0)
    solver = InteriorPoint()
    results = solver.solve_batch(mpc.nlp, plan_data)
    controls = np.stack([np.reshape(r.z, guess.shape[1:]) for r in results])
    record = {"solver": repr(solver), "plan_status": [r.status.name.lower() for r in results],
              "plan_cost": [float(r.objective) for r in results],
              "plan_iterations": [int(r.iterations) for r in results]}
    return controls, record


def _mpc_controls(env: Env, data: ProblemData, seed: int, settings: PolicySettings):
    """Each episode's closed-loop MPC controls (E, N, m), its planner given the episode's true parameters."""
    host = jax.device_get(data)
    controls, failures = [], []
    for e in range(host.x0.shape[0]):
        params = {k: np.asarray(v[e]) for k, v in host.params.items()}
        ep = MPC(env, params, replan_every=settings.replan_every).run(ProblemData(params, host.x0[e]), seed=seed)
        controls.append(ep.controls)
        failures.append(ep.failures)
    return np.stack(controls), {"solver": "ipopt (rl.mpc.MPC, terminal penalty)", "replan_failures": failures}


def plan_actions(env: Env, policy: str, data: ProblemData, seed: int,
                 settings: PolicySettings) -> tuple[np.ndarray, dict[str, Any]]:
    """The (E, T, m) actions of ``policy`` in ``env``'s action units and what to record of how they were made."""
    T, episodes = _limit(env), data.x0.shape[0]
    lo, hi = env.action_bounds
    key = jax.random.fold_in(jax.random.PRNGKey(seed), 1)
    if policy == "random":
        draws = np.asarray(jax.random.uniform(key, (episodes, T, env.action_size), jnp.float64))
        return lo + draws * (hi - lo), {}
    if policy == "mpc":
        controls, record = _mpc_controls(env, data, seed, settings)
        return _to_actions(env, controls[:, :T]), record
    controls, record = optimal_controls(env, data)
    actions = _to_actions(env, controls[:, :T])
    if policy == "noisy":
        noise = np.asarray(jax.random.normal(key, actions.shape, jnp.float64))
        actions = np.clip(actions + settings.noise * (hi - lo) * noise, lo, hi)
    return actions, record
