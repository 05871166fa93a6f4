"""The functional environment: any system as pure ``reset`` / ``step`` functions that ``jax.jit`` and ``jax.vmap``,
in gymnax's signatures. The episode's contract (observation, action, reward and terminal penalty, termination, the
automatic reset) is in README.md in this folder.

    env = make_jax("van_der_pol")                 # Env(system, EnvOptions())
    params = env.default_params()                 # ProblemData(params, x0): data, so a batch is one vmap
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

A spec that declares uncertainty (schema 3) makes a randomised, stochastic env: with ``randomize=True`` (opt-in)
``reset`` draws the uncertain parameters from their distributions with its key (data, not a recompile), the dynamics
carry the declared process noise (a stochastic scheme on the env's grid) and the observations the declared
observation noise; ``widen``, ``process_noise_scale`` and ``observation_noise_scale`` scale each (0 turns the noise
off). Without any of it the env is the deterministic one, step for step and bit for bit.
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
from ..uncertainty.distributions import draw, uncertain_spec, with_values
from ..uncertainty.sde import SDEScheme, for_integrator

__all__ = ["DEFAULT_ACTION_BOUNDS", "EnvOptions", "EnvState", "Env", "Episode", "make_jax", "play", "expected_cost"]

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
        randomize: draw the spec's uncertain parameters from their distributions at every reset (domain
            randomisation; README.md: uncertainty). Opt-in: by default (False) the env runs on the parameters
            given in the data (the spec's values by default), so declaring a range on a shipped spec leaves its
            ``myriad/<Name>-v0`` env and every table played in it unchanged.
        widen: the factor on every uncertain parameter's spread about its distribution's centre (1: as declared,
            0: the centre; runtime/uncertainty/README.md).
        process_noise_scale: the factor on the spec's process noise sigma (0: deterministic dynamics).
        observation_noise_scale: the factor on the spec's observation noise std (0: exact observations).
    """

    steps: int = 100
    integrator: AbstractIntegrator = Heun()
    substeps: int = 1
    max_steps: int | None = None
    start_noise: float = 0.0
    penalty: float = 100.0
    normalize_actions: bool = True
    action_bound: float | None = None
    randomize: bool = False
    widen: float = 1.0
    process_noise_scale: float = 1.0
    observation_noise_scale: float = 1.0

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
        for name in ("widen", "process_noise_scale", "observation_noise_scale"):
            if not 0 <= getattr(self, name) < np.inf:
                raise ValueError(f"EnvOptions: {name} must be finite and non-negative, got {getattr(self, name)}")


class EnvState(NamedTuple):
    """The environment's state (a pytree): the system's state and the index k of the current grid node; in a
    randomised env also the episode's draw of the uncertain parameters (``theta``, in ``uncertain_params``' order),
    in a noisy one the key of the episode's noise (split at every step). Both are None (no leaves) otherwise."""

    x: Any
    k: Any
    theta: Any = None
    key: Any = None


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
        uncertain_spec(self.system)  # a malformed declaration fails here, not inside a trace
        for name in ("process_noise", "observation_noise"):
            levels = getattr(self.system, name, ())
            if len(levels) not in (0, self.system.n_states) or not all(0 <= v < np.inf for v in levels):
                raise ValueError(f"{self.system.name}: {name} needs one finite non-negative level per state "
                                 f"({self.system.n_states}), got {tuple(levels)}")
        if self.process_sigma is not None:
            try:
                for_integrator(self.options.integrator)
            except ValueError as e:
                raise ValueError(f"{self.system.name}: {e}, or process_noise_scale=0") from None

    # ---- uncertainty (schema 3): what of it this env uses, static ----------------------------------------------
    @property
    def randomized(self) -> bool:
        """True when ``reset`` draws the uncertain parameters (the spec has some, and ``randomize``)."""
        return self.options.randomize and bool(uncertain_spec(self.system)[0])

    def _levels(self, name: str, scale: float) -> np.ndarray | None:
        levels = scale * np.asarray(getattr(self.system, name, ()), np.float64)
        return levels if levels.size and np.any(levels > 0) else None

    @property
    def process_sigma(self) -> np.ndarray | None:
        """The diffusion sigma (n_states,) of dx = f dt + sigma dW (the spec's times ``process_noise_scale``), or None
        for deterministic dynamics."""
        return self._levels("process_noise", self.options.process_noise_scale)

    @property
    def observation_std(self) -> np.ndarray | None:
        """The observation noise's standard deviation per state, or None for exact observations."""
        return self._levels("observation_noise", self.options.observation_noise_scale)

    @property
    def sde_scheme(self) -> SDEScheme | None:
        """The stochastic scheme of the process noise (the one whose noiseless limit is ``integrator``), or None."""
        return None if self.process_sigma is None else for_integrator(self.options.integrator)

    @property
    def stochastic(self) -> bool:
        """True when an episode depends on its reset key beyond ``start_noise``: drawn parameters or noise."""
        return self.randomized or self.process_sigma is not None or self.observation_std is not None

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
        """The spec's state bounds, then [0, T] for the time to go (infinite where the spec gives no bound, and for
        a state with process or observation noise: a Gaussian increment or reading has no bound)."""
        a = self.system.arrays()
        lo, hi = a["x_lower"], a["x_upper"]
        noisy = np.zeros(self.system.n_states, bool)
        for levels in (self.process_sigma, self.observation_std):
            if levels is not None:
                noisy |= levels > 0
        lo, hi = np.where(noisy, -np.inf, lo), np.where(noisy, np.inf, hi)
        return np.append(lo, 0.0), np.append(hi, float(self.system.horizon))

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

    def _observe(self, state: EnvState, z: Any) -> Any:
        """The observation, with the observation noise std * z on the states when there is any (z (n_states,)
        standard normals)."""
        obs = self.observation(state)
        std = self.observation_std
        if std is None:
            return obs
        return obs + jnp.append(jnp.asarray(std, obs.dtype) * z, jnp.zeros((1,), obs.dtype))  # t to go: exact

    def reset(self, key: Any, params: ProblemData) -> tuple[Any, EnvState]:
        """A new episode at t = 0: ``(observation, state)``. ``key`` draws the random start (``start_noise``), the
        uncertain parameters and the episode's noise; a deterministic env uses it only with ``start_noise``."""
        x0 = jnp.asarray(params.x0)
        theta = noise = None
        if self.stochastic:  # separate streams; a deterministic env keeps drawing its start from the key itself
            key, k_theta, k_obs, noise = jax.random.split(key, 4)
            theta = draw(self.system, k_theta, self.options.widen, x0.dtype) if self.randomized else None
            noise = noise if self.process_sigma is not None or self.observation_std is not None else None
        if self.options.start_noise > 0:
            scale = jnp.asarray(state_scale(self.system), x0.dtype)
            u = jax.random.uniform(key, x0.shape, x0.dtype, -1.0, 1.0)
            a = self.system.arrays()
            x0 = jnp.clip(x0 + self.options.start_noise * scale * u, jnp.asarray(a["x_lower"], x0.dtype),
                          jnp.asarray(a["x_upper"], x0.dtype))
        state = EnvState(x=x0, k=jnp.zeros((), jnp.int32), theta=theta, key=noise)
        z = jax.random.normal(k_obs, x0.shape, x0.dtype) if self.observation_std is not None else None
        return self._observe(state, z), state

    def step_env(self, state: EnvState, action: Any, params: ProblemData):
        """One step without the automatic reset: ``(obs, state, reward, terminated, truncated, info)``."""
        opts, system = self.options, self.system
        key, z_dw, z_obs = self._normals(state)
        p = params.params if state.theta is None else with_values(system, params.params, state.theta)
        u = self.control(action).astype(state.x.dtype)
        x_next, running = self._advance(state, u, p, z_dw)
        dtype = x_next.dtype
        k_next = state.k + 1
        terminated = k_next >= opts.steps
        limit = opts.steps if opts.max_steps is None else opts.max_steps
        truncated = (k_next >= limit) & ~terminated
        T = float(system.horizon)
        terminal = jnp.asarray(system.terminal_cost(x_next, T, p), dtype)
        penalty = self._terminal_penalty(x_next)
        cost = running + jnp.where(terminated, terminal + penalty, jnp.zeros((), dtype))
        next_state = EnvState(x=x_next, k=k_next, theta=state.theta, key=key)
        obs = self._observe(next_state, z_obs)
        info = {
            "final_observation": obs,
            "control": u,
            "running_cost": running,
            "penalty": jnp.where(terminated, penalty, jnp.zeros((), dtype)),
            "bound_violation": jnp.max(self._outside(x_next)),
        }
        return obs, next_state, -cost, terminated, truncated, info

    def _normals(self, state: EnvState) -> tuple[Any, Any, Any]:
        """(the next noise key, (substeps, n) normals of the Wiener increments or None, (n,) normals of the
        observation noise or None): one split and one draw a step (the key stream costs more than the step)."""
        if state.key is None:
            return None, None, None
        n, s, dtype = self.system.n_states, self.options.substeps, state.x.dtype
        n_dw = s * n if self.process_sigma is not None else 0
        n_obs = n if self.observation_std is not None else 0
        key, sub = jax.random.split(state.key)
        z = jax.random.normal(sub, (n_dw + n_obs,), dtype)
        return key, (z[:n_dw].reshape(s, n) if n_dw else None), (z[n_dw:] if n_obs else None)

    def _advance(self, state: EnvState, u: Any, p: Any, z: Any) -> tuple[Any, Any]:
        """(x_{k+1}, the running cost over the step): ``substeps`` steps of the integrator (with process noise, of
        its stochastic scheme, the Wiener increments sqrt(h) z, z (substeps, n) standard normals) on the state and
        the cost as one more state, which carries no noise."""
        opts, system = self.options, self.system
        x = state.x
        dtype = x.dtype
        n, s = system.n_states, opts.substeps
        h = float(system.horizon) / (opts.steps * s)

        def f_aug(y, u, t):
            return jnp.concatenate([system.dynamics(y[:n], u, t, p),
                                    jnp.reshape(system.running_cost(y[:n], u, t, p), (1,)).astype(dtype)])

        sigma, scheme = self.process_sigma, self.sde_scheme
        if sigma is not None:
            sigma = jnp.append(jnp.asarray(sigma, dtype), jnp.zeros((1,), dtype))
            dw = jnp.concatenate([jnp.sqrt(jnp.asarray(h, dtype)) * z, jnp.zeros((s, 1), dtype)], axis=1)

        def substep(j, y):
            # t = (k s + j) h, not a running sum: the times of rollout_with_cost exactly (the consistency test).
            t = (state.k * s + j).astype(dtype) * h
            if sigma is None:
                return opts.integrator.step(f_aug, y, t, h, u, u)
            return scheme.step(f_aug, y, t, h, u, sigma, dw[j])

        y = jnp.concatenate([x, jnp.zeros((1,), dtype)])
        y = substep(0, y) if s == 1 else jax.lax.fori_loop(0, s, substep, y)
        return y[:n], y[n]

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


@functools.partial(jax.jit, static_argnums=(0, 3))
def _costs(env: Env, actions: Any, params: ProblemData, episodes: int, key: Any) -> Any:
    return jax.vmap(lambda k: play(env, actions, params, k).cost)(jax.random.split(key, episodes))


def expected_cost(env: Env, actions: Any, params: ProblemData | None = None, episodes: int = 1000,
                  seed: int = 0) -> tuple[float, float]:
    """Monte Carlo of the expected cost E J = -E return of open-loop ``actions`` (K, m) under the env's uncertainty
    (drawn parameters, process and observation noise, random starts): ``(mean, standard error)`` over ``episodes``
    episodes, each from its own reset key (``jax.random.split(PRNGKey(seed), episodes)``), one vmapped program.
    A deterministic env's episodes are all alike (a standard error of rounding only)."""
    if episodes < 2:
        raise ValueError(f"expected_cost: episodes must be at least 2 for a standard error, got {episodes}")
    params = env.default_params() if params is None else params
    costs = np.asarray(_costs(env, jnp.asarray(actions), params, episodes, jax.random.PRNGKey(seed)), np.float64)
    return float(costs.mean()), float(costs.std(ddof=1) / np.sqrt(episodes))
