"""The imitation policy: an MLP from the env's observation to a control inside the control bounds.

    policy = Policy.of(env, width=64, depth=2)          # the env's scales and bounds; no parameters
    net = policy.init(jax.random.PRNGKey(0))          # the MLP (an equinox module: the trainable pytree)
    u = policy.control(net, obs)                      # (..., d) observations -> (..., m) controls

The observation is the env's ``[x_k, T - t_k]``: the state and the time to go, which is all an optimal policy of a
fixed-horizon problem needs (it is time-varying; README.md of ``runtime/rl``). The network sees it normalised,
``x / s`` (s the state's nominal scale) and ``2 (T - t) / T - 1``, so every input is O(1) whatever the units.

The output is squashed by tanh into the control bounds, ``u = lo + (tanh(y) + 1) (hi - lo) / 2``: the policy can never
ask for a control outside the action space, and, unlike clipping a linear output, the squash has a non-zero gradient
everywhere, so an expert that sits on a bound (bang-bang and bound-active optima are common here) pulls the output
towards it instead of leaving a clipped output with no gradient. Losses compare actions in the normalised units
``a = tanh(y)`` in [-1, 1] (:meth:`Policy.normalise` maps a control there), so controls of different units weigh alike.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..rl.env import Env
from ..transcriptions.nominal_scales import state_scale

__all__ = ["Policy"]


@dataclasses.dataclass(frozen=True, eq=False)
class Policy:
    """What maps a network's output to the env (its observation scales and control bounds) and the network's shape.

    Attributes:
        obs_scale: (d,) what each observation is divided by (the states' nominal scales, then T / 2).
        obs_shift: (d,) what is subtracted after scaling (0 for the states, 1 for the time to go).
        lo, hi: (m,) the control bounds (finite: the env's action bounds).
        width, depth: the hidden layers' width and number (tanh after each; a linear output).
    """

    obs_scale: np.ndarray
    obs_shift: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    width: int = 64
    depth: int = 2

    @classmethod
    def of(cls, env: Env, width: int = 64, depth: int = 2) -> Policy:
        """The policy shape of ``env`` (its controls must have finite bounds: ``action_bound`` where they do not)."""
        env.require_finite_controls("a policy's output cannot be squashed into them")
        if width < 1 or depth < 1:
            raise ValueError(f"Policy: width and depth must be at least 1, got {width}, {depth}")
        n = env.system.n_states
        scale = np.append(state_scale(env.system), 0.5 * float(env.system.horizon))
        shift = np.append(np.zeros(n), 1.0)
        lo, hi = env.control_bounds
        return cls(scale, shift, np.asarray(lo, np.float64), np.asarray(hi, np.float64), int(width), int(depth))

    @property
    def obs_size(self) -> int:
        return self.obs_scale.size

    @property
    def action_size(self) -> int:
        return self.lo.size

    def init(self, key: Any) -> eqx.nn.MLP:
        """A fresh network (equinox's default initialisation, float64 under x64)."""
        return eqx.nn.MLP(self.obs_size, self.action_size, self.width, self.depth, activation=jnp.tanh, key=key,
                          dtype=jnp.float64)

    def action(self, net: eqx.nn.MLP, obs: Any) -> Any:
        """The normalised action tanh(y) in (-1, 1), (..., m), of observations (..., d)."""
        obs = jnp.asarray(obs)
        z = obs / jnp.asarray(self.obs_scale, obs.dtype) - jnp.asarray(self.obs_shift, obs.dtype)
        flat = jnp.reshape(z, (-1, self.obs_size))
        out = jax.vmap(net)(flat)
        return jnp.tanh(jnp.reshape(out, (*obs.shape[:-1], self.action_size)))

    def control(self, net: eqx.nn.MLP, obs: Any) -> Any:
        """The controls (..., m) of observations (..., d): the action mapped onto [lo, hi]."""
        a = self.action(net, obs)
        lo, hi = jnp.asarray(self.lo, a.dtype), jnp.asarray(self.hi, a.dtype)
        return lo + 0.5 * (a + 1.0) * (hi - lo)

    def normalise(self, controls: Any) -> Any:
        """Controls (..., m) in the normalised action units [-1, 1] (clipped: an expert's plan can pass a bound by a
        solver's tolerance)."""
        u = jnp.asarray(controls)
        lo, hi = jnp.asarray(self.lo, u.dtype), jnp.asarray(self.hi, u.dtype)
        return jnp.clip(2.0 * (u - lo) / (hi - lo) - 1.0, -1.0, 1.0)

