"""MPC under a schema 3 spec's declared uncertainty (issue 30 item 4): ``perturbed`` draws the true parameters from
their distributions and runs the declared noise instead of the hard-coded perturbations; older specs keep those,
unchanged; the planner stays nominal and noise-free; an episode is the env's own (replaying its controls in the same
env from the same key gives its states)."""

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pytest

from myriad.runtime.loader import load
from myriad.runtime.rl.env import Env, EnvOptions, play
from myriad.runtime.rl.mpc import MPC, mismatched_params, perturbed
from myriad.runtime.rl.reference import reference_env
from myriad.runtime.sweep import SweepConfig
from myriad.runtime.sweep.tasks import run

SPEC = str(Path(__file__).parents[2] / "compiler" / "schema3" / "uncertain_oscillator.yaml")
CERTAIN = str(Path(__file__).with_name("certain_oscillator.yaml"))  # the same system, schema 1
SHORT = EnvOptions(steps=20)  # 20 actions, a re-plan every 10: two small NLPs


@pytest.fixture(scope="module")
def env():
    return reference_env(load(SPEC), SHORT)


def test_older_specs_keep_the_hard_coded_perturbations():
    env = reference_env(load(CERTAIN), SHORT)
    played, params, obs_noise = perturbed(env, 0.1, 0.05, seed=3)
    assert played is env and obs_noise == 0.05
    assert {k: float(v) for k, v in params.items()} == {k: float(v) for k, v in mismatched_params(env, 0.1, 3).items()}
    assert perturbed(env, 0.0, 0.0) == (env, None, 0.0)


def test_the_declared_uncertainty_replaces_them(env):
    played, params, obs_noise = perturbed(env, 0.1, 0.0, seed=3)
    assert played.randomized and played.process_sigma is None and params is None and obs_noise == 0.0
    played, params, obs_noise = perturbed(env, 0.0, 0.05, seed=3)
    assert not played.randomized and params is None and obs_noise == 0.0
    np.testing.assert_array_equal(played.process_sigma, [0.0, 0.05])
    np.testing.assert_array_equal(played.observation_std, [0.01, 0.02])
    played, params, obs_noise = perturbed(env, 0.1, 0.05, seed=3, declared=False)  # the hard-coded ones asked for
    assert played is env and params is not None and obs_noise == 0.05


@pytest.mark.slow  # two short closed-loop episodes (the planner compiles once)
def test_episodes_play_the_drawn_parameters_and_the_declared_noise(env):
    data = env.default_params()
    randomized, _, _ = perturbed(env, 0.1, 0.0)
    mpc = MPC(randomized, replan_every=10)
    assert not mpc.model.randomized and mpc.model.process_sigma is None and mpc.model.observation_std is None
    ep = mpc.run(data, seed=5)
    assert ep.failures == 0 and 1.5 <= ep.theta[0] <= 2.5
    np.testing.assert_array_equal(ep.theta, randomized.reset(jax.random.PRNGKey(5), data)[1].theta)
    # The truth is the drawn parameters: the controls replayed at those fixed values give the episode's states.
    fixed = Env(randomized.system, dataclasses.replace(randomized.options, randomize=False))
    replay = play(fixed, ep.controls, fixed.default_params(dict(zip(("k", "c"), ep.theta))))
    np.testing.assert_allclose(replay.states, ep.states, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(float(replay.cost), ep.cost, rtol=1e-12)

    noisy, _, _ = perturbed(env, 0.0, 0.05)
    quiet = MPC(noisy, replan_every=10)
    assert quiet.nlp is mpc.nlp  # the planner is the nominal, noise-free problem either way
    first, again, other = (quiet.run(data, seed=s) for s in (1, 1, 2))
    assert first.cost == again.cost != other.cost and first.theta is None
    replay = play(noisy, first.controls, data, jax.random.PRNGKey(1))  # the env's own noise stream
    np.testing.assert_allclose(replay.states, first.states, rtol=1e-12, atol=1e-12)
    nominal = MPC(env, replan_every=10).run(data)
    assert np.max(np.abs(first.states - nominal.states)) > 1e-3


@pytest.mark.slow  # two sweep tasks of 100-step episodes, two re-plans each
def test_sweep_kind_records_the_declared_draw():
    config = SweepConfig([SPEC], ["mpc:replan_every=50,mismatch=0.1",
                                  "hard=mpc:replan_every=50,mismatch=0.1,declared=false"], seeds=[2], cache_dir=None)
    declared, hard = (run(t) for t in config.tasks())
    assert declared["status"] == "ok" and hard["status"] == "ok", (declared["message"], hard["message"])
    assert declared["declared"]["parameters"] and not declared["declared"]["noise"]
    assert set(declared["declared"]["theta"]) == {"k", "c"} and "declared" not in hard
    assert declared["cost"] != hard["cost"]
