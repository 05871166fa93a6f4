"""A policy played in the environment, and its score: nominal, under parameter mismatch, under observation noise.

    ret = episode_return(env, policy, net)                             # one closed-loop episode's return
    scores = score(env, policy, net)                                   # normalised scores (runtime/rl/reference.py)

Closed loop: at step k the policy sees the observation ``[x_k, T - t_k]`` (with observation noise,
``x_k + noise * s * N(0, 1)``, s the state's nominal scale: the noise of :meth:`~myriad.runtime.rl.mpc.MPC.run`) and
its control is held over the step. Scores are ``normalized_score(system, J)`` of J = -return (0: the uniform random
policy, 100: the optimiser's open-loop controls). Under mismatch the *environment* runs with
:func:`~myriad.runtime.rl.mpc.mismatched_params` (each uncertain parameter off by +-``mismatch``, signs from the
seed) while the policy, trained on the nominal system, is unchanged; the score is still against the nominal
reference scores, so it says how much of the nominal performance survives.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..data import ProblemData
from ..rl.env import Env
from ..rl.mpc import mismatched_params
from ..rl.reference import normalized_score
from ..transcriptions.nominal_scales import state_scale
from .policy import Policy

__all__ = ["PolicyEpisode", "episode_return", "rollout", "score"]


class PolicyEpisode(NamedTuple):
    """One closed-loop episode: observations seen (N, d), controls (N, m), true states (N + 1, n), return."""

    observations: Any
    controls: Any
    states: Any
    total: Any


@eqx.filter_jit  # the env, the policy shape and the network's activation are static; arrays are traced
def rollout(env: Env, policy: Policy, net: Any, data: ProblemData, key: Any, obs_noise: Any) -> PolicyEpisode:
    """Play ``net`` for a whole episode of ``env`` from a reset with ``key`` (the env's ``start_noise``; also the
    observation noise's draws) and ``obs_noise`` (an array: one program for every level and every data)."""
    reset_key, noise_key = jax.random.split(key)
    obs, state = env.reset(reset_key, data)
    scale = jnp.append(jnp.asarray(state_scale(env.system), obs.dtype), 0.0)  # the time to go is known exactly

    def body(carry, k):
        obs, state = carry
        seen = obs + obs_noise * scale * jax.random.normal(jax.random.fold_in(noise_key, k), obs.shape, obs.dtype)
        u = policy.control(net, seen)
        obs, state, reward, _, _, _ = env.step_env(state, u, data)
        return (obs, state), (seen, u, reward, state.x)

    _, (seen, us, rewards, xs) = jax.lax.scan(body, (obs, state), jnp.arange(env.options.steps))
    return PolicyEpisode(seen, us, jnp.concatenate([state.x[None], xs]), jnp.sum(rewards))


def episode_return(env: Env, policy: Policy, net: Any, params: dict | None = None, seed: int = 0,
                   obs_noise: float = 0.0) -> float:
    """The return of one episode in ``env`` with ``params`` (default: the spec's), the draws from ``seed``."""
    data = jax.tree.map(jnp.asarray, env.default_params(params))  # one dtype per leaf: one compiled program
    key, level = jax.random.PRNGKey(seed), jnp.asarray(obs_noise, data.x0.dtype)
    return float(rollout(env, policy, net, data, key, level).total)


def score(env: Env, policy: Policy, net: Any, *, mismatch: float = 0.1, noise: float = 0.02,
          episodes: int = 3) -> dict[str, Any]:
    """The policy's normalised score and return in ``env`` (the reference env: default options, controls in their
    units), nominal, and the mean over ``episodes`` seeded episodes under ``mismatch`` and under ``noise``."""
    ret = episode_return(env, policy, net)
    mismatched = [episode_return(env, policy, net, mismatched_params(env, mismatch, s)) for s in range(episodes)]
    noisy = [episode_return(env, policy, net, seed=s, obs_noise=noise) for s in range(episodes)]
    out = {"episode_return": ret, "normalized_score": normalized_score(env.system, -ret)}
    for name, returns, level in (("mismatch", mismatched, mismatch), ("noise", noisy, noise)):
        mean = float(np.mean(returns))
        out[name] = {"level": level, "episodes": episodes, "episode_return": mean,
                     "normalized_score": normalized_score(env.system, -mean)}
    return out
