"""Fitting (runtime/sysid/fit.py, losses.py, checkpoint.py): the loss against mathematics (zero at the truth, gradient
against differences), recovery of known parameters, a Neural ODE that learns, no recompiles, determinism, resume, and
errors before work."""

import dataclasses
import importlib
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from jax.test_util import check_grads

from myriad.runtime import RK4, Adaptive, Heun, load
from myriad.runtime.integrators import rollout
from myriad.runtime.learn.checkpoint import CheckpointMismatch, load_checkpoint, save_checkpoint
from myriad.runtime.learn.dataset import Sampling, make_dataset
from myriad.runtime.learn.loop import Stop
from myriad.runtime.learn.models import NeuralODE, Parametric
from myriad.runtime.sysid import losses
from myriad.runtime.sysid.fit import FitConfig, fit
from myriad.runtime.sysid.losses import fit_integrator, layout, state_scale, window_losses

# The module, not the function (a package that re-exports ``fit`` would shadow it in a ``from`` import).
fit_module = importlib.import_module("myriad.runtime.sysid.fit")
N = 20  # a short grid keeps compilation and epochs cheap; the published N = 100 changes nothing in the logic


@pytest.fixture(scope="module")
def system():
    # x' = G u x - D x^2 on [0, 2]: one state, learnable G (true 1, guess 1.2) and D (true 1, guess 0.8). (Cancer
    # Treatment's guesses blow up on so coarse a grid: h = 1 there.)
    return load("bioreactor")


@pytest.fixture(scope="module")
def data(system):
    return make_dataset(system, Sampling(intervals=N), trajectories=(12, 4, 0), seed=0)


def loss_of(model, theta, data, *, window=None, tile=True, gamma=1.0, scale="none"):
    """The loss of runtime/sysid/losses.py on the training set, as ``fit`` composes it."""
    lay = layout(data.intervals, window, tile=tile, gamma=gamma)
    inv = jnp.asarray(1.0 / state_scale(model.system, data.train.states, scale))
    per = window_losses(model, fit_integrator(data.sampling), lay, theta, model.system.default_params(jnp.float64),
                        data.times[0], data.horizon / data.intervals, jnp.asarray(data.train.controls),
                        jnp.asarray(data.train.states), inv)
    return jnp.mean(per)


def leaves_equal(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


# ---- the loss ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kw", [{}, {"window": 7}, {"window": 6, "gamma": 0.9, "scale": "range"},
                                {"window": 5, "tile": False}])
def test_true_model_has_zero_loss_on_noise_free_data(system, data, kw):
    model = Parametric(system)
    loss = jax.jit(lambda th: loss_of(model, th, data, **kw))
    assert float(loss(model.true_params())) < 1e-20
    assert float(loss(model.init_params())) > 1e-4


def test_single_shooting_is_the_published_mean_squared_error(system, data):
    model = Parametric(system)
    theta = model.init_params()
    f = lambda x, u, t: model.vector_field(x, u, t, theta, system.default_params())  # noqa: E731
    one = lambda x0, u: rollout(Heun(), f, x0, 0.0, system.horizon / N, u)  # noqa: E731
    pred = np.asarray(jax.jit(jax.vmap(one))(data.train.states[:, 0], data.train.controls))
    want = np.mean((pred[:, 1:] - data.train.states[:, 1:]) ** 2)
    np.testing.assert_allclose(float(loss_of(model, theta, data)), want, rtol=1e-12)


def test_window_layout_weighs_every_node_once():
    lay = layout(20, 8, gamma=1.0)  # 8 does not divide 20: the last window starts at 12 and overlaps
    assert lay.starts.tolist() == [0, 8, 12] and lay.count == 20
    per_node = np.zeros(21)
    for s, w in zip(lay.starts, lay.weights):
        per_node[s + 1:s + 9] += w
    np.testing.assert_allclose(per_node[1:], 1.0)
    prefix = layout(20, 5, tile=False, gamma=0.5)
    assert prefix.starts.tolist() == [0] and prefix.count == 5
    np.testing.assert_allclose(prefix.weights[0], 0.5 ** np.arange(1, 6))


@pytest.mark.parametrize("kw", [{}, {"window": 6, "gamma": 0.9}])
def test_loss_gradient_matches_finite_differences(system, data, kw):
    model = Parametric(system)
    check_grads(jax.jit(lambda th: loss_of(model, th, data, **kw)), (model.init_params(),), order=1, modes=("rev",))
    if kw:  # a nested pytree, the frozen leaves included (once: each check compiles a Neural ODE's rollouts anew)
        node = NeuralODE(system, hidden=(4,), activation="tanh")
        theta = node.init_params(jax.random.PRNGKey(1), data.train)
        check_grads(jax.jit(lambda th: loss_of(node, th, data, **kw)), (theta,), order=1, modes=("rev",))


def test_integrator_and_scale_choices(system):
    assert fit_integrator(Sampling(integrator=Heun())) == Heun()
    assert fit_integrator(Sampling(integrator=Adaptive())) == RK4()  # fixed steps on the same grid
    hiv = load("hiv_treatment")  # states of very different magnitudes: T ~ 800, I ~ 0.04
    np.testing.assert_allclose(state_scale(hiv, np.ones((1, 2, 3)), "range"), [1600.0, 100.0, 100.0])
    np.testing.assert_allclose(state_scale(hiv, np.ones((1, 2, 3)), "none"), 1.0)
    # "data": the spread of each state over the data, never above the range; a state the data never move keeps it
    x = np.stack([np.array([[100.0, 0.01, 5.0], [500.0, 0.03, 5.0]])])
    np.testing.assert_allclose(state_scale(hiv, x, "data"), [400.0, 0.02, 100.0])
    np.testing.assert_allclose(state_scale(hiv, np.array([[[0.0, -200.0, 0.0], [0.0, 300.0, 1.0]]]), "data"),
                               [1600.0, 100.0, 1.0])


# ---- fitting -------------------------------------------------------------------------------------------------------

def test_parametric_fit_recovers_the_true_parameters(system, data):
    model = Parametric(system)
    res = fit(model, data, FitConfig(optimizer=1e-2, epochs=400, validate_every=20, patience=None))
    assert res.success and res.stopped is Stop.MAX_EPOCHS and res.epochs == 400
    for name, true in model.true_params().items():
        assert abs(float(res.theta[name]) / float(true) - 1) < 1e-2, (name, res.theta)
    assert res.best_validation_loss < 1e-6 and res.integrator == "heun"
    epochs = [e for e, _, _ in res.history]
    assert epochs == list(range(20, 401, 20))


def test_neural_ode_learns_a_simple_system(system, data):
    model = NeuralODE(system, hidden=(16, 16), activation="tanh")
    res = fit(model, data, FitConfig(optimizer=1e-2, epochs=300, validate_every=10, patience=None))
    theta0 = model.init_params(jax.random.split(jax.random.PRNGKey(0))[1], data.train)  # fit's own start (seed 0)
    before, after = float(loss_of(model, theta0, data)), float(loss_of(model, res.theta, data))
    assert after < before / 10 and res.best_validation_loss < 1e-2, (before, after, res.best_validation_loss)
    assert leaves_equal(res.theta["norm"], theta0["norm"])  # frozen leaves are never updated


def test_no_recompiles_across_epochs_and_fits(system, data):
    # A configuration used by no other test (gamma, window, batch padding: 12 = 5 + 5 + 2 padded), so its traces count.
    cfg = FitConfig(optimizer=3e-3, epochs=25, batch_size=5, method="multiple_shooting", window=6, gamma=0.95,
                    validate_every=5, patience=None)
    model = Parametric(system)
    before = dict(losses.TRACES)
    first = fit(model, data, cfg)
    assert losses.TRACES["train_epoch"] - before["train_epoch"] == 1  # 25 epochs, one trace
    assert losses.TRACES["validation_loss"] - before["validation_loss"] <= 1  # 6 validations (maybe cached already)
    again = fit(model, data, dataclasses.replace(cfg, epochs=40))
    assert again.compile_count == 0 and again.epochs == 40  # a new fit of the same configuration reuses both
    assert leaves_equal(again.history[:5], first.history[:5])


def test_same_seed_same_bits(system, data):
    model = NeuralODE(system, hidden=(16, 16), activation="tanh")  # the learning test's: its validation is compiled
    cfg = FitConfig(optimizer=1e-2, epochs=20, batch_size=5, validate_every=5, patience=None, seed=3)
    a, b = fit(model, data, cfg), fit(model, data, cfg)
    assert leaves_equal(a.theta, b.theta) and a.history == b.history
    c = fit(model, data, dataclasses.replace(cfg, seed=4))
    assert not leaves_equal(a.theta, c.theta)


def test_resume_continues_bit_for_bit(system, data, tmp_path, monkeypatch):
    model = NeuralODE(system, hidden=(16, 16), activation="tanh")  # the learning test's: its validation is compiled
    cfg = FitConfig(optimizer=1e-2, epochs=40, batch_size=5, validate_every=5, patience=None, seed=3,
                    checkpoint_every=10)
    whole = fit(model, data, cfg)
    # 17 is off both schedules: the first run still checkpoints where it stops, before its closing validation.
    part = fit(model, data, dataclasses.replace(cfg, epochs=17), checkpoint_dir=tmp_path)
    assert part.epochs == 17 and (tmp_path / "checkpoint.npz").is_file() and (tmp_path / "checkpoint.json").is_file()
    rest = fit(model, data, cfg, checkpoint_dir=tmp_path, resume=True)
    assert rest.epochs == 40 and leaves_equal(rest.theta, whole.theta)
    assert rest.history == whole.history and rest.best_validation_loss == whole.best_validation_loss
    again = fit(model, data, cfg, checkpoint_dir=tmp_path, resume=True)  # the checkpoint is at the end already
    assert again.epochs == 40 and leaves_equal(again.theta, whole.theta)

    # A crash mid-run (epoch 27): the resume starts from the last scheduled checkpoint (epoch 20).
    calls, real = [0], fit_module.train_epoch

    def crashing(*args, **kwargs):
        calls[0] += 1
        if calls[0] == 27:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    with monkeypatch.context() as m:
        m.setattr(fit_module, "train_epoch", crashing)
        with pytest.raises(KeyboardInterrupt):
            fit(model, data, cfg, checkpoint_dir=tmp_path / "crash")
    assert json.loads((tmp_path / "crash" / "checkpoint.json").read_text())["epoch"] == 20
    resumed = fit(model, data, cfg, checkpoint_dir=tmp_path / "crash", resume=True)
    assert leaves_equal(resumed.theta, whole.theta) and resumed.history == whole.history

    other = dataclasses.replace(data, train=data.validation)
    with pytest.raises(CheckpointMismatch, match="dataset .* but this fit's dataset is"):
        fit(model, other, cfg, checkpoint_dir=tmp_path, resume=True)
    with pytest.raises(CheckpointMismatch, match="batch_size: 5 in the checkpoint, 4 now"):
        fit(model, data, dataclasses.replace(cfg, batch_size=4), checkpoint_dir=tmp_path, resume=True)


def test_checkpoint_round_trip_and_template_mismatch(tmp_path):
    theta = {"a": jnp.arange(3.0), "b": jnp.asarray(2.5)}
    opt = optax.adam(1e-3)
    state = opt.init(theta)
    path = save_checkpoint(tmp_path / "c.npz", theta=theta, opt_state=state, key=jax.random.PRNGKey(7), epoch=4,
                           best_theta=theta, best_val=math.inf, history=[(2, 0.5, 0.25)], dataset_id="d" * 64,
                           config_id="c" * 64, extra={"stalls": 1})
    c = load_checkpoint(path, {"theta": theta, "opt_state": state}, dataset_id="d" * 64, config_id="c" * 64)
    assert leaves_equal(c.theta, theta) and leaves_equal(c.opt_state, state) and c.best_val == math.inf
    assert c.epoch == 4 and c.history == [(2, 0.5, 0.25)] and c.extra == {"stalls": 1}
    assert np.array_equal(c.key, jax.random.PRNGKey(7))
    with pytest.raises(CheckpointMismatch, match=r"\['a'\] is \(3,\)"):
        load_checkpoint(path, {"theta": {"a": jnp.zeros(4), "b": jnp.asarray(0.0)}, "opt_state": state})
    with pytest.raises(CheckpointMismatch, match="written for dataset dddd.*this fit's dataset is eeee"):
        load_checkpoint(path, {"theta": theta, "opt_state": state}, dataset_id="e" * 64)


def test_non_finite_loss_stops_and_keeps_the_best(system, data):
    model = Parametric(system)
    bad = {"G": jnp.asarray(1.0), "D": jnp.asarray(-1e3)}  # x' = 1e3 x^2 + ...: inf within a few steps, then NaN
    res = fit(model, data, FitConfig(optimizer=1e-2, epochs=400, validate_every=20, patience=None), theta0=bad)
    assert res.stopped is Stop.NON_FINITE and not res.success and res.epochs == 0
    assert leaves_equal(res.theta, bad) and "not finite" in res.message


def test_curriculum_stages_and_progress_bar(system, data, capsys):
    model = Parametric(system)
    cfg = FitConfig(optimizer=1e-2, epochs=60, method="multiple_shooting", curriculum=((5, 30), (20, None)),
                    validate_every=10, patience=2, gamma=0.99)  # gamma: a configuration of this test only
    before = losses.TRACES["train_epoch"]
    res = fit(model, data, cfg, progress=True)
    assert losses.TRACES["train_epoch"] - before == 2  # one compilation per stage
    assert res.success and res.best_validation_loss < res.history[0][2]
    assert "fit bioreactor" in capsys.readouterr().err


# ---- errors before work --------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class NoWork(Parametric):
    """A model whose first piece of work fails loudly: the errors below must come before it."""

    def init_params(self, key=None, data=None):
        raise AssertionError("work started before the arguments were checked")


@pytest.mark.parametrize("kwargs, match", [
    ({"method": "shooting"}, "unknown method 'shooting'"),
    ({"batch_size": 0}, "batch_size must be an integer >= 1"),
    ({"method": "multiple_shooting"}, "needs a window"),
    ({"window": 5}, "window is for method='multiple_shooting'"),
    ({"gamma": 0.0}, r"gamma must be in \(0, 1\]"),
    ({"scale": "log"}, "unknown scale"),
    ({"curriculum": ((5, 10), (0, None))}, "curriculum must be"),
    ({"optimizer": -1.0}, "learning rate must be finite and > 0"),
])
def test_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FitConfig(**kwargs)


def test_bad_fit_arguments_fail_before_work(system, data, tmp_path):
    model = NoWork(system)
    with pytest.raises(ValueError, match=f"window 21 does not fit the dataset's grid of N = {N} steps"):
        fit(model, data, FitConfig(method="multiple_shooting", window=N + 1))
    with pytest.raises(ValueError, match=f"window 50 does not fit .* N = {N}"):
        fit(model, data, FitConfig(curriculum=(5, 50)))
    other = dataclasses.replace(data, system="cancer_treatment")
    with pytest.raises(ValueError, match="dataset is of system 'cancer_treatment' but the model is of 'bioreactor'"):
        fit(model, other, FitConfig())
    with pytest.raises(ValueError, match="spec"):
        fit(model, dataclasses.replace(data, spec_sha256="0" * 64), FitConfig())
    with pytest.raises(ValueError, match="resume=True needs a checkpoint_dir"):
        fit(model, data, FitConfig(), resume=True)
    with pytest.raises(TypeError, match="dataset must be a sysid Dataset"):
        fit(model, data.train, FitConfig())
    with pytest.raises(TypeError, match="config must be a FitConfig"):
        fit(model, data, {"epochs": 3})
    with pytest.raises(ValueError, match="structure"):  # checked against init_params' shapes, abstractly
        fit(Parametric(system), data, FitConfig(), theta0={"r": 0.1})
