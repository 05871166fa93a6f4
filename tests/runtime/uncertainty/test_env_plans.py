"""Plans in the environment under the declared uncertainty (env_plans.py) against a closed form: x' = b u, cost
w u^2 + (x(T) - 1)^2, b ~ U(0.5, 1.5) (specs/uncertain_gain.yaml). Held controls u_k = v cost J(v; b) = w v^2 +
(b v - 1)^2 exactly on any fixed-step grid, so the mean over scenarios with moments m1, m2 of b is least at
v = m1 / (w + m2), and E J(v) = (w + m2) v^2 - 2 m1 v + 1 under the distribution (m1 = 1, m2 = 1 + 1/12)."""

import math

import jax
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.rl.env import EnvOptions
from myriad.runtime.rl.reference import reference_env
from myriad.runtime.uncertainty.env_plans import fresh_values, mean_and_error, nominal_values, plan_costs, scenario_plan

from ._systems import SPECS

W, N = 0.1, 4
M1, M2 = 1.0, 1.0 + 1.0 / 12.0  # E b and E b^2 under U(0.5, 1.5)


def expected(v, m1=M1, m2=M2):
    return (W + m2) * v * v - 2.0 * m1 * v + 1.0


@pytest.fixture(scope="module")
def env():
    with jax.enable_x64(True):
        yield reference_env(load(SPECS / "uncertain_gain.yaml"), EnvOptions(steps=N))


def test_the_scenario_plan_is_the_closed_form_optimum_of_its_scenarios(env):
    with jax.enable_x64(True):
        nominal, r = scenario_plan(env, nominal_values(env.system), np.zeros((N, 1)))
        assert r.success and nominal_values(env.system).tolist() == [[1.0]]
        np.testing.assert_allclose(nominal, 1.0 / (W + 1.0), rtol=1e-8)  # one scenario at b = 1: the nominal plan
        values = np.array([[0.5], [1.5], [0.8]])
        robust, r = scenario_plan(env, values, nominal)
        m1, m2 = values.mean(), (values ** 2).mean()
        assert r.success
        np.testing.assert_allclose(robust, m1 / (W + m2), rtol=1e-8)
        np.testing.assert_allclose(r.objective, expected(m1 / (W + m2), m1, m2), rtol=1e-10)


def test_plan_costs_are_the_env_cost_at_each_draw_and_their_mean_the_expectation(env):
    draws = fresh_values(env.system, 4000, seed=7)
    assert draws.shape == (4000, 1) and 0.5 <= draws.min() and draws.max() <= 1.5
    v = 0.8
    costs = plan_costs(env, np.full((N, 1), v), draws)
    np.testing.assert_allclose(costs, W * v * v + (draws[:, 0] * v - 1.0) ** 2, rtol=1e-12, atol=1e-14)
    mean, se = mean_and_error(costs)
    assert abs(mean - expected(v)) <= 3 * se


def test_the_robust_plan_beats_the_nominal_one_out_of_sample(env):
    """The mean plan over the distribution's moments is the expected cost's minimiser: it beats the nominal plan
    in closed form, and the paired Monte Carlo difference over fresh draws is negative beyond 3 standard errors."""
    nominal, robust = 1.0 / (W + 1.0), M1 / (W + M2)
    assert expected(robust) < expected(nominal)
    draws = fresh_values(env.system, 2000, seed=11)
    diff = plan_costs(env, np.full((N, 1), robust), draws) - plan_costs(env, np.full((N, 1), nominal), draws)
    mean, se = mean_and_error(diff)
    assert abs(mean - (expected(robust) - expected(nominal))) <= 3 * se and mean + 3 * se < 0


def test_fresh_draws_are_not_the_planning_scenarios_and_the_standard_error_by_hand(env):
    with pytest.raises(ValueError, match="robust_seed"):
        fresh_values(env.system, 10, seed=0)
    with pytest.raises(ValueError, match="at least 2"):
        fresh_values(env.system, 1, seed=3)
    mean, se = mean_and_error([1.0, 2.0, 3.0, 6.0])  # mean 3, sample variance 14 / 3
    assert mean == 3.0 and se == pytest.approx(math.sqrt(14.0 / 3.0) / 2.0, rel=1e-15)
    assert math.isnan(mean_and_error([1.0, float("inf")])[1])
