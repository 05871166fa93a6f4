"""The gymnax adapter (``myriad.runtime.rl.gymnax``): the same steps as the functional env, and a real trainer step.

gymnax, flax and rejax are the optional extra ``rl`` (not in ``make setup``): without them this module is skipped.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("gymnax")
pytest.importorskip("flax")

from myriad.runtime.rl import Env, EnvOptions, make_jax  # noqa: E402
from myriad.runtime.rl.gymnax import GymnaxEnv, GymnaxParams  # noqa: E402


def test_steps_are_the_functional_envs():
    env = make_jax("van_der_pol")
    g = GymnaxEnv(env, dtype=jnp.float64)
    params = g.default_params
    assert isinstance(params, GymnaxParams) and params.max_steps_in_episode == env.options.steps
    key = jax.random.PRNGKey(0)
    obs, state = g.reset(key, params)
    ref_obs, ref_state = env.reset(key, env.default_params())
    np.testing.assert_array_equal(obs, ref_obs)
    for k in range(env.options.steps):
        action = jnp.full((env.action_size,), 0.5 * np.sin(k))
        obs, state, reward, done, _ = g.step_env(key, state, action, params)
        ref_obs, ref_state, ref_reward, terminated, truncated, _ = env.step_env(ref_state, action, env.default_params())
        np.testing.assert_array_equal(obs, ref_obs)
        assert float(reward) == float(ref_reward) and bool(done) == bool(terminated | truncated)
    assert bool(done)  # the last step ends the episode
    # gymnax's own step resets on done: the next observation is the start's.
    obs, _, _, done, _ = g.step(key, state, jnp.zeros(env.action_size), params)
    np.testing.assert_array_equal(obs, g.reset(key, params)[0])


def test_spaces_hash_and_float32_params():
    env = Env(make_jax("van_der_pol").system, EnvOptions(steps=10))
    g = GymnaxEnv(env)
    assert g == GymnaxEnv(env) and hash(g) == hash(GymnaxEnv(env)) and g != GymnaxEnv(env, jnp.float64)
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree.leaves(g.default_params))
    action, observation = g.action_space(), g.observation_space()
    assert action.shape == (env.action_size,) and float(action.low) == -1.0 and float(action.high) == 1.0
    assert observation.shape == (env.observation_size,)
    assert np.all(np.isfinite(observation.low)) and np.all(np.isfinite(observation.high))
    raw = GymnaxEnv(Env(env.system, EnvOptions(steps=10, normalize_actions=False))).action_space()
    np.testing.assert_array_equal(raw.low, env.control_bounds[0].astype(np.float32))


def test_rejax_trains_on_it():
    """A real trainer step: rejax's PPO, four updates of 16 steps on the published grid, gives finite parameters
    (on a coarse grid, 8 steps, random actions make Heun's rollout blow up: that is the env, not the adapter)."""
    rejax = pytest.importorskip("rejax")
    g = GymnaxEnv(make_jax("van_der_pol"))
    algo = rejax.PPO.create(env=g, env_params=g.default_params, total_timesteps=64, eval_freq=64, num_envs=2,
                            num_steps=8, num_epochs=1, num_minibatches=2, skip_initial_evaluation=True)
    # As bench/rl_baselines.py trains (rejax's statistics are in the default dtype), with the standard promotion
    # rules: rejax's own code mixes bool and int (`1 - done`), which the suite's strict rules refuse.
    with jax.enable_x64(False), jax.numpy_dtype_promotion("standard"):
        ts, _ = jax.jit(algo.train)(jax.random.PRNGKey(0))
    leaves = jax.tree.leaves(ts.actor_ts.params)
    assert leaves and all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in leaves)
    assert int(ts.global_step) >= 64
