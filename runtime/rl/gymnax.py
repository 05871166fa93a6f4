"""The functional environment in gymnax's shape: what gymnax-based trainers (rejax, PureJaxRL) train on.

:class:`~myriad.runtime.rl.env.Env` already has gymnax's signatures, but a gymnax trainer wants a
``gymnax.environments.environment.Environment``: a hashable object (gymnax jits ``step`` and ``reset`` with the env
static) with ``default_params``, gymnax's spaces, a single ``done`` flag and params that carry
``max_steps_in_episode``. :class:`GymnaxEnv` is that wrapper, adding nothing to the dynamics or the reward:
``GymnaxEnv(make_jax("van_der_pol"))`` is what ``rejax.PPO.create(env=...)`` takes (``bench/rl_baselines.py``).

Needs gymnax and flax (``pip install 'myriad-control[rl]'``, which installs rejax with them); importing this module
without them raises ``ImportError``, and nothing else in :mod:`myriad.runtime.rl` imports it.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from gymnax.environments import environment, spaces

from .env import Env

__all__ = ["GymnaxEnv", "GymnaxParams"]


@struct.dataclass
class GymnaxParams:
    """A :class:`GymnaxEnv`'s params: the env's problem data and gymnax's episode length (static)."""

    data: Any
    max_steps_in_episode: int = struct.field(pytree_node=False, default=100)


class GymnaxEnv(environment.Environment):
    """An :class:`~myriad.runtime.rl.env.Env` as a gymnax ``Environment``: ``done`` is ``terminated | truncated``
    (gymnax's ``step`` resets on it), infinite sides of the spaces are clipped to the dtype's largest value (gymnax's
    ``Box`` samples from them).

    Args:
        env: the functional environment.
        dtype: the float type of the params and the spaces (float32: rejax's running statistics are created in JAX's
            default dtype).
    """

    def __init__(self, env: Env, dtype: Any = jnp.float32):
        self.env = env
        self.dtype = jnp.dtype(dtype)

    def __hash__(self):  # gymnax jits step/reset with the environment static
        return hash((self.env, self.dtype))

    def __eq__(self, other):
        return isinstance(other, GymnaxEnv) and other.env == self.env and other.dtype == self.dtype

    @property
    def default_params(self) -> GymnaxParams:
        data = jax.tree.map(lambda a: jnp.asarray(a, self.dtype), self.env.default_params())
        return GymnaxParams(data, self.env.options.steps)

    def reset_env(self, key, params: GymnaxParams):
        return self.env.reset(key, params.data)

    def step_env(self, key, state, action, params: GymnaxParams):
        obs, state, reward, terminated, truncated, _ = self.env.step_env(state, action, params.data)
        return obs, state, reward, terminated | truncated, {}

    def action_space(self, params: GymnaxParams | None = None) -> spaces.Box:
        if self.env.options.normalize_actions:
            return spaces.Box(-1.0, 1.0, (self.env.action_size,), self.dtype)
        return spaces.Box(*self._finite(self.env.action_bounds), (self.env.action_size,), self.dtype)

    def observation_space(self, params: GymnaxParams | None = None) -> spaces.Box:
        return spaces.Box(*self._finite(self.env.observation_bounds), (self.env.observation_size,), self.dtype)

    def _finite(self, bounds: tuple[np.ndarray, np.ndarray]) -> tuple[Any, Any]:
        big = float(np.finfo(self.dtype).max)
        return tuple(jnp.asarray(np.clip(b, -big, big), self.dtype) for b in bounds)
