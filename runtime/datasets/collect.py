"""Episodes of a policy in a system's environment: the demonstrations a dataset holds (README.md in this folder).

    eps = collect("van_der_pol", policy="optimal", episodes=20, seed=0, perturb=Perturbation(start=0.1, params=0.05))
    eps.observations   # (E, T + 1, n + 1)   eps.actions (E, T, m), in the env's action units
    eps.returns        # (E,): each the sum of the episode's rewards, -J of its rollout
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..data import ProblemData
from ..loader import load
from ..rl.env import Env, EnvOptions
from ..system import System
from .policies import POLICIES, PolicySettings, plan_actions

__all__ = ["Perturbation", "Episodes", "collect", "collection_env", "options_record", "episode_data"]


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """How the episodes' start states and parameters differ, drawn from the seed (README.md: perturbations).

    Attributes:
        start: each start state x0 + start * s * U(-1, 1) per state (s its nominal scale), clipped to the state
            bounds: the environment's own ``start_noise``, drawn by its ``reset`` (0: the spec's x0).
        params: each uncertain parameter (the spec's learnable ones, else all; never a structural one) times
            1 + params * U(-1, 1), drawn per episode (0: the spec's values).
    """

    start: float = 0.0
    params: float = 0.0

    def __post_init__(self):
        for name in ("start", "params"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value < np.inf) or isinstance(value, bool):
                raise ValueError(f"Perturbation: {name} must be a finite number >= 0, got {value!r}")
        if self.params >= 1.0:
            raise ValueError(f"Perturbation: params must be below 1 (a parameter keeps its sign), got {self.params}")


@dataclasses.dataclass(frozen=True, eq=False)
class Episodes:
    """E episodes of T steps (T = the env's ``max_steps`` or ``steps``), numpy float64 / bool arrays.

    Attributes:
        observations: (E, T + 1, n + 1): ``[x_k, T - t_k]`` at every node, the last one where the episode ended.
        actions: (E, T, m): what the policy played, in the env's action units ([-1, 1] when normalised).
        rewards: (E, T): the env's rewards (minus each step's cost).
        terminations: (E, T): True on the step that reaches the horizon.
        truncations: (E, T): True on the step that reaches ``max_steps`` first.
        states: (E, T + 1, n): the system's states.
        returns: (E,): the sums of the rewards.
        params: each parameter's (E,) values (the episodes' true parameters).
        info: the policy, its settings, the seed, the perturbation, the env's options and the system's identity.
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    states: np.ndarray
    returns: np.ndarray
    params: dict[str, np.ndarray]
    info: dict[str, Any]

    def __len__(self) -> int:
        return int(self.returns.shape[0])


def options_record(options: EnvOptions) -> dict[str, Any]:
    """The env's options as plain data (the integrator by its registry name): ``EnvOptions(**record)`` and
    ``gymnasium.make(id, **record)`` rebuild them."""
    record = dataclasses.asdict(options)
    record["integrator"] = options.integrator.label
    return record


def collection_env(system: System, options: EnvOptions | None, perturb: Perturbation) -> Env:
    """The env the episodes are recorded in: ``options`` with ``start_noise = perturb.start``. A start noise in
    ``options`` itself is refused (the perturbation is its one place, so it is recorded once)."""
    options = EnvOptions() if options is None else options
    if options.start_noise:
        raise ValueError("collect: set the start perturbation with perturb=Perturbation(start=...), not "
                         "EnvOptions(start_noise=...)")
    return Env(system, dataclasses.replace(options, start_noise=float(perturb.start)))


def _uncertain(system: System) -> list[str]:
    """The parameters a perturbation changes: the learnable ones, else all, never a structural one (those set x0,
    bounds, final values or the horizon); the same set as ``rl.mpc.mismatched_params``."""
    return [n for n in (system.learnable or system.param_names) if n not in system.structural_params]


def episode_data(env: Env, episodes: int, seed: int, perturb: Perturbation) -> ProblemData:
    """The episodes' data, batched (leading axis E): parameters scaled by the perturbation and the start states the
    env's ``reset`` draws with its start noise. Episode e's key is ``fold_in(fold_in(PRNGKey(seed), 0), e)`` (the
    policies draw from ``fold_in(PRNGKey(seed), 1)``), the parameters' draws ``numpy.random.default_rng(seed)``'s:
    the same seed gives the same episodes, whatever the policy."""
    system = env.system
    nominal = env.default_params()
    rng = np.random.default_rng(seed)
    params = {k: np.repeat(np.asarray(v, np.float64)[None], episodes, axis=0) for k, v in nominal.params.items()}
    for name in _uncertain(system):
        factor = 1.0 + perturb.params * rng.uniform(-1.0, 1.0, size=episodes)
        params[name] = params[name] * factor.reshape((episodes,) + (1,) * (params[name].ndim - 1))
    root = jax.random.fold_in(jax.random.PRNGKey(seed), 0)
    keys = jax.vmap(lambda e: jax.random.fold_in(root, e))(jnp.arange(episodes))
    batch = ProblemData({k: jnp.asarray(v) for k, v in params.items()},
                        jnp.broadcast_to(jnp.asarray(nominal.x0), (episodes, system.n_states)))
    x0 = jax.vmap(lambda key, d: env.reset(key, d)[1].x)(keys, batch)
    return ProblemData(batch.params, x0)


@functools.partial(jax.jit, static_argnums=0)
def _rollouts(env: Env, actions: Any, data: ProblemData):
    """The episodes of (E, T, m) actions from the data's start states (no reset noise: x0 is drawn already)."""

    def one(acts, d):
        obs0, state0 = env.reset(jax.random.PRNGKey(0), d)

        def body(state, action):
            obs, state, reward, terminated, truncated, _ = env.step_env(state, action, d)
            return state, (obs, state.x, reward, terminated, truncated)

        _, (obs, xs, rewards, term, trunc) = jax.lax.scan(body, state0, acts)
        return (jnp.concatenate([obs0[None], obs]), jnp.concatenate([state0.x[None], xs]), rewards, term, trunc)

    return jax.vmap(one)(actions, data)


def _target_name(target: Any, system: System) -> str | None:
    """What ``load`` remakes the system from: a spec file's absolute path, a name, or None for an object."""
    if isinstance(target, System):
        return None
    path = Path(os.fspath(target))
    return str(path.resolve()) if path.is_file() else os.fspath(target)


def collect(target: System | str, policy: str = "optimal", episodes: int = 10, seed: int = 0,
            options: EnvOptions | None = None, perturb: Perturbation | None = None,
            settings: PolicySettings | None = None) -> Episodes:
    """``episodes`` episodes of ``policy`` in the environment of ``target`` (a system, a shipped name or a spec path).

    Args:
        policy: ``"optimal"``, ``"noisy"``, ``"mpc"`` or ``"random"`` (README.md in this folder: policies).
        seed: every draw's (starts, parameters, action noise, random actions): the same seed, the same episodes.
        options: the env's :class:`~myriad.runtime.rl.env.EnvOptions` (default: the Gymnasium id's, actions in
            [-1, 1]); its ``start_noise`` must be 0 (``perturb.start`` sets it).
        perturb: the start-state and parameter perturbations (default none: every episode the spec's problem).
        settings: the policies' settings (noise level, MPC re-planning; default :class:`PolicySettings`).
    """
    if policy not in POLICIES:
        raise ValueError(f"collect: unknown policy {policy!r}; one of {', '.join(POLICIES)}")
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"collect: episodes must be a positive int, got {episodes!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"collect: seed must be a non-negative int, got {seed!r}")
    system = load(target) if not isinstance(target, System) else target
    perturb = Perturbation() if perturb is None else perturb
    settings = PolicySettings() if settings is None else settings
    env = collection_env(system, options, perturb)
    data = episode_data(env, int(episodes), int(seed), perturb)
    played = Env(system, dataclasses.replace(env.options, start_noise=0.0))  # x0 drawn: the rollouts replay it
    actions, policy_info = plan_actions(played, policy, data, int(seed), settings)
    obs, states, rewards, term, trunc = jax.device_get(_rollouts(played, jnp.asarray(actions), data))
    rewards = np.asarray(rewards, np.float64)
    info = {"policy": policy, "settings": dataclasses.asdict(settings), "seed": int(seed), "episodes": int(episodes),
            "perturb": dataclasses.asdict(perturb), "options": options_record(env.options), "system": system.name,
            "spec_sha256": system.spec_sha256, "target": _target_name(target, system), **policy_info}
    return Episodes(observations=np.asarray(obs, np.float64), actions=np.asarray(actions, np.float64),
                    rewards=rewards, terminations=np.asarray(term, bool), truncations=np.asarray(trunc, bool),
                    states=np.asarray(states, np.float64), returns=rewards.sum(axis=1),
                    params={k: np.asarray(v, np.float64) for k, v in data.params.items()}, info=info)
