"""The L-BFGS polish (runtime/sysid/polish.py): it reaches a known optimum, lowers what Adam left, fits its anchors,
compiles once, is deterministic, and refuses bad settings before work."""

import math

import jax
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.learn.dataset import Sampling, make_dataset
from myriad.runtime.learn.loop import Stop
from myriad.runtime.learn.models import NeuralODE, Parametric
from myriad.runtime.sysid import polish as polish_module
from myriad.runtime.sysid.fit import FitConfig, fit
from myriad.runtime.sysid.polish import PolishConfig, polish
from myriad.runtime.sysid.run import SysidConfig, run_sysid

pytestmark = pytest.mark.slow  # not in `make test-fast`: L-BFGS fits of Neural ODEs

N = 20


@pytest.fixture(scope="module")
def system():
    return load("bioreactor")  # x' = G u x - D x^2: learnable G and D (true 1, guesses 1.2 and 0.8)


@pytest.fixture(scope="module")
def data(system):
    return make_dataset(system, Sampling(intervals=N), trajectories=(8, 3, 0), seed=0)


@pytest.fixture(scope="module")
def anchor(system):
    u = system.arrays()["u_upper"][0]
    plan = np.full(N + 1, u)  # full control all the way: unlike the random walks, observed exactly
    exact = Sampling(controls="around", spread=0.0, x0_std=0.0, intervals=N)
    return make_dataset(system, exact, trajectories=(1, 0, 0), seed=5, around=plan).train


@pytest.fixture(scope="module")
def node_fit(system, data):
    model = NeuralODE(system, hidden=(8, 8), activation="tanh")
    return model, fit(model, data, FitConfig(optimizer=1e-2, epochs=30, validate_every=10, method="multiple_shooting",
                                             window=5, scale="range")).theta


def test_polish_recovers_parametric_truth_from_the_guesses(system, data):
    model = Parametric(system)
    res = polish(model, data, model.init_params(jax.random.PRNGKey(0), data.train),
                 PolishConfig(iterations=200, window=None))
    assert res.status is Stop.CONVERGED and res.objective[1] < 1e-20 < res.objective[0]
    for k, v in model.true_params().items():
        assert abs(float(res.theta[k]) - float(v)) <= 1e-6 * abs(float(v)), k


def test_polish_lowers_an_adam_fit_and_compiles_once(node_fit, data):
    model, theta = node_fit
    config = PolishConfig(iterations=40)
    first = polish(model, data, theta, config)
    traces = polish_module.TRACES["polish"]
    again = polish(model, data, theta, config)
    assert polish_module.TRACES["polish"] == traces  # same shapes and settings: nothing recompiled
    assert first.status is Stop.CONVERGED and first.iterations == 40
    assert first.objective[1] < 0.5 * first.objective[0] and math.isnan(first.anchor_loss[0])
    same = zip(jax.tree.leaves(first.theta), jax.tree.leaves(again.theta))
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in same)  # deterministic


def test_anchors_are_fitted_more_closely_than_without_them(node_fit, data, anchor):
    model, theta = node_fit
    anchored = polish(model, data, theta, PolishConfig(iterations=30, anchor_weight=10.0), anchors=anchor)
    ignored = polish(model, data, theta, PolishConfig(iterations=30, anchor_weight=0.0), anchors=anchor)
    assert anchored.anchor_loss[1] < anchored.anchor_loss[0]
    assert anchored.anchor_loss[1] < 0.5 * ignored.anchor_loss[1]


@pytest.mark.parametrize("kw, match", [({"iterations": 0}, "iterations"), ({"window": 0}, "window"),
                                       ({"anchor_weight": -1.0}, "anchor_weight"), ({"scale": "log"}, "scale"),
                                       ({"gtol": math.nan}, "gtol")])
def test_bad_polish_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        PolishConfig(**kw)


def test_sysid_config_refuses_a_polish_without_adam():
    with pytest.raises(ValueError, match="polish"):
        SysidConfig(model="parametric", polish=PolishConfig())
    assert SysidConfig(model="node").polish == PolishConfig() and SysidConfig().polish is None


def test_node_datasets_in_sequence_polish_with_the_plans_as_anchors():
    config = SysidConfig(model="node", trajectories=4, rounds=2, hidden=(8, 8),
                         fit=FitConfig(epochs=20, validate_every=10), polish=PolishConfig(iterations=20))
    report = run_sysid("cancer_treatment", config)
    assert report.dataset.n_train == 8 and report.rounds == 2  # the second dataset sampled around the first plan
    assert np.all(np.isfinite(report.dataset.train.states))
    assert report.history and report.history[-1][0] > report.history[0][0]
    first, second = report.polish
    assert math.isnan(first.anchor_loss[0]) and math.isfinite(second.anchor_loss[0])  # the round-0 plan anchors
    assert second.anchor_loss[1] < second.anchor_loss[0]
    assert len(report.record()["polish"]) == 2 and report.evaluation.converged


def test_cli_polish_goes_with_a_neural_ode(capsys):
    from myriad.runtime.cli import main

    assert main(["sysid", "cancer_treatment", "--polish", "5"]) == 2
    assert "--polish N (N >= 0) goes with --model node" in capsys.readouterr().err
