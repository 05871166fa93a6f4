"""The Gymnasium adapter: every shipped id, Simple Case with its default action bound and specs that do not ship
(registered by rl.make: a spec, gymnasium.make and make_vec) pass Gymnasium's checks with warnings as errors; ids,
spaces, the action-bound refusal, rendering, and the vector env against the core."""

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import myriad.runtime.rl as rl
from myriad.runtime import load
from myriad.runtime.rl.gym import MyriadVectorEnv
from myriad.runtime.systems import NAMES

from ...helpers import ROOT


def _check_through_make(ident, **options):
    """Gymnasium's checks as a user meets them: ``gymnasium.make`` (the passive checker on), a few steps, a
    render, then ``check_env`` on the unwrapped env (it remakes the env from its spec for the render modes)."""
    env = gymnasium.make(ident, render_mode="rgb_array", **options)
    assert env.spec.id == ident and env.unwrapped.spec.id == ident
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    assert env.render().dtype == np.uint8
    check_env(env.unwrapped)
    return env


@pytest.mark.slow
@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name", NAMES)
def test_every_shipped_system_passes_the_gymnasium_checker(name):
    env = _check_through_make(rl.env_id(name))  # no options: Simple Case's default action bound included
    assert env.observation_space.dtype == np.float32 and env.action_space.dtype == np.float32
    assert env.observation_space.shape == (load(name).n_states + 1,)


@pytest.mark.filterwarnings("error")
def test_simple_case_and_a_spec_that_does_not_ship_pass_the_checker():
    assert _check_through_make("myriad/SimpleCase-v0").unwrapped.core.options.action_bound == 2.0
    path = ROOT / "tests/runtime/specs/double_integrator.yaml"  # unbounded states and control
    env = rl.make(path, action_bound=20.0, render_mode="rgb_array")
    assert env.render_mode == "rgb_array" and env.system.name == "double_integrator"
    assert env.spec.id == f"myriad-spec/DoubleIntegrator-{load(path).spec_sha256[:8]}-v0"
    assert env.spec.kwargs == {"system": str(path.resolve()), "action_bound": 20.0, "render_mode": "rgb_array"}
    check_env(env)
    _check_through_make(env.spec.id, action_bound=20.0)


@pytest.mark.filterwarnings("error")
def test_any_spec_is_registered_by_make_so_gymnasium_builds_it(tmp_path):
    copy = tmp_path / "simple_case.yaml"  # a copy of a shipped spec: its own id, the shipped default action bound
    copy.write_text((ROOT / "specs/simple_case.yaml").read_text())
    env = rl.make(copy, steps=20)
    ident = env.spec.id
    assert ident == f"myriad-spec/SimpleCase-{load('simple_case').spec_sha256[:8]}-v0" and ident in gymnasium.registry
    assert rl.register(copy) == ident and rl.register(str(copy)) == ident  # idempotent
    assert rl.register("simple_case") == rl.register(load("simple_case")) == "myriad/SimpleCase-v0"
    np.testing.assert_array_equal(env.core.control_bounds, ([-2.0], [2.0]))
    check_env(env)
    # The same problem from its id, single and vectorised, step for step.
    single = gymnasium.make(ident, steps=20)
    envs = gymnasium.make_vec(ident, num_envs=2, vectorization_mode="vector_entry_point", steps=20)
    assert isinstance(envs, MyriadVectorEnv) and envs.spec.id == ident
    obs, _ = envs.reset(seed=0)
    np.testing.assert_array_equal(single.reset(seed=0)[0], obs[0])
    for a in np.linspace(-1.0, 1.0, 20):
        obs, reward, terminated, *_ = envs.step(np.full((2, 1), a, np.float32))
        _, r, done, *_ = single.step(np.float32([a]))
        np.testing.assert_allclose(reward, [r, r], rtol=1e-12)
    assert done and terminated.all()
    # The content names the id: an edited spec is a new one, and its system object maps to it too.
    copy.write_text(copy.read_text().replace("C: {value: 4", "C: {value: 3"))
    edited = rl.register(copy)
    assert edited != ident and edited.startswith("myriad-spec/SimpleCase-") and rl.register(load(copy)) == edited
    # A peer problem by name, with options.
    peer = rl.make("peers/catalyst_mixing", steps=10)
    assert peer.spec.id.startswith("myriad-spec/CatalystMixing-")
    assert peer.spec.kwargs == {"system": "peers/catalyst_mixing", "steps": 10}
    check_env(peer)


def test_ids_are_the_generated_class_names_and_all_are_registered():
    for name in NAMES:
        ident = rl.env_id(name)
        assert ident == f"myriad/{type(load(name)).__name__}-v0" and ident in gymnasium.registry
        assert gymnasium.registry[ident].max_episode_steps is None  # no TimeLimit: reaching T is terminated
    assert rl.env_id("van_der_pol") == "myriad/VanDerPol-v0"


def test_an_unbounded_control_needs_an_action_bound_and_simple_case_has_a_default():
    path = ROOT / "tests/runtime/specs/double_integrator.yaml"
    with pytest.raises(ValueError, match="double_integrator.*control.*u.*action_bound"):
        rl.make(path)
    with pytest.raises(ValueError, match="action_bound"):
        rl.make(path, normalize_actions=False)
    np.testing.assert_array_equal(rl.make("simple_case", normalize_actions=False).action_space.low, [-2.0])
    env = rl.make("simple_case", action_bound=5.0, normalize_actions=False)
    np.testing.assert_array_equal(env.action_space.high, [5.0])


def test_spaces_come_from_the_bounds_and_rewards_from_the_core():
    env = rl.make("van_der_pol", normalize_actions=False)
    np.testing.assert_array_equal(env.action_space.low, np.float32([-0.75]))
    np.testing.assert_array_equal(env.observation_space.high, np.float32([4.0, 4.0, 10.0]))
    obs, info = env.reset(seed=1)
    np.testing.assert_array_equal(obs, np.float32([0.0, 1.0, 10.0]))
    actions = np.linspace(-0.7, 0.9, 100)[:, None]
    rewards, ends = [], []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        rewards.append(reward)
        ends.append((terminated, truncated))
    assert ends == [(False, False)] * 99 + [(True, False)]
    ep = rl.play(env.core, actions, env.core.default_params())
    np.testing.assert_allclose(sum(rewards), float(ep.total), rtol=1e-12)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(actions[0])


def test_render_draws_the_traces_so_far():
    env = rl.make("cartpole", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(30):
        env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    assert np.count_nonzero(np.any(frame != first, axis=-1)) > 1000  # the traces moved on
    assert rl.make("cartpole").render() is None


def test_vector_env_steps_differently_parameterised_envs_as_the_core_does():
    a = np.array([0.5, 0.8, 1.1, 1.4])
    envs = gymnasium.make_vec("myriad/VanDerPol-v0", num_envs=4, vectorization_mode="vector_entry_point",
                              params={"a": a}, steps=50)
    assert isinstance(envs, MyriadVectorEnv) and envs.metadata["autoreset_mode"].value == "SameStep"
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (4, 3) and obs.dtype == np.float32
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (50, 4, 1)).astype(np.float32)
    total = np.zeros(4)
    for k in range(50):
        obs, reward, terminated, truncated, info = envs.step(actions[k])
        total += reward
    assert terminated.all() and not truncated.any() and info["_final_obs"].all()
    np.testing.assert_array_equal(obs[:, -1], np.float32(10.0))  # reset in the same step: t = 0 again
    assert np.all(info["final_obs"][:, -1] == 0.0)  # the observation that reached T
    for i in range(4):
        core = envs.core
        ep = rl.play(core, actions[:, i], core.default_params(params={"a": a[i]}))
        np.testing.assert_allclose(total[i], float(ep.total), rtol=1e-6)  # float32 actions, float64 sums
        np.testing.assert_allclose(info["final_obs"][i, :2], np.asarray(ep.states[-1]), rtol=1e-5)
    with pytest.raises(ValueError, match="num_envs"):
        MyriadVectorEnv("van_der_pol", num_envs=3, params={"a": a})
    assert jax.tree.leaves(envs.data)[0].shape[0] == 4
