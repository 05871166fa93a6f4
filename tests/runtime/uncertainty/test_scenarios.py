"""Scenario parameter sets: the explicit scenarios stacked in order, drawn ones reproducible from robust_seed,
both ready for vmap; malformed scenarios refused."""

import jax
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.uncertainty import sample, scenario_data, scenario_params, scenario_values

from ...helpers import ROOT
from ._systems import declared, four_parameters, plain

ONE = {"uncertain_params": ("k",), "uncertain_kinds": ("uniform",), "uncertain_args": ((1.5, 2.5),)}


def test_explicit_scenarios_are_stacked_in_order_the_other_parameters_at_their_values():
    system = declared("four_parameters", **ONE, scenarios=((1.5,), (2.0,), (2.5,)))
    params = scenario_params(system)
    assert set(params) == {"k", "c", "g", "m"}
    np.testing.assert_array_equal(params["k"], [1.5, 2.0, 2.5])
    np.testing.assert_array_equal(params["c"], [0.5] * 3)
    data = scenario_data(system)
    assert data.x0.shape == (3, 2) and data.params["k"].shape == (3,)
    # ready for vmap: one program evaluates the dynamics under every scenario
    f = jax.vmap(lambda d: system.dynamics(d.x0, np.zeros(1), 0.0, d.params))(data)
    np.testing.assert_allclose(np.asarray(f)[:, 1], [-0.5, -1.0, -1.5], rtol=1e-15)  # v' = -k x + g: x = g = 1


def test_the_schema3_example_specs_scenarios_as_compiled():
    params = scenario_params(load(ROOT / "tests/compiler/schema3/uncertain_oscillator.yaml"))
    assert {k: v.tolist() for k, v in params.items()} == {"k": [1.5, 2.0, 2.5], "c": [0.45, 0.5, 0.55],
                                                          "w": [0.1, 0.1, 0.1]}


def test_drawn_scenarios_are_robust_samples_draws_from_robust_seed():
    system = four_parameters(robust_samples=7, robust_seed=3)
    values = scenario_values(system)
    assert values.shape == (7, 4)
    np.testing.assert_array_equal(values, np.asarray(sample(system, jax.random.PRNGKey(3), 7)))
    np.testing.assert_array_equal(values, scenario_values(system))  # reproducible
    assert not np.array_equal(values, scenario_values(four_parameters(robust_samples=7, robust_seed=4)))
    assert scenario_values(four_parameters()).shape == (16, 4)  # the schema's default count


def test_malformed_scenarios_are_refused():
    with pytest.raises(ValueError, match="one value per uncertain parameter"):
        scenario_values(declared("four_parameters", **ONE, scenarios=((1.5, 2.0),)))
    with pytest.raises(ValueError, match="no scenarios"):
        scenario_values(plain("four_parameters"))
    with pytest.raises(ValueError, match="robust_samples"):
        scenario_values(four_parameters(robust_samples=0))
