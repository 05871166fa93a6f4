"""The functional RL environment: the episode contract (observation, reward, terminal penalty, termination and
truncation, automatic reset), against the simulator; parameters as data under jit and vmap; random starts; actions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load, simulate
from myriad.runtime.integrators import RK4, Adaptive, Heun
from myriad.runtime.rl import Env, EnvOptions, make_jax, play
from myriad.runtime.transcriptions.nominal_scales import state_scale

from ...helpers import ROOT

KEY = jax.random.PRNGKey(0)


def _episode(env, action, params=None, steps=None):
    """Step an env with a constant action from a reset; returns the per-step outputs as lists."""
    params = env.default_params() if params is None else params
    obs, state = env.reset(KEY, params)
    out = []
    step = jax.jit(env.step)
    for _ in range(steps or env.options.steps):
        obs, state, reward, terminated, truncated, info = step(KEY, state, jnp.asarray(action), params)
        out.append((obs, state, float(reward), bool(terminated), bool(truncated), info))
    return out


@pytest.mark.parametrize("substeps", [1, 3])
def test_return_is_minus_the_simulated_cost_under_a_constant_control(substeps):
    # A constant control is the same signal held (the env) or interpolated (simulate): both integrate it alike.
    system = load("van_der_pol")
    env = make_jax(system, steps=20, substeps=substeps, penalty=0.0, normalize_actions=False)
    u = np.array([0.3])
    ep = play(env, np.tile(u, (20, 1)), env.default_params())
    sim = simulate(system, np.tile(u, (20 * substeps + 1, 1)), integrator=Heun())
    np.testing.assert_allclose(float(ep.cost), float(sim.cost), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(ep.states[-1]), np.asarray(sim.states[-1]), rtol=1e-12)


def test_episode_contract_observation_time_to_go_termination_and_terminal_penalty():
    system = load("van_der_pol")  # x(T) = (0, 0) required
    env = make_jax(system, steps=10, normalize_actions=False)
    steps = _episode(env, [0.0])
    obs0, _ = env.reset(KEY, env.default_params())
    np.testing.assert_array_equal(np.asarray(obs0), [0.0, 1.0, 10.0])  # x0, then T - 0
    assert [s[3] for s in steps] == [False] * 9 + [True] and not any(s[4] for s in steps)
    final = steps[-1][5]
    assert float(final["final_observation"][-1]) == 0.0  # the observation that reached T
    to_go = [float(s[5]["final_observation"][-1]) for s in steps]
    np.testing.assert_allclose(to_go, 10.0 - np.arange(1, 11), atol=1e-12)
    # Auto-reset: the returned observation and state are the next episode's first.
    np.testing.assert_array_equal(np.asarray(steps[-1][0]), np.asarray(obs0))
    assert int(steps[-1][1].k) == 0
    # The penalty comes once, at T: w * sum ((x_i(T) - 0) / 4)^2 with w = 100 * |2.87|.
    xT = np.asarray(final["final_observation"][:2])
    assert [float(s[5]["penalty"]) for s in steps[:-1]] == [0.0] * 9
    np.testing.assert_allclose(float(final["penalty"]), 287.0 * np.sum((xT / 4.0) ** 2), rtol=1e-12)
    np.testing.assert_allclose(steps[-1][2], -(float(final["running_cost"]) + float(final["penalty"])), rtol=1e-12)


def test_final_state_bounds_are_penalised_at_T_and_only_reported_on_the_way():
    system = load("bacteria")  # maximise; x(T) <= 10 is the published constraint a policy could break
    env = make_jax(system, steps=10, normalize_actions=False)
    steps = _episode(env, [2.0])  # the largest dose drives x far above 10
    xT = float(steps[-1][5]["final_observation"][0])
    assert xT > 10.0
    w = 100.0 * 7.98
    np.testing.assert_allclose(float(steps[-1][5]["penalty"]), w * ((xT - 10.0) / 10.0) ** 2, rtol=1e-12)
    over = [float(s[5]["bound_violation"]) for s in steps]
    assert over[-1] == pytest.approx((xT - 10.0) / 10.0) and all(p == 0.0 for p in
                                                                  [float(s[5]["penalty"]) for s in steps[:-1]])


def test_a_shorter_limit_truncates_without_the_terminal_cost():
    env = make_jax("van_der_pol", steps=10, max_steps=4, normalize_actions=False)
    steps = _episode(env, [0.0], steps=4)
    assert [s[4] for s in steps] == [False, False, False, True] and not any(s[3] for s in steps)
    assert float(steps[-1][5]["penalty"]) == 0.0 and int(steps[-1][1].k) == 0  # reset after the truncation


def test_maximisation_reward_is_the_payoff():
    # Simple Case maximises int (A x - B u^2) dt: with u = 0, x stays positive, so every reward is positive.
    system = load("simple_case")
    assert system.sense == "maximize"
    env = make_jax(system, steps=10, normalize_actions=False)
    ep = play(env, np.zeros((10, 1)), env.default_params())
    assert np.all(np.asarray(ep.rewards) > 0)
    xs = np.asarray(ep.states)[:, 0]
    payoff_heun = np.sum(0.1 * 0.5 * (xs[:-1] + (xs[:-1] - 0.1 * 0.5 * xs[:-1] ** 2)))  # A = 1, L at the predictor
    np.testing.assert_allclose(float(ep.total), payoff_heun, rtol=1e-12)


def test_parameters_are_data_one_vmap_steps_differently_parameterised_envs():
    env = make_jax("van_der_pol", normalize_actions=False)
    a = jnp.array([0.5, 1.0, 1.5])
    base = env.default_params()
    batch = base._replace(params={"a": a}, x0=jnp.broadcast_to(base.x0, (3, 2)))
    step = jax.jit(jax.vmap(env.step))
    obs, state = jax.vmap(env.reset)(jax.random.split(KEY, 3), batch)
    actions = jnp.full((3, 1), 0.4)
    for _ in range(3):
        obs, state, reward, *_ = step(jax.random.split(KEY, 3), state, actions, batch)
    for i in range(3):
        ep = play(env, jnp.full((3, 1), 0.4), env.default_params(params={"a": float(a[i])}))
        np.testing.assert_allclose(np.asarray(state.x[i]), np.asarray(ep.states[-1]), rtol=1e-13)
    assert len({float(x) for x in state.x[:, 0]}) == 3
    # New parameter values are data: the compiled step is reused.
    step(jax.random.split(KEY, 3), state, actions, batch._replace(params={"a": a + 0.1}))
    assert step._cache_size() == 1


def test_random_starts_perturb_x0_within_the_state_bounds():
    system = load("cancer_treatment")  # x0 = 0.975 within [0.001, 1]: the upper bound clips
    env = make_jax(system, start_noise=0.5)
    params = env.default_params()
    starts = np.asarray(jax.jit(jax.vmap(env.reset, (0, None)))(jax.random.split(KEY, 64), params)[1].x)[:, 0]
    assert len(set(starts)) > 10 and starts.min() >= 0.001 and starts.max() <= 1.0 and np.any(starts == 1.0)
    assert np.all(np.abs(starts - 0.975) <= 0.5 * state_scale(system)[0] + 1e-15)
    quiet = make_jax(system)
    assert float(quiet.reset(KEY, params)[1].x[0]) == 0.975


def test_actions_are_clipped_and_normalised_onto_the_control_bounds():
    env = make_jax("van_der_pol")  # u in [-0.75, 1]
    for a, u in ((-1.0, -0.75), (1.0, 1.0), (0.0, 0.125), (3.0, 1.0), (-7.0, -0.75)):
        assert float(env.control(jnp.array([a]))[0]) == pytest.approx(u, abs=1e-15)
    native = make_jax("van_der_pol", normalize_actions=False)
    assert float(native.control(jnp.array([2.0]))[0]) == 1.0 and float(native.control(jnp.array([0.3]))[0]) == 0.3
    with pytest.raises(ValueError, match="double_integrator: control.*u.*no finite bounds.*action_bound"):
        make_jax(ROOT / "tests/runtime/specs/double_integrator.yaml")
    # Simple Case's unbounded control has a default bound, 2 (twice its optimal control's largest magnitude).
    assert make_jax("simple_case").options == EnvOptions(action_bound=2.0)
    assert float(make_jax("simple_case").control(jnp.array([1.0]))[0]) == 2.0
    assert float(make_jax("simple_case", action_bound=5.0).control(jnp.array([-1.0]))[0]) == -5.0


def test_a_spec_that_does_not_ship_is_an_environment():
    env = make_jax(ROOT / "tests/runtime/specs/double_integrator.yaml", action_bound=10.0, steps=50)
    t = (np.arange(50) + 0.5) / 50
    ep = play(env, (6.0 - 12.0 * t)[:, None] / 10.0, env.default_params())  # u* = 6 - 12 t, normalised by 10
    assert float(ep.cost) == pytest.approx(12.0, rel=1e-2)  # J* = 12, and the final values are met


def test_options_are_checked():
    for bad in ({"integrator": Adaptive()}, {"integrator": "nope"}, {"steps": 0}, {"max_steps": 101},
                {"penalty": -1.0}, {"action_bound": 0.0}):
        with pytest.raises(ValueError):
            EnvOptions(**bad)
    assert EnvOptions(integrator="rk4").integrator == RK4()
    assert hash(Env(load("pendulum"))) == hash(Env(load("pendulum"), EnvOptions()))  # a static jit argument
