"""Terminal re-aiming (runtime/learn/reaim.py): an aimed learned system plans to the shifted final values and is
another NLP; re-aiming a plan made on a wrong model brings the true system's final state to the required one."""

import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load, solve
from myriad.runtime.learn.dataset import Sampling
from myriad.runtime.learn.evaluate import evaluate
from myriad.runtime.learn.models import Parametric
from myriad.runtime.learn.reaim import observe, reaim
from myriad.runtime.sysid.run import SysidConfig
from myriad.runtime.transcriptions import SingleShooting, base


@pytest.fixture(scope="module")
def wrong():
    """Van der Pol (x(T) = 0 required) modelled with its damping 1 % off: the plan misses by 0.4 on the true system
    (with 3 % off, 1.06 -> 5.5e-3 in 4 re-aims, not monotone: successive plans move more)."""
    model = Parametric(load("van_der_pol"))
    return model, {"a": jnp.asarray(0.99)}


@pytest.mark.slow
def test_an_aimed_system_plans_to_the_shifted_final_values_and_is_another_problem(wrong):
    model, theta = wrong
    aim = np.array([0.05, -0.02])
    plain, aimed = model.as_system(theta), model.as_system(theta, aim)
    assert aimed != plain and hash(aimed) != hash(plain) and aimed == model.as_system(theta, aim.copy())
    assert aimed.x_final == (-0.05, 0.02) and plain.x_final == model.system.x_final
    sol = solve(aimed, resimulate=False)
    assert sol.converged
    np.testing.assert_allclose(sol.states[-1], -aim, atol=1e-6)  # in the model, the aimed values are met
    assert base.transcribe(aimed, SingleShooting()) is not base.transcribe(plain, SingleShooting())  # a new NLP
    with pytest.raises(ValueError, match="aim must be 2 finite numbers"):
        model.as_system(theta, [0.1])
    with pytest.raises(ValueError, match="aim must be 2 finite numbers"):
        model.as_system(theta, [0.1, np.nan])


@pytest.mark.slow
def test_reaiming_meets_the_true_final_values_that_the_plan_missed(wrong):
    model, theta = wrong
    first = evaluate(model, theta)
    assert first.converged and first.max_achieved_defect > 1e-2  # the wrong model's plan misses
    out = reaim(model, theta, first.plan, Sampling(), iterations=4, seed=0)
    assert out.misses[0] == pytest.approx(first.max_achieved_defect, rel=1e-9)  # noise-free observation
    assert first.max_achieved_defect > 0.1
    assert out.kept == int(np.argmin(out.misses)) == 4 and out.misses[out.kept] < 1e-4 * out.misses[0]
    again = evaluate(model, theta, plan=out.plan, optimum=first.optimum)
    assert again.max_achieved_defect == pytest.approx(out.misses[out.kept], rel=1e-9)
    assert "kept plan" in out.message and out.record()["kept"] == out.kept


@pytest.mark.slow
def test_reaiming_keeps_the_plan_when_nothing_is_required_at_the_end():
    model = Parametric(load("bioreactor"))  # no required final values
    theta = model.init_params()
    plan = evaluate(model, theta).plan
    out = reaim(model, theta, plan, Sampling(), iterations=3, seed=0)
    assert out.plan is plan and out.misses == () and "nothing to re-aim" in out.message


def test_observe_is_the_true_rollout_under_the_controls():
    system = load("van_der_pol")
    u = np.linspace(-0.5, 0.5, 101)
    obs = observe(system, Sampling(), u, seed=3)
    from myriad.runtime.simulate import simulate

    sim = simulate(system, u[:, None])
    np.testing.assert_allclose(obs.states[0], np.asarray(sim.states), rtol=0, atol=1e-12)


def test_reaim_defaults_and_bad_values():
    assert SysidConfig(model="node").reaim == 6 and SysidConfig().reaim == 0
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="reaim must be an integer >= 0"):
            SysidConfig(model="node", reaim=bad)


def test_cli_refuses_a_negative_reaim_before_work(capsys):
    from myriad.runtime.cli import main

    assert main(["sysid", "van_der_pol", "--model", "node", "--reaim", "-1"]) == 2
    assert "reaim must be an integer >= 0" in capsys.readouterr().err


@pytest.mark.slow
def test_end_to_end_evaluation_re_aims_with_the_learned_parameters(wrong):
    from myriad.runtime.e2e.config import E2EConfig
    model, theta = wrong
    params = {"spec": model.system.default_params(), "model": theta}
    expert = solve(model.system, resimulate=False)
    plain = evaluate(model, theta, optimum=expert, params=params)
    aimed = evaluate(model, theta, optimum=expert, params=params, reaim=4)
    assert plain.reaim is None and max(map(abs, plain.achieved_defect)) > 0.1
    assert max(map(abs, aimed.achieved_defect)) < 1e-4 * max(map(abs, plain.achieved_defect))
    assert aimed.record()["reaim"]["kept"] == aimed.reaim.kept
    # reaim judges, it does not train: a resumed run may change it
    assert E2EConfig(model="node").reaim == 6 and E2EConfig().reaim == 0
    assert E2EConfig(model="node", reaim=0).identity("x")[0] == E2EConfig(model="node").identity("x")[0]
    with pytest.raises(ValueError, match="reaim must be an integer >= 0"):
        E2EConfig(model="node", reaim=-2)
