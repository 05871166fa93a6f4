"""Consistency with the optimiser: its controls, played open loop in the environment on the same grid with the same
integrator, return minus its cost, to 1e-8 relative, on every shipped system.

The env holds each action over its step (zero-order hold); the transcriptions interpolate controls linearly between
nodes. Forward Euler reads only the control at the start of a step, so single shooting with Euler on N intervals is
the env's own problem: its controls u_0..u_{N-1} are the N actions (u_N acts on nothing), its cost is the same
running-cost state integrated by the same steps, and its final values are met to the solver's tolerance, so the
quadratic terminal penalty adds nothing measurable. With Heun (the published setting) the two parametrisations
differ by O(h) and no such identity holds; the env's Heun integration is checked against ``simulate`` under
constant controls in test_rl_env.py instead.
"""

import numpy as np
import pytest

from myriad.runtime import Euler, Ipopt, SingleShooting, load, solve
from myriad.runtime.rl import make_jax, play
from myriad.runtime.systems import NAMES

N = 100


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_open_loop_return_of_the_optimisers_controls_is_minus_its_cost(name):
    system = load(name)
    sol = solve(system, SingleShooting(intervals=N, integrator=Euler()), Ipopt(), resimulate=False)
    assert sol.converged, sol.message
    env = make_jax(system, steps=N, integrator=Euler(), normalize_actions=False)
    episode = play(env, np.asarray(sol.controls)[:-1], env.default_params())
    assert float(episode.total) == pytest.approx(-sol.cost, rel=1e-8, abs=1e-12)
    # The same trajectory, node by node (the env's states are the solver's).
    np.testing.assert_allclose(np.asarray(episode.states), sol.states, rtol=1e-9, atol=1e-9 * np.abs(sol.states).max())
