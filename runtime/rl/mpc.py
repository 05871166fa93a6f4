"""Model-predictive control: the trajectory optimiser as a closed-loop policy in the environment.

    env = make_jax("van_der_pol", normalize_actions=False)
    mpc = MPC(env, replan_every=10)                    # plans on the env's own discretisation, nominal parameters
    ep = mpc.run(env.default_params())                 # one closed-loop episode
    ep.cost, normalized_score("van_der_pol", ep.cost)

The design (the planning problem, why it has a fixed size, failed re-plans, disturbances): README.md in this
folder.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.caches import program_cache
from ..data import ProblemData, check_structural_params
from ..nlp import NLP
from ..solvers import Ipopt
from ..transcriptions.nlp_parts import bounded_free_states, final_value_rows, guess_controls
from ..transcriptions.nominal_scales import control_scale, state_scale
from .env import Env, EnvState

__all__ = ["MPC", "MPCEpisode", "mismatched_params", "perturbed"]


@dataclasses.dataclass(frozen=True)
class MPCEpisode:
    """One closed-loop episode.

    Attributes:
        cost: J = -return in the environment (its parameters, minimisation form): what ``normalized_score`` takes.
        controls: (N, m) the controls applied.
        states: (N + 1, n) the environment's true states.
        penalty: the part of ``cost`` that is the terminal penalty on missed final values and final-state bounds.
        replans: the re-plans solved (step 0 included).
        failures: re-plans whose result was not used (not converged or not finite).
        iterations: IPOPT iterations over all re-plans.
        solve_seconds: wall time in the solver (compiling excluded).
        compile_seconds: time spent compiling (the first episode of a system only).
        wall_seconds: the whole episode.
        theta: the true values of the spec's uncertain parameters in a randomised env (drawn at the reset), else
            None.
    """

    cost: float
    controls: np.ndarray
    states: np.ndarray
    penalty: float
    replans: int
    failures: int
    iterations: int
    solve_seconds: float
    compile_seconds: float
    wall_seconds: float
    theta: np.ndarray | None = None


def mismatched_params(env: Env, fraction: float, seed: int = 0) -> dict[str, Any]:
    """The nominal parameters with each uncertain one scaled by 1 +- ``fraction`` (signs drawn from ``seed``).

    The uncertain parameters are the spec's ``learnable`` ones (those system identification would fit), else every
    parameter; structural ones (used by x0, bounds, final values or the horizon) are never changed.
    """
    system = env.system
    p = {k: np.asarray(v, np.float64) for k, v in zip(system.param_names, system.param_values)}
    names = [n for n in (system.learnable or system.param_names) if n not in system.structural_params]
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=len(names))
    return {**p, **{n: p[n] * (1.0 + fraction * s) for n, s in zip(names, signs)}}


def perturbed(env: Env, mismatch: float, obs_noise: float, seed: int = 0,
              declared: bool = True) -> tuple[Env, dict | None, float]:
    """What a perturbed MPC episode runs: ``(the env, the planner's parameters, the observation noise MPC.run
    adds)``. The perturbations are the spec's declared uncertainty where it declares it (schema 3, ``declared``):

    - ``mismatch`` > 0: on a spec with uncertain parameters the true ones are drawn at the reset from their declared
      distributions (the env randomised; the planner keeps the nominal values); otherwise the planner's are
      :func:`mismatched_params` (+-``mismatch``, signs from ``seed``) and the env keeps the nominal ones;
    - ``obs_noise`` > 0: on a spec that declares noise the env steps with its process noise and observes with its
      observation noise (what MPC sees); otherwise MPC.run adds ``obs_noise`` * scale * N(0, 1) to what it sees.

    Schema 1 and 2 specs (or ``declared=False``) get the second branch of each: their episodes are unchanged. The
    value of ``mismatch`` or ``obs_noise`` only switches the declared perturbation on: its size is the spec's.
    """
    system = env.system
    draws = declared and mismatch > 0 and bool(getattr(system, "uncertain_params", ()))
    noisy = declared and obs_noise > 0 and any(np.any(np.asarray(getattr(system, name, ()), np.float64) > 0)
                                               for name in ("process_noise", "observation_noise"))
    if draws or noisy:
        scale = 1.0 if noisy else 0.0
        env = Env(system, dataclasses.replace(env.options, randomize=draws, process_noise_scale=scale,
                                              observation_noise_scale=scale))
    params = mismatched_params(env, mismatch, seed) if mismatch > 0 and not draws else None
    return env, params, 0.0 if noisy else obs_noise


@program_cache(maxsize=None)
def _planning_nlp(model: Env, terminal: str) -> NLP:
    """The planning problem (README.md); data ``ProblemData({"model": p, "k": k, "prev": (N, m)}, x_k)``."""
    system = model.system
    N, m = model.options.steps, system.n_controls
    su = control_scale(system)
    lo, hi = model.control_bounds
    fixed, final = final_value_rows(system)
    bounded = bounded_free_states(system)
    sx = state_scale(system)
    steps = jnp.arange(N, dtype=jnp.int32)  # the env counts steps in int32 (strict promotion: no mixing)

    def rollout(z, data):
        us = jnp.reshape(z, (N, m))
        k, prev, p = data.params["k"], data.params["prev"], data.params["model"]
        inner = ProblemData(p, data.x0)

        @jax.checkpoint  # save only the carry per step: fewer kernels in the derivative programs (see shooting)
        def body(carry, j):
            x, cost = carry
            _, nxt, reward, _, _, _ = model.step_env(EnvState(x=x, k=j), us[j], inner)
            active = j >= k
            return (jnp.where(active, nxt.x, x), cost + jnp.where(active, -reward, 0.0)), None

        (xN, cost), _ = jax.lax.scan(body, (data.x0, jnp.zeros((), data.x0.dtype)), steps)
        held = jnp.where((steps < k)[:, None], (us - prev) / su, 0.0)
        return xN, cost + 0.5 * jnp.sum(held * held)

    def rows(xN):
        return jnp.concatenate([xN[fixed] - final, xN[bounded] / sx[bounded]])

    def both(z, data):
        xN, cost = rollout(z, data)
        return cost, rows(xN)

    constrained = terminal == "constraint" and fixed.size + bounded.size > 0
    a = system.arrays()
    c_lower = np.concatenate([np.zeros(fixed.size), a["x_lower"][bounded] / sx[bounded]]) if constrained else []
    c_upper = np.concatenate([np.zeros(fixed.size), a["x_upper"][bounded] / sx[bounded]]) if constrained else []
    return NLP(
        objective=lambda z, data: rollout(z, data)[1],
        constraints=(lambda z, data: rows(rollout(z, data)[0])) if constrained else None,
        c_lower=np.asarray(c_lower, np.float64),
        c_upper=np.asarray(c_upper, np.float64),
        z_lower=np.tile(lo, N),
        z_upper=np.tile(hi, N),
        initial_guess=lambda data: jnp.reshape(data.params["prev"], (-1,)),
        unravel=lambda z, data: (jnp.linspace(0.0, float(system.horizon), N + 1), None, jnp.reshape(z, (N, m))),
        z_scale=np.tile(su, N),
        name=f"{system.name}/mpc(N={N}, {terminal})",
        objective_and_constraints=both if constrained else None,
    )


class MPC:
    """A receding-horizon policy for ``env`` (README.md in this folder: model-predictive control).

    Args:
        env: the environment the policy acts in (actions normalised or not: the plan's controls are applied).
        params: the planner's model parameters (a partial dict overrides the spec's; default: the spec's).
        replan_every: re-plan at the steps 0, k, 2k, ... (1: every step).
        terminal: ``"penalty"`` (the environment's terminal cost) or ``"constraint"`` (the published rows).
        solver: an :class:`Ipopt` (default ``Ipopt(tol=1e-8)``).
    """

    def __init__(self, env: Env, params: dict | None = None, *, replan_every: int = 10,
                 terminal: Literal["penalty", "constraint"] = "penalty", solver: Ipopt | None = None):
        if replan_every < 1:
            raise ValueError(f"MPC: replan_every must be at least 1, got {replan_every}")
        if terminal not in ("penalty", "constraint"):
            raise ValueError(f"MPC: terminal must be 'penalty' or 'constraint', got {terminal!r}")
        self.env, self.replan_every, self.terminal = env, replan_every, terminal
        self.solver = Ipopt(tol=1e-8) if solver is None else solver
        penalty = env.options.penalty if terminal == "penalty" else 0.0
        # The planner's model is the nominal, noise-free system whatever the env draws or adds.
        self.model = Env(env.system, dataclasses.replace(env.options, normalize_actions=False, max_steps=None,
                                                         start_noise=0.0, penalty=penalty, randomize=False,
                                                         process_noise_scale=0.0, observation_noise_scale=0.0))
        if params is not None:
            check_structural_params(env.system, params)
        self.params = env.default_params(params).params
        # The planner's parameters are data, so MPCs that differ only in them (nominal, mismatched) share one NLP,
        # and with it IPOPT's compiled derivatives (the solver caches them per NLP object).
        self.nlp = _planning_nlp(self.model, terminal)
        # The closed loop plays the plan's controls themselves: the env with controls as actions, all else its own.
        self._loop = Env(env.system, dataclasses.replace(env.options, normalize_actions=False))
        self._step = jax.jit(self._loop.step_env)

    def initial_plan(self) -> np.ndarray:
        """The cold start of the first plan: the transcriptions' default guess (mid-bounds, else 0), (N, m)."""
        lo, hi = self.model.control_bounds
        return np.clip(guess_controls(self.env.system, self.model.options.steps), lo, hi)

    def plan(self, x: Any, k: int, previous: np.ndarray):
        """Solve the problem left at step ``k`` from state ``x``, warm-started from ``previous`` (N, m): returns
        ``(controls (N, m), NLPResult)``, ``controls[k:]`` the plan and ``controls[:k]`` ``previous``'s."""
        previous = np.asarray(previous, np.float64)
        data = ProblemData({"model": self.params, "k": np.int32(k), "prev": previous}, np.asarray(x, np.float64))
        result = self.solver.solve(self.nlp, data, previous.reshape(-1))
        controls = np.asarray(result.z, np.float64).reshape(previous.shape)
        controls[:k] = previous[:k]  # the solver only approximates them (they are played already, never used)
        return controls, result

    def run(self, data: ProblemData, *, obs_noise: float = 0.0, seed: int = 0,
            first_plan: np.ndarray | None = None) -> MPCEpisode:
        """One closed-loop episode in the environment with ``data`` (``env.default_params(...)``: its true parameters
        and x0). In a randomised or noisy env (a schema 3 spec's uncertainty, :func:`perturbed`) the reset draws the
        true parameters and the noise, and MPC sees the env's own (noisy) observations of the state.

        Args:
            obs_noise: the observation noise's standard deviation per unit of state scale, added to what MPC sees.
            seed: the noise's seed (``numpy.random.default_rng``), and the reset's key.
            first_plan: the warm start of the first plan, (N, m) controls (default :meth:`initial_plan`).
        """
        start = time.perf_counter()
        env, N = self.env, self.model.options.steps
        rng = np.random.default_rng(seed)
        scale = state_scale(env.system)
        plan = self.initial_plan() if first_plan is None else np.asarray(first_plan, np.float64)
        # The key matters only with the env's start_noise, drawn parameters or noise.
        obs, state = self._loop.reset(jax.random.PRNGKey(seed), data)
        n, observed = env.system.n_states, self._loop.observation_std is not None
        states, controls = [np.asarray(state.x)], []
        total, penalty, replans, failures, iterations, solve_s, compile_s = 0.0, 0.0, 0, 0, 0, 0.0, 0.0
        for k in range(N):
            if k % self.replan_every == 0:
                x_seen = np.asarray(obs[:n] if observed else state.x, np.float64)
                if obs_noise > 0:
                    x_seen = x_seen + obs_noise * scale * rng.standard_normal(x_seen.shape)
                new, result = self.plan(x_seen, k, plan)
                replans, iterations = replans + 1, iterations + result.iterations
                solve_s, compile_s = solve_s + result.solve_seconds, compile_s + result.compile_seconds
                if result.success and np.all(np.isfinite(new)):
                    plan = new
                else:
                    failures += 1
            obs, state, reward, _, _, info = self._step(state, jnp.asarray(plan[k]), data)
            total, penalty = total + float(reward), penalty + float(info["penalty"])
            states.append(np.asarray(state.x))
            controls.append(plan[k].copy())
        return MPCEpisode(cost=-total, controls=np.array(controls), states=np.array(states),
                          penalty=penalty, replans=replans, failures=failures, iterations=iterations,
                          solve_seconds=solve_s, compile_seconds=compile_s, wall_seconds=time.perf_counter() - start,
                          theta=None if state.theta is None else np.asarray(state.theta))
