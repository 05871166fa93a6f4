"""The MPC baseline (runtime/rl/mpc.py) and its sweep kind: the closed loop reaches the open-loop optimum on the
nominal model, the planner is the env's own problem, the shrinking-horizon re-plan is the tail of the full plan, and
disturbances are seeded and applied to the planner only."""

import math

import jax
import numpy as np
import pytest

from myriad.runtime.loader import load
from myriad.runtime.rl.env import play
from myriad.runtime.rl.mpc import MPC, mismatched_params
from myriad.runtime.rl.reference import normalized_score, reference_env, reference_scores
from myriad.runtime.sweep import SweepConfig
from myriad.runtime.sweep.tasks import run

# Two cheap systems: Simple Case (one state, an unbounded control with the reference's action bound) and Van der Pol
# (two states, required final values, which the env's terminal penalty prices).
CHEAP = ["simple_case", "van_der_pol"]


@pytest.fixture(scope="module")
def nominal():
    out = {}
    for name in CHEAP:
        env = reference_env(load(name))
        mpc = MPC(env, replan_every=10)
        out[name] = (env, mpc, mpc.run(env.default_params()))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", CHEAP)
def test_nominal_mpc_reaches_the_open_loop_optimum(nominal, name):
    env, _, ep = nominal[name]
    j_opt = reference_scores()["systems"][name]["optimal"]["cost"]
    assert ep.replans == 10 and ep.failures == 0
    # Within 1 % of the optimum's cost (the planner and the reference solve the same env problem; the reference's
    # is certified): measured simple_case -1.354349 vs -1.354349, van_der_pol 2.87849 vs 2.878491 (format 1's
    # transcription controls cost 2.93130).
    assert ep.cost <= j_opt + 0.01 * abs(j_opt)
    assert normalized_score(name, ep.cost) >= 99.0
    # Without disturbances the closed loop is its own controls played open loop.
    replay = play(env, ep.controls, env.default_params())
    assert math.isclose(float(replay.cost), ep.cost, rel_tol=1e-12, abs_tol=1e-12)
    np.testing.assert_allclose(np.asarray(replay.states), ep.states, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_the_plan_is_the_env_cost_and_a_replan_is_the_tail_of_the_plan(nominal):
    env, mpc, _ = nominal["van_der_pol"]
    data = env.default_params()
    plan, res = mpc.plan(env.system.x0, 0, mpc.initial_plan())
    assert res.success
    # The planner's objective is the env's cost of its controls (same steps, integrator and terminal penalty).
    assert math.isclose(res.objective, float(play(env, plan, data).cost), rel_tol=1e-9)
    # Re-planning at step k from the state the plan reaches gives the plan's own tail (principle of optimality):
    # the controls already played are held apart and do not couple to the rest.
    k = 40
    x_k = np.asarray(play(env, plan[:k], data).states[-1])
    scrambled = mpc.initial_plan()  # a cold start for the tail, and other values for the controls already played
    scrambled[:k] = 0.3
    tail, res_k = mpc.plan(x_k, k, scrambled)
    assert res_k.success
    np.testing.assert_array_equal(tail[:k], scrambled[:k])
    np.testing.assert_allclose(tail[k:], plan[k:], atol=1e-4)


@pytest.mark.slow
def test_disturbed_episodes_are_seeded_and_share_the_compiled_planner(nominal):
    env, mpc, ep = nominal["simple_case"]
    data = env.default_params()
    noisy = [mpc.run(data, obs_noise=0.05, seed=s) for s in (1, 1, 2)]
    assert noisy[0].cost == noisy[1].cost != noisy[2].cost
    assert all(e.compile_seconds == 0 for e in noisy)
    env_v, _, _ = nominal["van_der_pol"]
    p = mismatched_params(env_v, 0.1, seed=0)
    assert math.isclose(abs(float(p["a"]) - 1.0), 0.1)  # Van der Pol's one learnable parameter, off by 10 %
    off = MPC(env_v, p, replan_every=10)
    assert off.nlp is nominal["van_der_pol"][1].nlp  # parameters are data: no second planner to compile
    wrong = off.run(env_v.default_params())
    assert wrong.compile_seconds == 0 and wrong.failures == 0
    # The planner's model is wrong, the env is not: the plan's predicted end state is not where the env ends.
    assert wrong.cost != nominal["van_der_pol"][2].cost
    assert normalized_score("van_der_pol", wrong.cost) < normalized_score("van_der_pol", nominal["van_der_pol"][2].cost)


@pytest.mark.slow
def test_constraint_terminal_meets_the_final_values():
    env = reference_env(load("van_der_pol"))
    ep = MPC(env, replan_every=25, terminal="constraint").run(env.default_params())
    j_opt = reference_scores()["systems"]["van_der_pol"]["optimal"]["cost"]
    assert ep.failures == 0 and ep.cost <= j_opt + 0.01 * abs(j_opt)
    np.testing.assert_allclose(ep.states[-1], [0.0, 0.0], atol=1e-6)
    assert 0 <= ep.penalty < 1e-10


def test_bad_options_are_refused():
    env = reference_env(load("simple_case"))
    with pytest.raises(ValueError, match="replan_every"):
        MPC(env, replan_every=0)
    with pytest.raises(ValueError, match="terminal"):
        MPC(env, terminal="soft")
    with pytest.raises(ValueError, match="replan_every"):
        SweepConfig(["simple_case"], ["mpc:replan_every=0"])
    with pytest.raises(ValueError, match="solver_options"):
        SweepConfig(["simple_case"], ['mpc:solver_options={"no_such_option":1}'])


def test_sweep_kind_records_the_score():
    config = SweepConfig(["simple_case"], ["mpc:replan_every=20", "noisy=mpc:replan_every=20,obs_noise=0.05"],
                         seeds=[3], cache_dir=None)
    nominal, noisy = (run(t) for t in config.tasks())
    assert nominal["status"] == "ok" and nominal["replans"] == 5 and nominal["failures"] == 0
    assert nominal["normalized_score"] >= 99.0 and abs(nominal["relative_gap"]) < 0.01
    assert noisy["status"] == "ok" and noisy["cost"] != nominal["cost"]
    assert jax.numpy.isfinite(noisy["normalized_score"])
