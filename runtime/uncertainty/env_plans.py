"""Plans for an environment's own problem under its spec's declared uncertainty, and their expected cost: the
scenario (mean) plan of the held controls, and the Monte Carlo of any plan's cost over parameter draws (README.md in
this folder, "Plans in the environment").

    env = reference_env("pendulum")                      # nominal env: drawn parameters enter as data
    plan = scenario_plan(env, scenario_values(env.system), start)    # (N, m): min (1/S) sum_s J(u; theta_s)
    costs = plan_costs(env, plan, fresh_values(env.system, 2000, seed=2026))   # (2000,) out of sample
    mean, se = mean_and_error(costs)

The problem is the certified optimum's (:mod:`myriad.runtime.rl.optimum`): single shooting whose stages are the env's
``step_env`` (zero-order hold, its integrator and substeps, the running cost integrated alongside, the terminal cost
and penalty at T), so J(u; theta) *is* the env's cost of the controls u played at parameters theta. The scenario plan
minimises the sample average over S scenarios (a sample-average approximation of the expected cost); S = 1 at the
nominal values is the nominal problem itself.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.caches import program_cache
from ..data import ProblemData
from ..nlp import NLP
from ..system import System
from .distributions import sample, uncertain_spec
from .scenarios import scenario_params

__all__ = ["nominal_values", "fresh_values", "scenario_plan_nlp", "scenario_plan", "plan_costs", "mean_and_error"]


def nominal_values(system: System) -> np.ndarray:
    """(1, n_uncertain): the uncertain parameters at their spec values (one scenario: the nominal problem)."""
    names = uncertain_spec(system)[0]
    values = dict(zip(system.param_names, system.param_values))
    return np.asarray([[float(values[n]) for n in names]], np.float64)


def fresh_values(system: System, n: int, seed: int) -> np.ndarray:
    """(n, n_uncertain) float64 draws of the declared distributions from ``PRNGKey(seed)``: out of sample when
    ``seed`` is not the spec's ``robust_seed`` (the planning scenarios' key)."""
    if seed == int(getattr(system, "robust_seed", 0)):
        raise ValueError(f"{system.name}: seed {seed} is the spec's robust_seed, whose draws are the planning "
                         f"scenarios; choose another seed for out-of-sample draws")
    if n < 2:
        raise ValueError(f"fresh_values: n must be at least 2 for a standard error, got {n}")
    with jax.enable_x64(True):
        return np.asarray(sample(system, jax.random.PRNGKey(seed), n), np.float64)


def _model_batch(system: System, values: np.ndarray) -> dict[str, np.ndarray]:
    """{name: (S,)} for every parameter: the uncertain ones from ``values``, the rest at the spec's values."""
    return scenario_params(system, np.asarray(values, np.float64).reshape(len(values), -1))


@program_cache(maxsize=None)
def scenario_plan_nlp(env: Any) -> NLP:
    """The mean of the env's cost over a batch of scenarios as an NLP in the (N m) held controls; data
    ``ProblemData({"model": {name: (S,)}, "k": 0, "prev": (N, m)}, x0)``. One program for every S of a shape."""
    from ..rl.mpc import _planning_nlp  # the certified optimum's problem: the env's own cost, exactly

    base = _planning_nlp(env, "penalty")

    def objective(z, data):
        def one(p):
            return base.objective(z, ProblemData({"model": p, "k": data.params["k"], "prev": data.params["prev"]},
                                                 data.x0))

        return jnp.mean(jax.vmap(one)(data.params["model"]))

    return NLP(objective=objective, constraints=None, c_lower=np.zeros(0), c_upper=np.zeros(0),
               z_lower=base.z_lower, z_upper=base.z_upper, initial_guess=base.initial_guess, unravel=base.unravel,
               z_scale=base.z_scale, name=f"{base.name} mean over scenarios")


def scenario_plan(env: Any, values: Any, start: Any, solver: Any = None) -> tuple[np.ndarray, Any]:
    """The held controls (N, m) that minimise the mean of the env's cost over the scenarios ``values``
    (S, n_uncertain), from ``start`` (N, m), and the solver's result. ``env`` is a nominal env with controls in
    their units (:func:`myriad.runtime.rl.reference.reference_env`); ``solver`` default IPOPT at 1e-10."""
    from ..solvers import Ipopt

    start = np.asarray(start, np.float64)
    solver = Ipopt(tol=1e-10) if solver is None else solver
    data = ProblemData({"model": _model_batch(env.system, values), "k": np.int32(0), "prev": start},
                       np.asarray(env.default_params().x0, np.float64))
    with jax.enable_x64(True):  # float64 whatever the caller's mode (the solvers require it)
        result = solver.solve(scenario_plan_nlp(env), data, start.reshape(-1))
    return np.asarray(result.z, np.float64).reshape(start.shape), result


@program_cache(maxsize=None)
def _costs_program(env: Any):
    from ..rl.env import play

    def costs(controls, model, x0):
        return jax.vmap(lambda p: play(env, controls, ProblemData(p, x0)).cost)(model)

    return jax.jit(costs)


def plan_costs(env: Any, controls: Any, values: Any) -> np.ndarray:
    """(M,) the env's cost of the open-loop ``controls`` (N, m) at each row of ``values`` (M, n_uncertain): one
    vmapped program (the env's ``play``, not the planning problem's rollout: an independent evaluation)."""
    with jax.enable_x64(True):
        x0 = jnp.asarray(env.default_params().x0, jnp.float64)
        model = {k: jnp.asarray(v) for k, v in _model_batch(env.system, values).items()}
        return np.asarray(_costs_program(env)(jnp.asarray(controls, jnp.float64), model, x0), np.float64)


def mean_and_error(costs: Any) -> tuple[float, float]:
    """The Monte Carlo mean of ``costs`` and its standard error (sample std with ddof 1 over sqrt(M))."""
    c = np.asarray(costs, np.float64)
    if c.size < 2 or not np.all(np.isfinite(c)):
        return float(np.mean(c)) if c.size else math.nan, math.nan
    return float(c.mean()), float(c.std(ddof=1) / math.sqrt(c.size))
