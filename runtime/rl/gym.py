"""The Gymnasium adapter: one env (:class:`MyriadEnv`) and a vector env (:class:`MyriadVectorEnv`), both thin shells
over the jit-compiled functional core (:mod:`myriad.runtime.rl.env`), and their ids: ``myriad/<Name>-v0`` for the
shipped systems, ``myriad-spec/<Name>-<hash>-v0`` for any other (:func:`register`). Spaces, ids and the episode's
end: README.md in this folder.

    import gymnasium, myriad.runtime.rl                        # importing registers myriad/VanDerPol-v0, ...
    env = gymnasium.make("myriad/VanDerPol-v0")
    env = myriad.runtime.rl.make("my/spec.yaml", steps=50)     # any spec; options are EnvOptions fields
    envs = gymnasium.make_vec("myriad/Pendulum-v0", num_envs=1024, vectorization_mode="vector_entry_point")
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..compilation.caches import program_cache
from ..data import batch_data
from ..loader import load
from ..system import System
from ..systems import NAMES
from ..uncertainty import uncertain_spec
from .env import Env, make_jax
from .render import draw_traces

__all__ = ["MyriadEnv", "MyriadVectorEnv", "make", "env_id", "register", "register_all"]

_F32_MAX = float(np.finfo(np.float32).max)


def env_id(name: str) -> str:
    """The Gymnasium id of a shipped system: ``van_der_pol`` -> ``myriad/VanDerPol-v0`` (the generated class name)."""
    return "myriad/" + "".join(part.capitalize() for part in name.split("_")) + "-v0"


def _core(system: System | str, options: dict) -> tuple[Env, spaces.Box, spaces.Box]:
    """The functional core, its (single) action space and observation space."""
    env = make_jax(system, **options)
    env.require_finite_controls("a Gymnasium action space cannot hold them")
    return env, _f32_box(*env.action_bounds), _f32_box(*env.observation_bounds)


def _f32_box(lo: np.ndarray, hi: np.ndarray) -> spaces.Box:
    lo = np.clip(np.asarray(lo, np.float64), -_F32_MAX, _F32_MAX).astype(np.float32)
    hi = np.clip(np.asarray(hi, np.float64), -_F32_MAX, _F32_MAX).astype(np.float32)
    return spaces.Box(lo, hi, dtype=np.float32)


_SCALARS = ("reward", "terminated", "truncated", "running_cost", "penalty", "bound_violation")


# One compiled program per (system, options), shared by every env instance (gymnasium.make, check_env's remakes).
@program_cache(maxsize=None)
def _single(env: Env):
    def step(state, action, data):
        # Everything the step returns packed into one vector: one device-to-host copy per step, not eleven.
        obs, state, reward, terminated, truncated, info = env.step_env(state, action, data)
        scalars = [reward, terminated, truncated, info["running_cost"], info["penalty"], info["bound_violation"]]
        packed = [obs, jnp.stack([jnp.asarray(v, obs.dtype) for v in scalars]), info["control"], state.x]
        return jnp.concatenate(packed), state

    return jax.jit(env.reset), jax.jit(step)


@program_cache(maxsize=None)
def _batched(env: Env):
    return jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def _drawn(env: Env, state: Any) -> dict[str, np.ndarray]:
    """The episode's drawn uncertain parameters, {name: value (or (B,) values)}; empty unless randomised."""
    if state is None or state.theta is None:
        return {}
    theta = np.asarray(state.theta, np.float64)
    return {name: theta[..., i] for i, name in enumerate(uncertain_spec(env.system)[0])}


class MyriadEnv(gymnasium.Env):
    """One system as a Gymnasium environment.

    A spec with uncertainty (schema 3) is noisy as declared and, with ``randomize=True`` (opt-in), randomised at
    every ``reset`` (its drawn parameters in the reset's ``info["params"]`` and :attr:`episode_params`); the options
    ``randomize``, ``widen``, ``process_noise_scale`` and ``observation_noise_scale`` control it (README.md in this
    folder: uncertainty).

    Args:
        system: a shipped name, a spec path or a :class:`~myriad.runtime.system.System`.
        render_mode: None or ``"rgb_array"`` (the state and control traces so far).
        params: parameter values overriding the spec's.
        x0: the start state (default: the spec's).
        **options: :class:`~myriad.runtime.rl.env.EnvOptions` fields.

    Raises:
        ValueError: a control without finite bounds and no ``action_bound``; an invalid option.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, system: System | str = "van_der_pol", *, render_mode: str | None = None,
                 params: dict | None = None, x0: Any = None, **options):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.core, self.action_space, self.observation_space = _core(system, options)
        self.system = self.core.system
        self.render_mode = render_mode
        self.data = self.core.default_params(params, x0)
        self._reset_fn, self._step_fn = _single(self.core)
        self._state = None
        self._over = False
        self._history: tuple[list, list, list] = ([], [], [])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        key = jax.random.PRNGKey(int(self.np_random.integers(0, 2**31 - 1)))
        obs, self._state = self._reset_fn(key, self.data)
        self._over = False
        self._history = ([0.0], [np.asarray(self._state.x, np.float64)], [])
        drawn = self.episode_params
        return np.asarray(obs, np.float32), ({"params": {k: float(v) for k, v in drawn.items()}} if drawn else {})

    @property
    def episode_params(self) -> dict[str, np.ndarray]:
        """The current episode's draw of the uncertain parameters ({} unless the env is randomised)."""
        return _drawn(self.core, self._state)

    def step(self, action):
        if self._state is None or self._over:
            raise RuntimeError("call reset() before step(): the episode has not started or is over")
        # float64 under jax_enable_x64, else float32: the core's own dtype, so no second compile
        action = np.asarray(action, jax.dtypes.canonicalize_dtype(np.float64)).reshape(self.action_space.shape)
        packed, self._state = self._step_fn(self._state, action, self.data)
        packed = np.asarray(packed, dtype=np.float64)
        n = self.core.observation_size
        first, m = n + len(_SCALARS), self.core.action_size
        obs, control, x = packed[:n], packed[first:first + m], packed[first + m:]
        values = dict(zip(_SCALARS, packed[n:n + len(_SCALARS)].tolist()))
        terminated, truncated = bool(values.pop("terminated")), bool(values.pop("truncated"))
        self._over = terminated or truncated
        times, states, controls = self._history
        times.append(float(self.system.horizon) * len(times) / self.core.options.steps)
        states.append(x)  # the true state: the observation may be noisy
        controls.append(control)
        reward = values.pop("reward")
        return np.asarray(obs, np.float32), reward, terminated, truncated, {**values, "control": control.copy()}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        times, states, controls = self._history
        if not states:
            raise RuntimeError("call reset() before render()")
        return draw_traces(self.system, np.asarray(times), np.stack(states),
                           np.stack(controls) if controls else np.zeros((0, self.system.n_controls)))


class MyriadVectorEnv(VectorEnv):
    """``num_envs`` copies of a system stepped as one jit-compiled ``vmap`` of the functional core.

    Args:
        system: a shipped name, a spec path or a system.
        num_envs: the batch size.
        params: per-env parameter values, ``{name: (num_envs,) array}`` (names not given keep the spec's).
        x0: (num_envs, n_states) start states (default: the spec's).
        **options: :class:`~myriad.runtime.rl.env.EnvOptions` fields.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, system: System | str = "van_der_pol", num_envs: int = 1, *, params: dict | None = None,
                 x0: Any = None, render_mode: str | None = None, **options):
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        if render_mode is not None:
            raise ValueError("MyriadVectorEnv does not render; make single envs with render_mode='rgb_array'")
        self.core, self.single_action_space, self.single_observation_space = _core(system, options)
        self.num_envs = num_envs
        if not params and x0 is None:  # batch_data needs a batch axis on something
            x0 = np.broadcast_to(self.core.default_params().x0, (num_envs, self.core.system.n_states))
        self.data = batch_data(self.core.system, params, x0)
        size = jax.tree.leaves(self.data)[0].shape[0]
        if size != num_envs:
            raise ValueError(f"params/x0 hold {size} envs, num_envs is {num_envs}")
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._reset_fn, self._step_fn = _batched(self.core)
        self._key = None
        self._state = None

    @property
    def episode_params(self) -> dict[str, np.ndarray]:
        """Each env's current draw of the uncertain parameters, {name: (num_envs,)} ({} unless randomised): a
        new draw wherever an episode auto-resets."""
        return _drawn(self.core, self._state)

    def _keys(self):
        self._key, sub = jax.random.split(self._key)
        return jax.random.split(sub, self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._key = jax.random.PRNGKey(int(self.np_random.integers(0, 2**31 - 1)))
        obs, self._state = self._reset_fn(self._keys(), self.data)
        return np.asarray(obs, np.float32), {}

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, jax.dtypes.canonicalize_dtype(np.float64)).reshape(self.action_space.shape)
        obs, self._state, reward, terminated, truncated, info = self._step_fn(self._keys(), self._state, actions,
                                                                              self.data)
        obs, reward, terminated, truncated, info = jax.device_get((obs, reward, terminated, truncated, info))
        out: dict[str, Any] = {"final_obs": np.asarray(info["final_observation"], np.float32),
                               "_final_obs": terminated | truncated}
        for name in ("running_cost", "penalty", "bound_violation", "control"):
            out[name] = np.asarray(info[name], np.float64)
            out["_" + name] = np.ones(self.num_envs, dtype=bool)
        return np.asarray(obs, np.float32), np.asarray(reward, np.float64), terminated, truncated, out


def make(system: System | str | os.PathLike, **options) -> MyriadEnv:
    """A :class:`MyriadEnv` for any system (a shipped name, a peer's, a spec path or a system object), made by
    ``gymnasium.make`` from its registered id (:func:`register`), so it has a ``spec`` to remake it from.

    ``options`` are :class:`MyriadEnv`'s keywords (``render_mode``, ``params``, ``x0``) and the
    :class:`~myriad.runtime.rl.env.EnvOptions` fields. Returned unwrapped (no order enforcing or passive checker).
    """
    return gymnasium.make(register(system), disable_env_checker=True, **options).unwrapped


def _register(ident: str, system: System | str) -> str:
    if ident not in gymnasium.registry:
        gymnasium.register(id=ident, entry_point="myriad.runtime.rl.gym:MyriadEnv",
                           vector_entry_point="myriad.runtime.rl.gym:MyriadVectorEnv", kwargs={"system": system})
    return ident


def register(system: System | str | os.PathLike) -> str:
    """The Gymnasium id of any system, registered on first use (idempotent).

    A shipped system is ``myriad/<Name>-v0``; any other is ``myriad-spec/<Name>-<hash>-v0``, ``<Name>`` its generated
    class name and ``<hash>`` the first 8 hex digits of its spec's SHA-256, so an edited spec gets a new id. The id
    makes the system from the spec's absolute path, the name given (a peer's) or the system object itself.
    """
    target = system if isinstance(system, System) else os.fspath(system)
    loaded = system if isinstance(system, System) else load(target)
    if loaded.name in NAMES and loaded == load(loaded.name):
        return env_id(loaded.name)
    if isinstance(target, str) and Path(target).is_file():
        target = str(Path(target).resolve())
    return _register(f"myriad-spec/{type(loaded).__name__}-{loaded.spec_sha256[:8]}-v0", target)


def register_all() -> list[str]:
    """Register ``myriad/<Name>-v0`` for every shipped system (idempotent); returns the ids."""
    return [_register(env_id(name), name) for name in NAMES]
