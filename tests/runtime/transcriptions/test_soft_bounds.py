"""Elastic final-state bounds in single shooting (``SingleShooting(soft_state_bounds=rho)``): the L1 exact penalty.

Where the hard problem is feasible and rho exceeds the bound's multiplier the optimum is the same; where it is
infeasible the plan violates the bound as little as it can (the closed form below) instead of the solve failing."""

from pathlib import Path

import jax
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.e2e import E2EConfig, run_e2e
from myriad.runtime.solve import solve
from myriad.runtime.solvers import Ipopt
from myriad.runtime.solvers.interior_point import InteriorPoint
from myriad.runtime.transcriptions import MultipleShooting, SingleShooting
from myriad.runtime.transcriptions.nominal_scales import state_scale

pytestmark = pytest.mark.slow  # not in `make test-fast`: interior-point and IPOPT solves of every bounded spec

jax.config.update("jax_enable_x64", True)
SPECS = Path(__file__).parent.parent / "specs"


@pytest.mark.parametrize("solver", [Ipopt(), InteriorPoint()], ids=["ipopt", "interior_point"])
def test_soft_bounds_keep_a_feasible_optimum(solver):
    # Bacteria's optimum sits on its final-state bound x(T) <= 10 (a non-zero multiplier): the elastic rows with a
    # penalty above it change neither the plan nor the cost beyond the solver's tolerance.
    system = load("bacteria")
    hard = solve(system, SingleShooting(intervals=40), solver, resimulate=False)
    soft = solve(system, SingleShooting(intervals=40, soft_state_bounds=10 * abs(float(hard.cost))), solver,
                 resimulate=False)
    assert hard.converged and soft.converged
    assert abs(float(soft.cost) - float(hard.cost)) <= 1e-7 * abs(float(hard.cost))
    np.testing.assert_allclose(soft.controls, hard.controls, atol=1e-5)
    assert float(soft.states[-1, 0]) == pytest.approx(10.0, abs=1e-6)


@pytest.mark.parametrize("solver", [Ipopt(), InteriorPoint()], ids=["ipopt", "interior_point"])
def test_soft_bounds_violate_an_unreachable_bound_least(solver):
    system = load(SPECS / "final_bound_unreachable.yaml")
    hard = solve(system, SingleShooting(intervals=20), solver, resimulate=False)
    assert not hard.converged  # x(1) >= 1 > 0.5 whatever u does
    rho = 3.0
    tr = SingleShooting(intervals=20, soft_state_bounds=rho)
    soft = solve(system, tr, solver, resimulate=False)
    assert soft.converged, soft.message
    # Least violation: u = 0, x(1) = 1, the slack n = (1 - 0.5) / s, the cost rho n (the integral of u^2 is 0).
    np.testing.assert_allclose(soft.controls, 0.0, atol=1e-6)
    assert float(soft.states[-1, 0]) == pytest.approx(1.0, abs=1e-6)
    n = 0.5 / float(state_scale(system)[0])
    assert float(soft.cost) == pytest.approx(rho * n, rel=1e-6)


def test_soft_bounds_layout_and_arguments():
    system = load("predator_prey")  # x and y bounded at the final node, z required
    hard, soft = SingleShooting(intervals=10), SingleShooting(intervals=10, soft_state_bounds=5.0)
    nh, ns = hard.transcribe(system), soft.transcribe(system)
    assert ns.n_variables == nh.n_variables + 4 and ns.n_constraints == nh.n_constraints
    sample = soft.sample(system, None, lambda t: np.full((np.size(t), 1), 0.5))
    assert sample.shape == (ns.n_variables,) and np.all(sample[-4:] == 0.0)
    for bad in (0.0, -1.0, float("inf"), True, "10"):
        with pytest.raises(ValueError, match="soft_state_bounds"):
            SingleShooting(soft_state_bounds=bad)
    with pytest.raises(ValueError, match="soft_state_bounds"):
        E2EConfig(model="node", soft_state_bounds=-2.0)
    with pytest.raises(ValueError, match="SingleShooting"):
        run_e2e("predator_prey", E2EConfig(soft_state_bounds=10.0), transcription=MultipleShooting(intervals=10))
