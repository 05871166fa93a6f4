"""Collecting episodes (runtime/datasets/collect.py, policies.py): every return is minus the env's cost of its
rollout replayed by ``rl.play``, the perturbations are seeded and stay inside their definitions, and the policies
sit where mathematics puts them: the optimal plan at the env's optimum (normalised 100), the interior point's plan
cost equal to the episode's cost and to IPOPT's closed-loop MPC, noise never better than the optimum, random near 0."""

import dataclasses

import jax
import numpy as np
import pytest

from myriad.runtime.datasets import Perturbation, PolicySettings, collect
from myriad.runtime.datasets.collect import collection_env, episode_data
from myriad.runtime.loader import load
from myriad.runtime.rl.env import Env, EnvOptions, play
from myriad.runtime.rl.reference import normalized_score
from myriad.runtime.transcriptions.nominal_scales import state_scale

SYSTEM = "van_der_pol"
PERTURB = Perturbation(start=0.2, params=0.1)


def _replayed_costs(eps, system):
    """Each episode's env cost, replayed from its actions and data by ``rl.play`` (an independent rollout)."""
    env = Env(system, dataclasses.replace(EnvOptions(**eps.info["options"]), start_noise=0.0))
    costs = []
    for e in range(len(eps)):
        data = env.default_params({k: v[e] for k, v in eps.params.items()}, eps.states[e, 0])
        costs.append(float(play(env, eps.actions[e], data).cost))
    return np.array(costs)


@pytest.fixture(scope="module")
def random_eps():
    return collect(SYSTEM, "random", episodes=4, seed=3, perturb=PERTURB)


def test_a_random_episode_returns_minus_the_env_cost_of_its_rollout(random_eps):
    system = load(SYSTEM)
    np.testing.assert_allclose(random_eps.returns, -_replayed_costs(random_eps, system), rtol=1e-6)
    E, T, n = len(random_eps), 100, system.n_states
    assert random_eps.observations.shape == (E, T + 1, n + 1) and random_eps.actions.shape == (E, T, 1)
    assert random_eps.states.shape == (E, T + 1, n) and random_eps.rewards.shape == (E, T)
    np.testing.assert_array_equal(random_eps.observations[..., :n], random_eps.states)
    np.testing.assert_allclose(random_eps.observations[:, 0, n], system.horizon)
    np.testing.assert_array_equal(random_eps.observations[:, -1, n], 0.0)
    assert random_eps.terminations[:, -1].all() and not random_eps.terminations[:, :-1].any()
    assert not random_eps.truncations.any()
    assert np.all(np.abs(random_eps.actions) <= 1.0) and random_eps.actions.std() > 0.4  # uniform on [-1, 1]


def test_the_same_seed_gives_the_same_episodes_and_another_seed_others(random_eps):
    again = collect(SYSTEM, "random", episodes=4, seed=3, perturb=PERTURB)
    for field in ("observations", "actions", "rewards", "states"):
        np.testing.assert_array_equal(getattr(again, field), getattr(random_eps, field))
    other = collect(SYSTEM, "random", episodes=4, seed=4, perturb=PERTURB)
    assert not np.allclose(other.states[:, 0], random_eps.states[:, 0])


def test_perturbations_stay_inside_their_definition_and_spare_structural_parameters():
    system = load(SYSTEM)
    env = collection_env(system, None, PERTURB)
    data = episode_data(env, 64, 0, PERTURB)
    x0 = np.asarray(env.default_params().x0)
    spread = np.abs(np.asarray(data.x0) - x0) / state_scale(system)
    assert spread.max() <= PERTURB.start + 1e-12 and spread.max() > 0.5 * PERTURB.start
    nominal = env.default_params().params
    for name in system.param_names:
        ratio = np.asarray(data.params[name]) / np.asarray(nominal[name])
        if name in system.structural_params:
            np.testing.assert_array_equal(ratio, 1.0)
        else:
            assert np.abs(ratio - 1).max() <= PERTURB.params + 1e-12
    same = episode_data(env, 64, 0, PERTURB)
    np.testing.assert_array_equal(np.asarray(same.x0), np.asarray(data.x0))


def test_a_truncated_env_records_truncations_and_episodes_of_max_steps():
    eps = collect(SYSTEM, "random", episodes=2, seed=0, options=EnvOptions(max_steps=30))
    assert eps.actions.shape[1] == 30 and eps.truncations[:, -1].all() and not eps.terminations.any()
    np.testing.assert_allclose(eps.returns, -_replayed_costs(eps, load(SYSTEM)), rtol=1e-6)


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"policy": "greedy"}, "unknown policy"),
    ({"episodes": 0}, "episodes"),
    ({"seed": -1}, "seed"),
    ({"options": EnvOptions(start_noise=0.1)}, "Perturbation(start"),
])
def test_bad_arguments_are_refused_naming_them(kwargs, words):
    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        collect(SYSTEM, **{"policy": "random", "episodes": 1, **kwargs})


@pytest.mark.parametrize("bad", [{"start": -0.1}, {"params": 1.0}, {"start": float("nan")}])
def test_a_bad_perturbation_is_refused(bad):
    with pytest.raises(ValueError, match="Perturbation"):
        Perturbation(**bad)


@pytest.mark.slow  # 100 random episodes: a few seconds; the mean's sampling error is what the bound allows
def test_the_random_policy_scores_near_zero():
    eps = collect(SYSTEM, "random", episodes=100, seed=1)
    scores = np.array([normalized_score(SYSTEM, -r) for r in eps.returns])
    # The reference's random cost is itself a 100-episode mean (another seed): allow both sampling errors, 3 sigma.
    assert abs(scores.mean()) < 3 * np.sqrt(2) * scores.std() / np.sqrt(len(scores)), scores.mean()


@pytest.fixture(scope="module")
def optimal_and_mpc():
    eps = collect(SYSTEM, "optimal", episodes=3, seed=0, perturb=PERTURB)
    mpc = collect(SYSTEM, "mpc", episodes=3, seed=0, perturb=PERTURB, settings=PolicySettings(replan_every=20))
    return eps, mpc


@pytest.mark.slow  # the batched interior point compiles (~20 s) and MPC re-plans with IPOPT
def test_the_optimal_plan_is_the_episodes_optimum_by_two_solvers(optimal_and_mpc):
    eps, mpc = optimal_and_mpc
    system = load(SYSTEM)
    assert eps.info["plan_status"] == ["converged"] * 3 and mpc.info["replan_failures"] == [0, 0, 0]
    np.testing.assert_allclose(eps.returns, -_replayed_costs(eps, system), rtol=1e-6)
    # The interior point's objective is the episode's cost: the planning problem is the env's own.
    np.testing.assert_allclose(eps.returns, -np.array(eps.info["plan_cost"]), rtol=1e-8)
    # IPOPT re-planning in closed loop on the true parameters reaches the same optimum, episode by episode.
    np.testing.assert_allclose(mpc.returns, eps.returns, rtol=1e-6)
    np.testing.assert_array_equal(mpc.states[:, 0], eps.states[:, 0])


@pytest.mark.slow
def test_action_noise_never_beats_the_optimum_and_zero_noise_is_the_optimum(optimal_and_mpc):
    eps, _ = optimal_and_mpc
    noisy = collect(SYSTEM, "noisy", episodes=3, seed=0, perturb=PERTURB, settings=PolicySettings(noise=0.05))
    assert np.all(noisy.returns <= eps.returns + 1e-9) and np.all(noisy.returns < eps.returns - 1e-6)
    assert np.abs(noisy.actions - eps.actions).max() > 0.05
    quiet = collect(SYSTEM, "noisy", episodes=3, seed=0, perturb=PERTURB, settings=PolicySettings(noise=0.0))
    np.testing.assert_array_equal(quiet.actions, eps.actions)


@pytest.mark.slow
@pytest.mark.parametrize("target", [SYSTEM, "specs/peers/lotka_volterra_fishing.yaml"])
def test_the_unperturbed_optimal_policy_scores_100(target, tmp_path, monkeypatch):
    monkeypatch.setenv("MYRIAD_RL_REFERENCE_CACHE", str(tmp_path))  # a spec that does not ship: computed here
    eps = collect(target, "optimal", episodes=2, seed=0)
    scores = [normalized_score(target, -r) for r in eps.returns]
    np.testing.assert_allclose(scores, 100.0, atol=0.5)
    np.testing.assert_array_equal(eps.returns[0], eps.returns[1])  # unperturbed: one problem twice
    assert jax.numpy.isfinite(eps.returns).all()
