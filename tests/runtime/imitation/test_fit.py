"""The imitation policy and its fit (runtime/imitation/policy.py, fit.py), on synthetic pairs: no demonstrations and
no solver, so quick. The policy stays inside the control bounds; a policy the network can represent is recovered;
early stopping keeps the best held-out network; a non-finite loss stops without taking the step; a fit killed
between two checkpoints resumes from the last one and ends bit for bit where the uninterrupted fit ends."""

import dataclasses
import json

import jax
import numpy as np
import pytest

from myriad.runtime.imitation.fit import FitConfig, Pairs, _Fit, fit, loss
from myriad.runtime.imitation.policy import Policy
from myriad.runtime.learn.checkpoint import CheckpointMismatch
from myriad.runtime.learn.loop import Stop
from myriad.runtime.loader import load
from myriad.runtime.rl.reference import reference_env

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def policy():
    return Policy.of(reference_env(load("van_der_pol")), width=16, depth=2)


def _pairs(policy, n, seed):
    """Observations spread over the state scales and the horizon, and a smooth target policy's normalised actions
    a*(x, t) = tanh(x1 - 0.5 x2 + (T - t) / T), which the network can represent."""
    rng = np.random.default_rng(seed)
    obs = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(0, 10, n)])
    return Pairs.of(obs, np.tanh(obs[:, :1] / 4 - 0.125 * obs[:, 1:2] + obs[:, 2:] / 10))


def test_policy_stays_inside_the_control_bounds_and_normalise_inverts_its_map(policy):
    net = policy.init(jax.random.PRNGKey(0))
    huge = np.array([[1e6, -1e6, 0.0], [-1e6, 1e6, 10.0]])
    u = np.asarray(policy.control(net, huge))
    assert np.all(u >= policy.lo) and np.all(u <= policy.hi)
    obs = np.random.default_rng(1).normal(size=(7, 3))
    np.testing.assert_allclose(policy.normalise(policy.control(net, obs)), policy.action(net, obs), atol=1e-14)
    assert policy.control(net, np.zeros((2, 5, 3))).shape == (2, 5, 1)
    with pytest.raises(ValueError, match="width and depth"):
        Policy.of(reference_env(load("van_der_pol")), width=0)


def test_fit_recovers_a_representable_policy(policy):
    train, held = _pairs(policy, 400, 0), _pairs(policy, 100, 1)
    result = fit(policy, policy.init(jax.random.PRNGKey(0)), train, held,
                 FitConfig(epochs=150, steps=20, learning_rate=1e-2, width=16))
    assert result.stop in (Stop.MAX_EPOCHS, Stop.EARLY_STOPPING)
    assert result.best < 1e-4 and result.best == min(row[2] for row in result.history)
    assert float(loss(policy, result.net, held)) == pytest.approx(result.best, rel=1e-12)  # the kept network's


def test_early_stopping_keeps_the_best_held_out_network(policy):
    train, held = _pairs(policy, 60, 0), _pairs(policy, 60, 1)
    noise = Pairs.of(held.obs, np.random.default_rng(2).uniform(-1, 1, held.actions.shape))  # unlearnable labels
    result = fit(policy, policy.init(jax.random.PRNGKey(0)), train, noise, FitConfig(epochs=500, patience=5))
    assert result.stop is Stop.EARLY_STOPPING and len(result.history) < 500
    best = min(range(len(result.history)), key=lambda i: result.history[i][2])
    assert len(result.history) - 1 - best == 5  # stopped after exactly `patience` epochs without a new best
    assert float(loss(policy, result.net, noise)) == pytest.approx(result.history[best][2], rel=1e-12)


def test_a_non_finite_loss_stops_without_taking_the_step(policy):
    train, held = _pairs(policy, 50, 0), _pairs(policy, 20, 1)
    bad = Pairs.of(np.where(np.arange(50)[:, None] == 3, np.nan, train.obs), train.actions)
    net = policy.init(jax.random.PRNGKey(0))
    result = fit(policy, net, bad, held, FitConfig(epochs=10))
    assert result.stop is Stop.NON_FINITE and result.history == [] and result.net is net


def test_a_killed_fit_resumes_from_its_last_checkpoint_bit_for_bit(policy, tmp_path, monkeypatch):
    train, held = _pairs(policy, 100, 0), _pairs(policy, 30, 1)
    config = FitConfig(epochs=30, steps=3, checkpoint_every=5, width=16)
    start = policy.init(jax.random.PRNGKey(0))
    whole = fit(policy, start, train, held, config, checkpoint_dir=tmp_path / "whole")

    step = _Fit.step

    def killed(self, index):  # the process dies during epoch 14: epochs 11-13 are done but not checkpointed
        if index == 13:
            raise KeyboardInterrupt
        return step(self, index)

    monkeypatch.setattr(_Fit, "step", killed)
    with pytest.raises(KeyboardInterrupt):
        fit(policy, start, train, held, config, checkpoint_dir=tmp_path / "parts")
    monkeypatch.setattr(_Fit, "step", step)
    assert json.loads((tmp_path / "parts" / "checkpoint.json").read_text())["epoch"] == 10  # 3 epochs lost < 5
    resumed = fit(policy, start, train, held, config, checkpoint_dir=tmp_path / "parts", resume=True)
    assert resumed.history == whole.history and resumed.best == whole.best
    for a, b in zip(jax.tree.leaves(resumed.net), jax.tree.leaves(whole.net)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(CheckpointMismatch, match="learning_rate"):
        fit(policy, start, train, held, dataclasses.replace(config, learning_rate=0.1),
            checkpoint_dir=tmp_path / "parts", resume=True)
    with pytest.raises(CheckpointMismatch, match="dataset"):
        fit(policy, start, held, held, config, checkpoint_dir=tmp_path / "parts", resume=True)


def test_the_fit_is_deterministic(policy):
    train, held = _pairs(policy, 80, 0), _pairs(policy, 20, 1)
    runs = [fit(policy, policy.init(jax.random.PRNGKey(3)), train, held, FitConfig(epochs=5)) for _ in range(2)]
    assert runs[0].history == runs[1].history


def test_bad_settings_are_refused():
    for bad in ({"epochs": 0}, {"learning_rate": -1.0}, {"patience": 1.5}, {"steps": True}, {"width": 0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            FitConfig(**bad)
