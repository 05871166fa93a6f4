"""The RL reference records' expected costs under a spec's declared uncertainty (runtime/rl/reference.py,
issue 30 item 3) on the closed-form system of test_env_plans.py (x' = b u, cost w u^2 + (x(T) - 1)^2,
b ~ U(0.5, 1.5)): the nominal and the robust plan's Monte Carlo means within 3 standard errors of the exact
expectations, the robust plan the closed form of its scenarios, and the stale check's replay."""

import jax
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.rl import reference as R
from myriad.runtime.uncertainty.scenarios import scenario_values

from ._systems import SPECS, plain

W, N = 0.1, 100  # the reference env's 100 steps


def expected(v):  # E J(v) = (w + E b^2) v^2 - 2 E b v + 1
    return (W + 1.0 + 1.0 / 12.0) * v * v - 2.0 * v + 1.0


@pytest.fixture(scope="module")
def record():
    system = load(SPECS / "uncertain_gain.yaml")
    with jax.enable_x64(True):
        env = R.reference_env(system)
        nominal = np.full((N, 1), 1.0 / (W + 1.0))  # the nominal optimum: v = 1 / (w + 1)
        u = R.expected_costs(env, nominal)
        planning = scenario_values(system)[:, 0]
    return system, planning, {"optimal": {"controls": nominal.tolist()}, "uncertainty": u}


def test_expected_costs_are_the_closed_form_within_their_standard_errors(record):
    system, planning, r = record
    u = r["uncertainty"]
    assert (u["draws"], u["seed"], u["scenarios"]) == (R.UNCERTAIN_DRAWS, 1, 16) and u["robust_plan"]["converged"]
    v_robust = planning.mean() / (W + (planning ** 2).mean())
    np.testing.assert_allclose(u["robust_plan"]["controls"], v_robust, rtol=1e-7)
    for key, v in (("nominal_plan", 1.0 / (W + 1.0)), ("robust_plan", v_robust)):
        assert abs(u[key]["cost"] - expected(v)) <= 3 * u[key]["se"], key
    d = u["robust_minus_nominal"]
    assert abs(d["cost"] - (expected(v_robust) - expected(1.0 / (W + 1.0)))) <= 3 * d["se"] and d["cost"] < 0


def test_the_stale_check_replays_the_stored_plans(record):
    system, _, r = record
    assert R._stale_uncertainty("gain", system, r, 1e-9) == []
    tampered = {**r, "uncertainty": {**r["uncertainty"], "nominal_plan": {"cost": 0.5, "se": 0.0}}}
    assert "nominal_plan expected cost" in R._stale_uncertainty("gain", system, tampered, 1e-9)[0]
    assert "no expected costs" in R._stale_uncertainty("gain", system, {"optimal": r["optimal"]}, 1e-9)[0]
    assert "declares none" in R._stale_uncertainty("gain", plain("ornstein_uhlenbeck"), r, 1e-9)[0]
