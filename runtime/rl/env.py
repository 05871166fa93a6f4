"""The functional environment: any system as pure ``reset`` / ``step`` functions that ``jax.jit`` and ``jax.vmap``,
in gymnax's signatures. The episode's contract (observation, action, reward and terminal penalty, termination, the
automatic reset) is in README.md in this folder.

    env = make_jax("van_der_pol")                 # Env(system, EnvOptions())
    params = env.default_params()                 # ProblemData(params, x0): data, so a batch is one vmap
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..data import ProblemData, default_data
from ..integrators import INTEGRATORS, AbstractIntegrator, Heun
from ..loader import load
from ..system import System
from ..transcriptions.nlp_parts import bounded_free_states, final_value_rows
from ..transcriptions.nominal_scales import state_scale

__all__ = ["DEFAULT_ACTION_BOUNDS", "EnvOptions", "EnvState", "Env", "Episode", "make_jax", "play"]

# Where ``action_bound`` is not given, a shipped unbounded control's: twice its optimal control's largest magnitude,
# rounded up, so the optimum is inside the action space with room past it (README.md: action bounds).
DEFAULT_ACTION_BOUNDS = {"simple_case": 2.0}


@dataclasses.dataclass(frozen=True)
class EnvOptions:
    """How a system becomes an environment (hashable: an :class:`Env` is a static ``jit`` argument).

    Attributes:
        steps: N, the actions per episode on the grid t_k = k T / N (100: the published grid).
        integrator: the fixed-step method of the dynamics and of the running cost (Heun: the published one); an
            object or its registry name (``"rk4"``).
        substeps: integrator steps per action (the step size is T / (N substeps)).
        max_steps: a time limit shorter than N: the episode is then ``truncated`` after this many steps.
        start_noise: random starts: x0 + start_noise * s * U(-1, 1) per state (s the nominal scale), clipped to the
            state bounds; 0 starts at x0 exactly.
        penalty: the weight of the terminal penalty on missed final values and final-state bounds, per unit of the
            system's cost scale (README.md: the episode); 0 turns it off.
        normalize_actions: actions in [-1, 1] mapped onto the control bounds (what RL libraries and Gymnasium's
            checker expect); False: actions are the controls, in their units.
        action_bound: B > 0, the bound used on every unbounded side of a control ([-B, B] for a free control);
            required where a control is unbounded (default: :data:`DEFAULT_ACTION_BOUNDS`, Simple Case's 2).
    """

    steps: int = 100
    integrator: AbstractIntegrator = Heun()
    substeps: int = 1
    max_steps: int | None = None
    start_noise: float = 0.0
    penalty: float = 100.0
    normalize_actions: bool = True
    action_bound: float | None = None

    def __post_init__(self):
        if isinstance(self.integrator, str):  # a registry name: options of gymnasium.make stay plain data
            if self.integrator not in INTEGRATORS:
                raise ValueError(f"EnvOptions: unknown integrator {self.integrator!r}; one of {sorted(INTEGRATORS)}")
            object.__setattr__(self, "integrator", INTEGRATORS[self.integrator]())
        if self.steps < 1 or self.substeps < 1:
            raise ValueError(f"EnvOptions: steps and substeps must be at least 1, got {self.steps}, {self.substeps}")
        if not isinstance(self.integrator, AbstractIntegrator) or not self.integrator.fixed_step:
            raise ValueError(f"EnvOptions: integrator must be a fixed-step integrator (euler, heun, midpoint, rk4), "
                             f"got {self.integrator!r}")
        if self.max_steps is not None and not 1 <= self.max_steps <= self.steps:
            raise ValueError(f"EnvOptions: max_steps must be in [1, steps = {self.steps}], got {self.max_steps}")
        if not self.start_noise >= 0 or not self.penalty >= 0:
            raise ValueError("EnvOptions: start_noise and penalty must be non-negative")
        if self.action_bound is not None and not (0 < self.action_bound < np.inf):
            raise ValueError(f"EnvOptions: action_bound must be positive and finite, got {self.action_bound}")


class EnvState(NamedTuple):
    """The environment's state (a pytree): the system's state and the index k of the current grid node."""

    x: Any
    k: Any


class Episode(NamedTuple):
    """What :func:`play` returns: the rewards (N,), the states (N + 1, n) and the return."""

    rewards: Any
    states: Any
    total: Any

    @property
    def cost(self) -> Any:
        """J = -return, minimisation form."""
        return -self.total


@dataclasses.dataclass(frozen=True)
class Env:
    """A system as a functional environment (README.md in this folder: the episode's contract)."""

    system: System
    options: EnvOptions = EnvOptions()

    def __post_init__(self):
        # An episode runs on the fixed horizon with the cost as reward: a free final time has no horizon to run on
        # (``system.horizon`` is only its guess) and the reward would not see path constraints.
        self.system.require_schema1_features("the RL environment")
        default = DEFAULT_ACTION_BOUNDS.get(self.system.name)
        if self.options.action_bound is None and default is not None:
            object.__setattr__(self, "options", dataclasses.replace(self.options, action_bound=default))
        if self.options.normalize_actions:
            self.require_finite_controls("actions cannot be normalised to [-1, 1]", ", or normalize_actions=False "
                                         "for actions in the control's own units (unclipped where unbounded)")

    def require_finite_controls(self, why: str, alternative: str = "") -> None:
        """Raise ``ValueError`` naming the controls without finite bounds (after ``action_bound``), if any."""
        lo, hi = self.control_bounds
        free = [n for n, a, b in zip(self.system.control_names, lo, hi) if not (np.isfinite(a) and np.isfinite(b))]
        if free:
            raise ValueError(f"{self.system.name}: control(s) {', '.join(free)} have no finite bounds, so {why}; pass "
                             f"action_bound=B to limit each unbounded side to B in magnitude{alternative}")

    @property
    def observation_size(self) -> int:
        return self.system.n_states + 1

    @property
    def action_size(self) -> int:
        return self.system.n_controls

    @property
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The controls' bounds (float64), the unbounded sides replaced by -+``action_bound`` when it is given."""
        a = self.system.arrays()
        lo, hi = a["u_lower"], a["u_upper"]
        b = self.options.action_bound
        if b is not None:
            lo = np.where(np.isfinite(lo), lo, -b)
            hi = np.where(np.isfinite(hi), hi, b)
        return lo, hi

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of an action: [-1, 1] when normalised, else the control bounds."""
        if self.options.normalize_actions:
            return -np.ones(self.action_size), np.ones(self.action_size)
        return self.control_bounds

    @property
    def observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The spec's state bounds, then [0, T] for the time to go (infinite where the spec gives no bound)."""
        a = self.system.arrays()
        return np.append(a["x_lower"], 0.0), np.append(a["x_upper"], float(self.system.horizon))

    def default_params(self, params: dict | None = None, x0: Any = None) -> ProblemData:
        """The environment's data: the system's parameters (``params`` overriding the spec's) and the start x0."""
        return default_data(self.system, params, x0)

    def control(self, action: Any) -> Any:
        """The control an action applies: clipped to the action bounds, then mapped onto the controls if normalised."""
        action = jnp.asarray(action)
        dtype = action.dtype if jnp.issubdtype(action.dtype, jnp.floating) else jnp.result_type(float)
        lo, hi = (jnp.asarray(b, dtype) for b in self.control_bounds)
        action = jnp.reshape(action.astype(dtype), (self.action_size,))
        if self.options.normalize_actions:
            a = jnp.clip(action, -1.0, 1.0)
            return lo + 0.5 * (a + 1.0) * (hi - lo)
        return jnp.clip(action, lo, hi)

    def observation(self, state: EnvState) -> Any:
        x = state.x
        # T (N - k) / N is exactly T at k = 0 and exactly 0 at k = N (T - k T / N can miss either by an ulp, and
        # then the observation leaves its space).
        n_steps = self.options.steps
        to_go = float(self.system.horizon) * ((n_steps - state.k).astype(x.dtype) / n_steps)
        return jnp.concatenate([x, jnp.reshape(to_go, (1,))])

    def reset(self, key: Any, params: ProblemData) -> tuple[Any, EnvState]:
        """A new episode at t = 0: ``(observation, state)``. ``key`` is used only with ``start_noise``."""
        x0 = jnp.asarray(params.x0)
        if self.options.start_noise > 0:
            scale = jnp.asarray(state_scale(self.system), x0.dtype)
            u = jax.random.uniform(key, x0.shape, x0.dtype, -1.0, 1.0)
            a = self.system.arrays()
            x0 = jnp.clip(x0 + self.options.start_noise * scale * u, jnp.asarray(a["x_lower"], x0.dtype),
                          jnp.asarray(a["x_upper"], x0.dtype))
        state = EnvState(x=x0, k=jnp.zeros((), jnp.int32))
        return self.observation(state), state

    def step_env(self, state: EnvState, action: Any, params: ProblemData):
        """One step without the automatic reset: ``(obs, state, reward, terminated, truncated, info)``."""
        opts, system = self.options, self.system
        x = state.x
        dtype = x.dtype
        u = self.control(action).astype(dtype)
        p = params.params
        n, s = system.n_states, opts.substeps
        h = float(system.horizon) / (opts.steps * s)

        def f_aug(y, u, t):
            return jnp.concatenate([system.dynamics(y[:n], u, t, p),
                                    jnp.reshape(system.running_cost(y[:n], u, t, p), (1,)).astype(dtype)])

        def substep(j, y):
            # t = (k s + j) h, not a running sum: the times of rollout_with_cost exactly (the consistency test).
            t = (state.k * s + j).astype(dtype) * h
            return opts.integrator.step(f_aug, y, t, h, u, u)

        y = jnp.concatenate([x, jnp.zeros((1,), dtype)])
        y = substep(0, y) if s == 1 else jax.lax.fori_loop(0, s, substep, y)
        x_next, running = y[:n], y[n]
        k_next = state.k + 1
        terminated = k_next >= opts.steps
        limit = opts.steps if opts.max_steps is None else opts.max_steps
        truncated = (k_next >= limit) & ~terminated
        T = float(system.horizon)
        terminal = jnp.asarray(system.terminal_cost(x_next, T, p), dtype)
        penalty = self._terminal_penalty(x_next)
        cost = running + jnp.where(terminated, terminal + penalty, jnp.zeros((), dtype))
        next_state = EnvState(x=x_next, k=k_next)
        obs = self.observation(next_state)
        info = {
            "final_observation": obs,
            "control": u,
            "running_cost": running,
            "penalty": jnp.where(terminated, penalty, jnp.zeros((), dtype)),
            "bound_violation": jnp.max(self._outside(x_next)),
        }
        return obs, next_state, -cost, terminated, truncated, info

    def step(self, key: Any, state: EnvState, action: Any, params: ProblemData):
        """One step, resetting when the episode ends: ``(obs, state, reward, terminated, truncated, info)``.

        After an ending step ``obs`` and ``state`` are those of the new episode (started with ``key``), and
        ``info["final_observation"]`` is the observation the step reached; ``reward``, ``terminated`` and
        ``truncated`` are the step's own.
        """
        obs, next_state, reward, terminated, truncated, info = self.step_env(state, action, params)
        obs_reset, state_reset = self.reset(key, params)
        done = terminated | truncated
        next_state = jax.tree.map(lambda a, b: jnp.where(done, a, b), state_reset, next_state)
        return jnp.where(done, obs_reset, obs), next_state, reward, terminated, truncated, info

    def _outside(self, x):
        """Each state's distance outside its bounds, relative to its nominal scale s (0 inside)."""
        a = self.system.arrays()
        lo, hi = jnp.asarray(a["x_lower"], x.dtype), jnp.asarray(a["x_upper"], x.dtype)
        over = jnp.maximum(jnp.maximum(lo - x, x - hi), jnp.zeros((), x.dtype))
        return over / jnp.asarray(state_scale(self.system), x.dtype)

    def _terminal_penalty(self, x):
        """P = w * (the scaled misses of the required final values and of the final-state bounds, squared), with
        w = penalty * max(1, |reference target|): the weight in the units of the cost."""
        system = self.system
        if self.options.penalty == 0:
            return jnp.zeros((), x.dtype)
        scale = jnp.asarray(state_scale(system), x.dtype)
        fixed, final = final_value_rows(system)
        rows = jnp.concatenate([(x[fixed] - jnp.asarray(final, x.dtype)) / scale[fixed],
                                self._outside(x)[bounded_free_states(system)]])
        ref = dict(system.reference)
        target = ref.get("target", ref.get("published"))
        weight = self.options.penalty * max(1.0, abs(float(target)) if target is not None else 1.0)
        return weight * jnp.sum(rows * rows)


def make_jax(target: System | str, **options) -> Env:
    """The functional environment of a system object, a shipped name or a spec path; ``options`` are
    :class:`EnvOptions` fields."""
    system = load(target) if not isinstance(target, System) else target
    return Env(system, EnvOptions(**options))


@functools.partial(jax.jit, static_argnums=0)
def play(env: Env, actions: Any, params: ProblemData, key: Any = None) -> Episode:
    """Play (K, m) actions open loop from a reset with ``key`` (used only with ``start_noise``), K <= N steps of
    ``step_env`` (no automatic reset: K = N plays a whole episode); jit-compiled once per env and shapes (``vmap``
    it over action sequences, parameters or keys)."""
    key = jax.random.PRNGKey(0) if key is None else key
    _, state0 = env.reset(key, params)

    def body(state, action):
        _, state, reward, _, _, _ = env.step_env(state, action, params)
        return state, (reward, state.x)

    _, (rewards, xs) = jax.lax.scan(body, state0, jnp.asarray(actions))
    return Episode(rewards=rewards, states=jnp.concatenate([state0.x[None], xs]), total=jnp.sum(rewards))
