"""The environment under a spec's uncertainty (schema 3's attributes on test systems, tests/runtime/uncertainty/):
parameters drawn at reset match their distributions and cost no recompilation; the Ornstein-Uhlenbeck env's x(T)
matches the closed form and its schemes' weak orders; observation noise; the Gymnasium adapter (check_env,
seeds reproduce bits); every option off is the deterministic env to the bit."""

import math

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import myriad.runtime.rl as rl
from myriad.runtime.rl import Env, EnvOptions, play
from myriad.runtime.rl.env import EnvState, expected_cost
from myriad.runtime.rl.gym import MyriadEnv, MyriadVectorEnv, _single

from ..uncertainty._systems import (
    FOUR,
    assert_mean_and_variance,
    assert_moments,
    declared,
    four_parameters,
    ornstein_uhlenbeck,
    ou_moments,
    plain,
)

KEY = jax.random.PRNGKey(0)
M = 10_000


def _final_states(env, n_paths, seed=0, chunk=1_000_000):
    """x(T) of ``n_paths`` episodes under zero control (action 0 is u = 0 on [-1, 1]), one vmapped program run on
    chunks of at most ``chunk`` episodes (each chunk its own key)."""
    actions = jnp.zeros((env.options.steps, 1))
    data = env.default_params()
    fn = jax.jit(jax.vmap(lambda k: play(env, actions, data, k).states[-1, 0]))
    sizes = [min(chunk, n_paths - i) for i in range(0, n_paths, chunk)]
    keys = [jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), i), n) for i, n in enumerate(sizes)]
    return np.concatenate([np.asarray(fn(k)) for k in keys])


@pytest.mark.parametrize("widen", [1.0, 2.0])
def test_parameters_drawn_at_reset_match_their_distributions_without_recompiling(widen):
    env = Env(four_parameters(), EnvOptions(steps=10, widen=widen, randomize=True))
    reset = jax.jit(jax.vmap(env.reset, (0, None)))
    data = env.default_params()
    _, state = reset(jax.random.split(KEY, M), data)
    assert_moments(state.theta, FOUR["uncertain_kinds"], FOUR["uncertain_args"], widen)
    one = jax.jit(env.reset)
    thetas = [np.asarray(one(jax.random.PRNGKey(i), data)[1].theta) for i in range(5)]
    assert len({t.tobytes() for t in thetas}) == 5 and one._cache_size() == 1  # new draws are data


def test_an_episode_runs_on_its_drawn_parameters_and_randomize_false_on_the_given_ones():
    system = four_parameters()
    env = Env(system, EnvOptions(steps=10, normalize_actions=False, randomize=True))
    data = env.default_params()
    _, state = env.reset(KEY, data)
    theta = np.asarray(state.theta)
    drawn = env.default_params(params=dict(zip(FOUR["uncertain_params"], theta.tolist())))
    fixed = Env(system, EnvOptions(steps=10, normalize_actions=False, randomize=False))
    assert not fixed.stochastic and fixed.reset(KEY, data)[1].theta is None
    a = jnp.array([0.3])
    ours = env.step_env(state, a, data)
    theirs = fixed.step_env(EnvState(x=state.x, k=state.k), a, drawn)
    np.testing.assert_array_equal(np.asarray(ours[0]), np.asarray(theirs[0]))
    assert float(ours[2]) == float(theirs[2])
    # the auto-reset of step draws the next episode's parameters
    last = EnvState(x=state.x, k=jnp.asarray(9, jnp.int32), theta=state.theta)
    nxt = env.step(jax.random.PRNGKey(1), last, a, data)[1]
    assert int(nxt.k) == 0 and not np.array_equal(np.asarray(nxt.theta), theta)


def test_every_option_off_steps_the_deterministic_env_to_the_bit():
    base = plain("four_parameters")
    noisy = four_parameters(process_noise=(0.0, 0.2), observation_noise=(0.1, 0.0))
    off = EnvOptions(steps=10, substeps=2, start_noise=0.2, randomize=False, process_noise_scale=0.0,
                     observation_noise_scale=0.0)
    actions = jax.random.uniform(KEY, (10, 1), minval=-1.0, maxval=1.0)
    for system in (base, noisy):
        env = Env(system, off)
        assert not env.stochastic and env.observation_bounds[0][0] == -5.0
        ep = play(env, actions, env.default_params(), jax.random.PRNGKey(4))
        ref = play(Env(base, off), actions, Env(base, off).default_params(), jax.random.PRNGKey(4))
        for a, b in zip(ep, ref):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_ornstein_uhlenbeck_x_T_has_the_closed_form_mean_and_variance():
    # dx = -2 x dt + dW, x(0) = 1, T = 1; stochastic Heun on 100 steps (h = 0.01: its bias ~1e-4 of the variance,
    # well inside the 3 standard errors, about 3e-2 of it, of 2 10^4 paths)
    env = Env(ornstein_uhlenbeck(), EnvOptions(steps=50, substeps=2))
    assert env.sde_scheme.label == "heun" and env.observation_bounds[0][0] == -np.inf
    assert_mean_and_variance(_final_states(env, 20_000), *ou_moments(2.0, 1.0, 1.0, 1.0))


@pytest.mark.parametrize("integrator, label", [("euler", "euler_maruyama"), ("heun", "heun")])
def test_the_env_steps_the_schemes_exact_moments_on_a_coarse_grid(integrator, label):
    # 2 steps of 2 substeps (theta h = 0.5): Monte Carlo against the scheme's own closed form, so the env's
    # substeps, times and increments are the scheme's
    env = Env(ornstein_uhlenbeck(), EnvOptions(steps=2, substeps=2, integrator=integrator))
    assert_mean_and_variance(_final_states(env, 100_000, seed=1), *ou_moments(2.0, 1.0, 1.0, 1.0, 4, label))


@pytest.mark.parametrize("integrator, label, order, grids", [("euler", "euler_maruyama", 1, (4, 8, 16)),
                                                             ("heun", "heun", 2, (2, 4, 8))])
def test_the_envs_weak_error_converges_at_the_stated_order(integrator, label, order, grids):
    # The env's x(T) is the scheme's on every grid of the convergence study (Monte Carlo within 3 standard errors of
    # the scheme's exact moments; 2.5 10^5 episodes: 3 standard errors 3e-3 of the mean, below the scheme's own
    # errors of 4e-3 to 3e-2 there), and those exact moments converge to the SDE's at the stated order on the last
    # pair (2.33, 2.14 for heun; 1.03, 1.09 for Euler), exactly. So the env's weak error converges at that order;
    # the Monte Carlo study of the observed orders themselves (4 10^6 episodes a grid): bench/sde_weak_order.py.
    exact = np.array(ou_moments(2.0, 1.0, 1.0, 1.0))
    errors = []
    for n in grids:
        scheme = ou_moments(2.0, 1.0, 1.0, 1.0, n, label)
        x = _final_states(Env(ornstein_uhlenbeck(), EnvOptions(steps=n, integrator=integrator)), 250_000, seed=n)
        assert_mean_and_variance(x, *scheme)
        errors.append(np.abs(np.array(scheme) - exact))
    observed = np.log2(errors[-2] / errors[-1])
    assert np.all(np.abs(observed - order) <= [0.5, 0.3]), observed
    assert errors[0][1] > errors[1][1] > errors[2][1]


def test_observation_noise_is_added_to_the_observed_states_only():
    system = declared("ornstein_uhlenbeck", observation_noise=(0.3,))
    env = Env(system, EnvOptions(steps=10))
    obs, state = jax.jit(jax.vmap(env.reset, (0, None)))(jax.random.split(KEY, M), env.default_params())
    obs = np.asarray(obs)
    assert np.all(np.asarray(state.x) == 1.0) and np.all(obs[:, 1] == 1.0)  # the state and the time to go: exact
    assert_mean_and_variance(obs[:, 0], 1.0, 0.09)
    assert env.observation_bounds[1][0] == np.inf
    one = EnvState(x=state.x[0], k=state.k[0], key=state.key[0])
    obs1, nxt, *_ = env.step_env(one, jnp.zeros(1), env.default_params())
    assert float(obs1[0]) != float(nxt.x[0]) and float(obs1[1]) == 0.9  # a noisy reading of x_1; t exact


def test_options_are_checked():
    with pytest.raises(ValueError, match="integrator='heun'.*process_noise_scale=0"):
        Env(ornstein_uhlenbeck(), EnvOptions(integrator="rk4"))
    Env(ornstein_uhlenbeck(), EnvOptions(integrator="rk4", process_noise_scale=0.0))  # no noise, any integrator
    for bad in ({"widen": -1.0}, {"process_noise_scale": np.inf}, {"observation_noise_scale": -0.1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            EnvOptions(**bad)
    with pytest.raises(ValueError, match="process_noise needs one finite non-negative level per state"):
        Env(declared("ornstein_uhlenbeck", process_noise=(0.1, 0.2)))


@pytest.mark.filterwarnings("error")
def test_a_randomised_noisy_env_passes_the_gymnasium_checker_and_seeds_reproduce_bits():
    system = four_parameters(process_noise=(0.0, 0.05), observation_noise=(0.01, 0.0))
    env = rl.make(system, steps=20, randomize=True)
    check_env(env)
    runs = []
    for seed in (3, 3, 4):
        obs, info = env.reset(seed=seed)
        out = [obs.tobytes(), repr(info)]
        rng = np.random.default_rng(0)
        for _ in range(20):
            o, r, *_ = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
            out += [o.tobytes(), repr(r)]
        runs.append(out)
    assert runs[0] == runs[1] and runs[0] != runs[2]
    assert set(info["params"]) == {"k", "c", "g", "m"} and env.episode_params["k"] == info["params"]["k"]
    wrapped = gymnasium.make(env.spec.id, steps=20, widen=2.0, randomize=True)  # passive checker on; keyword options
    wrapped.reset(seed=0)
    for _ in range(20):
        wrapped.step(wrapped.action_space.sample())
    assert wrapped.unwrapped.core.options.widen == 2.0
    for i in range(5):
        env.reset(seed=10 + i)
    assert _single(env.core)[0]._cache_size() == 1 and _single(env.core)[1]._cache_size() == 1


def test_the_vector_env_draws_per_env_and_reproduces_with_its_seed():
    envs = MyriadVectorEnv(four_parameters(), 4, steps=5, randomize=True)
    a, _ = envs.reset(seed=0)
    k = envs.episode_params["k"]
    b, _ = envs.reset(seed=0)
    np.testing.assert_array_equal(a, b)
    assert k.shape == (4,) and len(set(k.tolist())) == 4 and np.array_equal(envs.episode_params["k"], k)
    assert MyriadEnv(plain("four_parameters")).reset(seed=0)[1] == {}  # nothing drawn: no params in info
    assert math.isfinite(float(envs.step(np.zeros((4, 1)))[1][0]))


def test_expected_cost_is_the_closed_form_within_its_standard_error():
    # Zero control on the Ornstein-Uhlenbeck env: J = int_0^1 x^2 dt, E x(t)^2 = e^(-4t) + (1 - e^(-4t)) / 4, so
    # E J = 3 (1 - e^-4) / 16 + 1 / 4 (Heun's quadrature on 100 steps is off by ~1e-5, far inside the error)
    env = Env(ornstein_uhlenbeck(), EnvOptions(steps=100))
    mean, se = expected_cost(env, np.zeros((100, 1)), episodes=20_000, seed=3)
    exact = 3 * -math.expm1(-4.0) / 16 + 0.25
    assert abs(mean - exact) <= 3 * se and 0 < se < 5e-3
    assert expected_cost(Env(plain("ornstein_uhlenbeck"), EnvOptions(steps=10)), np.zeros((10, 1)))[1] < 1e-15
