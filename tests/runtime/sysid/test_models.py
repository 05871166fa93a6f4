"""System-identification models: Parametric and NeuralODE, and the LearnedSystem that plans on them."""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from myriad.runtime import load, simulate
from myriad.runtime.data import default_data
from myriad.runtime.learn.models import ACTIVATIONS, LearnedSystem, NeuralODE, Parametric
from myriad.runtime.solve import solve
from myriad.runtime.solvers import Ipopt
from myriad.runtime.status import Status
from myriad.runtime.system import OptimalControlUnavailable
from myriad.runtime.systems import NAMES
from myriad.runtime.transcriptions import ForwardBackwardSweep, SingleShooting, Trapezoidal

from ...helpers import sample_interval


class Trajectories(NamedTuple):  # the shape of runtime/learn/dataset.py's Trajectories
    controls: np.ndarray  # (B, N+1, m)
    states: np.ndarray  # (B, N+1, n)


@pytest.fixture(scope="module")
def cancer():
    return load("cancer_treatment")


def _point(system):
    rng = np.random.default_rng(0)
    a = system.arrays()
    x = np.array([sample_interval(lo, hi, c, rng, 1)[0] for lo, hi, c in zip(a["x_lower"], a["x_upper"], a["x0"])])
    u = np.array([sample_interval(lo, hi, 0.0, rng, 1)[0] for lo, hi in zip(a["u_lower"], a["u_upper"])])
    return jnp.asarray(x), jnp.asarray(u), jnp.asarray(0.3 * system.horizon)


def _synthetic(system, B=4, N=50, seed=0):
    rng = np.random.default_rng(seed)
    n, m = system.n_states, system.n_controls
    t = np.linspace(0.0, system.horizon, N + 1)[None, :, None]
    states = rng.normal(size=(B, 1, n)) * 3.0 + 2.0 + np.sin(t * (1.0 + np.arange(n))) * rng.uniform(1, 5, (B, 1, n))
    return Trajectories(controls=rng.uniform(-1, 4, (B, N + 1, m)), states=states)


def test_parametric_params_and_validation(cancer):
    m = Parametric(cancer)
    assert m.learnable == ("r", "delta")
    theta = m.init_params()
    assert {k: float(v) for k, v in theta.items()} == {"r": 0.1, "delta": 0.8}
    assert all(v.dtype == jnp.float64 for v in theta.values()) and m.n_parameters(theta) == 2
    assert {k: float(v) for k, v in m.true_params().items()} == {"r": 0.3, "delta": 0.45}
    assert Parametric(cancer, ["delta", "r"]) == m and hash(Parametric(cancer, ("delta", "r"))) == hash(m)
    assert Parametric(cancer, "delta").learnable == ("delta",)
    for make, error in [(lambda: Parametric(cancer, ("r", "a")), r"\['a'\] not learnable.*\['r', 'delta'\]"),
                        (lambda: Parametric(cancer, ("r", "r")), "once"),
                        (lambda: Parametric(load("epidemic")), "no learnable parameters"),
                        (lambda: m.as_system({"r": 0.3}), "structure"),
                        (lambda: m.as_system({"r": 0.3, "delta": jnp.ones(2)}), r"theta\['delta'\] has shape \(2,\)")]:
        with pytest.raises(ValueError, match=error):
            make()
    with pytest.raises(TypeError, match="true system"):
        Parametric(m.as_system(theta))


@pytest.mark.parametrize("name", [n for n in NAMES if load(n).learnable])
def test_parametric_at_true_values_is_the_spec(name):
    system = load(name)
    model = Parametric(system)
    p = system.default_params(jnp.float64)
    x, u, t = _point(system)
    assert np.array_equal(model.vector_field(x, u, t, model.true_params(), p), system.dynamics(x, u, t, p))
    learned, lam = model.as_system(model.true_params()), jnp.linspace(-1.0, 1.0, system.n_states)
    params = learned.default_params(jnp.float64)
    assert np.array_equal(learned.dynamics(x, u, t, params), system.dynamics(x, u, t, p))
    for name, args in (("costate_dynamics", (x, u, lam, t)), ("hamiltonian_grad_u", (x, u, lam, t)),
                       ("dynamics_jac_x", (x, u, t)), ("terminal_costate", (x, t)), ("running_cost", (x, u, t))):
        assert np.array_equal(getattr(learned, name)(*args, params), getattr(system, name)(*args, p)), name
    if system.optimal_control_kind != "none":
        assert np.array_equal(learned.optimal_control(x, lam, t, params), system.optimal_control(x, lam, t, p))
    # Costs are the true system's at the spec's values; the artefacts above use the learned values: they agree
    # only because no spec's cost uses a learnable parameter. Check that for every spec.
    g = jax.grad(lambda q: system.running_cost(x, u, t, q) + system.terminal_cost(x, t, q))(p)
    assert all(float(g[k]) == 0.0 for k in system.learnable)


def test_learned_system_metadata_and_data(cancer):
    model = Parametric(cancer)
    learned = model.as_system(model.init_params())
    assert isinstance(learned, LearnedSystem) and learned.name == cancer.name and learned.model_label == "parametric"
    assert learned.true_system is cancer and learned.optimal_control_kind == "stationary"
    for k, v in cancer.arrays().items():
        np.testing.assert_array_equal(learned.arrays()[k], v)
    assert learned.horizon == cancer.horizon and learned.state_names == cancer.state_names and learned != cancer
    data = default_data(learned)
    assert set(data.params) == {"spec", "model"}
    assert all(leaf.dtype == jnp.float64 for leaf in jax.tree.leaves(data))
    assert float(data.params["model"]["r"]) == 0.1 and float(data.params["spec"]["r"]) == 0.3
    with pytest.raises(AttributeError, match="immutable"):
        learned.theta = {}
    controls = np.linspace(0.0, 1.0, 101)
    truth = model.as_system(model.true_params())
    np.testing.assert_array_equal(simulate(truth, controls).states, simulate(cancer, controls).states)


def test_parametric_solves_like_the_true_system(cancer):
    model = Parametric(cancer)
    truth = model.as_system(model.true_params())
    trapezoidal = Trapezoidal(intervals=20)
    for method in (SingleShooting(), trapezoidal):  # the published setting, and a collocation
        ref, sol = solve(cancer, method, Ipopt(), resimulate=False), solve(truth, method, Ipopt(), resimulate=False)
        assert ref.converged and sol.converged, sol.message
        assert abs(sol.cost - ref.cost) < 1e-10
    # Another theta: an equal system, so the cached NLP and its compiled programs are reused.
    guessed = model.as_system(model.init_params())
    assert guessed == truth and hash(guessed) == hash(truth)
    again = solve(guessed, trapezoidal, Ipopt(), resimulate=False)
    assert again.compile_seconds == 0.0
    assert again.converged and abs(again.cost - sol.cost) > 1e-3  # the data really changed


# ---- NeuralODE -------------------------------------------------------------------------------------------------


def test_neural_ode_shapes_and_gradient():
    system = load("bear_populations")  # 3 states, 2 controls
    p = system.default_params(jnp.float64)
    x, u, t = _point(system)
    for time_input in (False, True):
        model = NeuralODE(system, hidden=(16, 8), activation="tanh", time_input=time_input)
        theta = model.init_params(jax.random.PRNGKey(0))
        assert all(leaf.dtype == jnp.float64 for leaf in jax.tree.leaves(theta))
        assert theta["net"][0].weight.shape == (16, 5 + time_input) and theta["net"][-1].weight.shape == (3, 8)
        assert model.n_parameters(theta) == (5 + time_input) * 16 + 16 + 16 * 8 + 8 + 8 * 3 + 3

        @jax.jit
        def run(theta):
            ts = jnp.linspace(0.0, system.horizon, 7)
            out = jax.vmap(model.vector_field, (None, None, 0, None, None))(x, u, ts, theta, p)
            g = jax.grad(lambda th: jnp.sum(model.vector_field(x, u, t, th, p) ** 2))(theta)
            return model.vector_field(x, u, t, theta, p), out, g

        one, out, g = run(theta)
        assert one.shape == (3,) and out.shape == (7, 3)
        assert (len(np.unique(np.asarray(out[:, 0]))) > 1) == time_input  # t matters only as an input
        leaves = jax.tree.leaves(g["net"])
        assert all(np.all(np.isfinite(a)) for a in leaves) and any(np.any(a != 0) for a in leaves)


def test_neural_ode_normalisation():
    system, data = load("van_der_pol"), _synthetic(load("van_der_pol"))
    model = NeuralODE(system, hidden=(4,))
    nrm = model.init_params(jax.random.PRNGKey(1), data)["norm"]
    xs, us = data.states.reshape(-1, 2), data.controls.reshape(-1, 1)
    dxs = (np.diff(data.states, axis=1) / (system.horizon / 50)).reshape(-1, 2)
    for v, name in ((xs, "x"), (us, "u"), (dxs, "dx")):
        z = (v - np.asarray(nrm[f"{name}_mean"])) / np.asarray(nrm[f"{name}_std"])
        np.testing.assert_allclose(z.mean(0), 0.0, atol=1e-12)
        np.testing.assert_allclose(z.std(0), 1.0, rtol=1e-12)
    const = Trajectories(controls=np.full((2, 11, 1), 0.5), states=data.states[:2, :11])
    nrm = model.init_params(jax.random.PRNGKey(1), const)["norm"]
    assert float(nrm["u_std"][0]) == pytest.approx(1.5e-6) and np.all(np.isfinite(np.asarray(nrm["u_std"])))
    # Without data: the bounds' middles and half-widths ([-4, 4]; [-0.75, 1]); dx: mean 0, scale / T.
    nrm = model.init_params(jax.random.PRNGKey(1))["norm"]
    got = {k: np.asarray(v).tolist() for k, v in nrm.items()}
    assert got == {"x_mean": [0.0, 0.0], "x_std": [4.0, 4.0], "u_mean": [0.125], "u_std": [0.875],
                   "dx_mean": [0.0, 0.0], "dx_std": [4.0 / system.horizon] * 2}
    nrm = NeuralODE(load("harvest"), hidden=(4,)).init_params(jax.random.PRNGKey(1))["norm"]  # unbounded state
    assert float(nrm["x_mean"][0]) == 0.0 and float(nrm["x_std"][0]) == 1.0


def test_neural_ode_trainable_mask_freezes_norm(cancer):
    model = NeuralODE(cancer, hidden=(8,))
    theta = model.init_params(jax.random.PRNGKey(0), _synthetic(cancer))
    mask = model.trainable(theta)
    assert all(jax.tree.leaves(mask["net"])) and not any(jax.tree.leaves(mask["norm"]))
    assert model.n_parameters(theta) == 2 * 8 + 8 + 8 + 1
    p, (x, u, t) = cancer.default_params(jnp.float64), _point(cancer)

    def loss(th):
        return jnp.sum(model.vector_field(x, u, t, th, p) ** 2)

    # The recommended way: differentiate with respect to the trainable part only.
    train, frozen = model.partition(theta)
    assert jax.tree.leaves(train["norm"]) == [] and jax.tree.leaves(frozen["net"]) == []
    grads = jax.grad(lambda tr: loss(model.combine(tr, frozen)))(train)
    assert jax.tree.leaves(grads["norm"]) == [] and len(jax.tree.leaves(grads["net"])) == 4
    # On the whole theta: optax.multi_transform with set_to_zero on the frozen leaves.
    opt = optax.multi_transform({True: optax.sgd(1e-1), False: optax.set_to_zero()}, mask)
    updates, _ = opt.update(jax.grad(loss)(theta), opt.init(theta), theta)
    new = optax.apply_updates(theta, updates)
    changed = [bool(np.any(a != b)) for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(theta))]
    assert changed == [True] * 4 + [False] * 6  # net, then norm


@pytest.mark.slow
def test_neural_ode_learned_system(cancer):
    model = NeuralODE(cancer, hidden=(8, 8))
    theta = model.init_params(jax.random.PRNGKey(0))
    learned = model.as_system(theta)
    assert learned.optimal_control_kind == "none" and learned.model_label == "node"
    other = model.as_system(model.init_params(jax.random.PRNGKey(5)))
    assert other == learned and hash(other) == hash(learned)
    assert NeuralODE(cancer, hidden=[8, 8]) == model and NeuralODE(cancer, hidden=(8, 9)) != model
    wider = NeuralODE(cancer, hidden=(8, 9))
    assert wider.as_system(wider.init_params(jax.random.PRNGKey(0))) != learned
    # Autodiff artefacts: lam' = -(dL/dx + (df/dx)^T lam), dH/du = dL/du + (df/du)^T lam.
    params, lam, (x, u, t) = learned.default_params(jnp.float64), jnp.array([0.7]), _point(cancer)
    fx, fu = learned.dynamics_jac_x(x, u, t, params), learned.dynamics_jac_u(x, u, t, params)
    np.testing.assert_allclose(learned.costate_dynamics(x, u, lam, t, params),
                               -(cancer.running_cost_grad_x(x, u, t, params["spec"]) + fx.T @ lam), rtol=1e-12)
    np.testing.assert_allclose(learned.hamiltonian_grad_u(x, u, lam, t, params),
                               cancer.running_cost_grad_u(x, u, t, params["spec"]) + fu.T @ lam, rtol=1e-12)
    with pytest.raises(OptimalControlUnavailable):
        learned.optimal_control(x, lam, t, params)
    sol = solve(learned, SingleShooting(intervals=20), Ipopt(max_iter=50))
    assert isinstance(sol.status, Status) and sol.controls.shape == (21, 1)
    with pytest.raises(OptimalControlUnavailable, match="node"):
        solve(learned, ForwardBackwardSweep(intervals=20))


def test_neural_ode_activations_and_bad_configs(cancer):
    x, u, t = _point(cancer)
    for act in ACTIVATIONS:
        model = NeuralODE(cancer, hidden=(3,), activation=act)
        assert np.all(np.isfinite(model.vector_field(x, u, t, model.init_params(jax.random.PRNGKey(0)), {})))
    for kwargs, error in [({"hidden": (8, 0)}, "positive ints"), ({"hidden": (8.0,)}, "positive ints"),
                          ({"hidden": "8"}, "positive ints"), ({"activation": "gelu"}, "'gelu'.*sigmoid")]:
        with pytest.raises(ValueError, match=error):
            NeuralODE(cancer, **kwargs)
    with pytest.raises(TypeError, match="System"):
        NeuralODE("cancer_treatment")
    model, key = NeuralODE(cancer, hidden=(4,)), jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="random key"):
        model.init_params()
    for controls, states, error in [((2, 5, 1), np.zeros((2, 5, 3)), r"states must have shape \(B, N\+1, 1\)"),
                                    ((2, 4, 1), np.zeros((2, 5, 1)), "controls must have shape"),
                                    ((2, 5, 1), np.full((2, 5, 1), np.nan), "non-finite")]:
        with pytest.raises(ValueError, match=error):
            model.init_params(key, Trajectories(np.zeros(controls), states))
    with pytest.raises(ValueError, match="structure"):
        model.as_system(NeuralODE(cancer, hidden=(5,)).init_params(key))
