"""A free final time in every direct transcription (schema 2), and the methods that refuse one.

Mathematics checked: the time scaling is exact (at T equal to a fixed horizon, the free-T NLP's objective and rows are
the fixed-horizon NLP's, path constraints and t-dependent costs included); the minimum-time double integrator (T* = 2,
bang-bang with one switch at T/2) is solved to 1e-5 by Hermite-Simpson on a uniform grid whose node falls on the
switch, and by trapezoidal collocation under mesh refinement (the grid in tau, T kept across levels); the declared
Jacobian patterns contain the true one with the dense column of T.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.data import default_data
from myriad.runtime.learn.dataset import make_dataset
from myriad.runtime.rl.env import Env
from myriad.runtime.solve import solve
from myriad.runtime.solvers import Ipopt
from myriad.runtime.sweep.config import SweepConfig, parse_method
from myriad.runtime.system import UnsupportedFeature
from myriad.runtime.transcriptions import (
    TRANSCRIPTIONS,
    ForwardBackwardSweep,
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
)
from myriad.runtime.transcriptions.base import transcribe

SCHEMA2 = "tests/compiler/schema2"

# The same problem twice: T fixed at 1.7, and T free with 1.7 as its guess. Costs and dynamics depend on t, and a
# path constraint too, so that every place time enters is compared.
_SCALED = """schema: 2
name: {name}
title: Time scaling check
description: A forced double integrator whose costs, dynamics and path constraint depend on t.
states:
  x1: {{initial: 0.3, final: 1, description: position}}
  x2: {{initial: 0, description: velocity}}
controls:
  u: {{bounds: [-3, 3], description: force}}
dynamics:
  x1: x2
  x2: u - 0.1*t*x1
cost:
  sense: minimize
  running: u**2 + t*x1**2
  terminal: x2**2 + t
horizon: {horizon}
path_constraints:
  mixed: {{expression: x1*u + t, bounds: [-10, 10], description: a mixed constraint with t}}
"""


@pytest.fixture(scope="module")
def scaled_pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scaled")
    fixed, free = folder / "fixed_t.yaml", folder / "free_t.yaml"
    fixed.write_text(_SCALED.format(name="fixed_t", horizon="1.7"))
    free.write_text(_SCALED.format(name="free_t", horizon="{free: true, guess: 1.7, bounds: [0.5, 5]}"))
    return load(str(fixed)), load(str(free))


def _methods():
    return [SingleShooting(intervals=8), MultipleShooting(intervals=4, steps_per_interval=2), Trapezoidal(intervals=8),
            HermiteSimpson(intervals=8), Trapezoidal.on_grid((0.0, 0.1, 0.35, 0.5, 0.8, 1.0))]


def _trajectories():
    states = lambda t: np.stack([0.3 + 0.4 * np.sin(t), 0.4 * np.cos(t)], axis=1)  # noqa: E731
    controls = lambda t: np.stack([np.sin(2.0 * t) - 0.5], axis=1)  # noqa: E731
    return states, controls


@pytest.mark.parametrize("method", _methods(), ids=lambda m: f"{m.label}-{m.grid_intervals}")
def test_the_time_scaling_is_exact_at_a_fixed_final_time(scaled_pair, method):
    """At T = 1.7 the free-T NLP is the fixed-horizon NLP: same objective, rows, layout (plus T) and unravel."""
    fixed, free = scaled_pair
    nlp_fixed, nlp_free = transcribe(fixed, method), transcribe(free, method)
    z_fixed = method.sample(fixed, *_trajectories())
    z_free = method.sample(free, *_trajectories(), final_time=1.7)
    np.testing.assert_array_equal(z_free, np.append(z_fixed, 1.7))
    assert nlp_free.n_variables == nlp_fixed.n_variables + 1
    assert (nlp_free.z_lower[-1], nlp_free.z_upper[-1], nlp_free.z_scale[-1]) == (0.5, 5.0, 1.7)
    np.testing.assert_array_equal(nlp_free.c_lower, nlp_fixed.c_lower)
    # Jitted: eager dispatch of the rollouts' scans is slower than compiling them.
    both = lambda nlp: jax.jit(lambda z, d: (nlp.evaluate(z, d), nlp.unravel(z, d)))  # noqa: E731
    (f0, c0), (t0, x0, u0) = both(nlp_fixed)(jnp.asarray(z_fixed), default_data(fixed))
    run_free = both(nlp_free)
    (f1, c1), (t1, x1, u1) = run_free(jnp.asarray(z_free), default_data(free))
    np.testing.assert_allclose(f1, f0, rtol=1e-13)
    np.testing.assert_allclose(c1, c0, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(t1, t0, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(x1, x0, rtol=1e-13, atol=1e-14)
    np.testing.assert_array_equal(u1, u0)
    # Another T: the nodes are T s_k in physical time.
    t2 = run_free(jnp.asarray(np.append(z_fixed, 2.5)), default_data(free))[1][0]
    np.testing.assert_allclose(t2, np.asarray(t0) * (2.5 / 1.7), rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize("label", list(TRANSCRIPTIONS))
def test_declared_sparsity_contains_the_true_jacobian_with_a_free_time(scaled_pair, label):
    _, free = scaled_pair
    method = TRANSCRIPTIONS[label].on_grid(6)
    nlp = transcribe(free, method)
    z = np.random.default_rng(1).uniform(-1.0, 1.0, nlp.n_variables)
    z[-1] = 1.3
    jac = np.asarray(jax.jit(jax.jacfwd(nlp.constraints))(jnp.asarray(z), default_data(free)))
    if nlp.jacobian_sparsity is None:  # single shooting: dense by declaration
        assert label == "single_shooting"
        return
    declared = np.zeros(jac.shape, dtype=bool)
    declared[nlp.jacobian_sparsity] = True
    assert not np.any((jac != 0) & ~declared), np.argwhere((jac != 0) & ~declared)[:5]
    assert jac[0, -1] != 0  # the first defect sees T through its step h_0 = T s_1


@pytest.fixture(scope="module")
def min_time():
    return load(f"{SCHEMA2}/min_time_double_integrator.yaml")


def test_minimum_time_double_integrator_hermite_simpson(min_time):
    """T* = 2 (accelerate to T/2, then brake). On a uniform grid with an even N the switch is a node, and
    Hermite-Simpson's free midpoint controls represent the bang-bang arc: T to 1e-5 on N = 10 (measured 5e-8)."""
    sol = solve(min_time, HermiteSimpson(intervals=10), Ipopt(), resimulate=False)
    assert sol.converged
    assert abs(sol.final_time - 2.0) < 1e-5 and abs(sol.cost - 2.0) < 1e-5  # running cost 1: J = T
    assert sol.times[-1] == sol.final_time and sol.record()["final_time"] == sol.final_time
    np.testing.assert_allclose(sol.times, np.linspace(0.0, sol.final_time, 21), rtol=0, atol=1e-14)
    u = sol.controls[:, 0]
    assert np.all(u[sol.times < 0.9] > 1 - 1e-6) and np.all(u[sol.times > 1.1] < -1 + 1e-6)  # bang-bang
    np.testing.assert_allclose(sol.states[-1], [1.0, 0.0], atol=1e-9)


@pytest.mark.slow
def test_minimum_time_double_integrator_trapezoidal_with_mesh_refinement(min_time):
    """Trapezoidal's linear control needs a ramp across the switch, which costs O(h^2) in T (2.02 on 10 intervals):
    mesh refinement (grid in tau, T carried over by the warm start) reaches T* = 2 to 1e-5 (measured 1.7e-6)."""
    sol = solve(min_time, Trapezoidal(intervals=10), Ipopt(), tolerance=1e-6, max_refinements=6)
    history = sol.refinement["history"]
    assert sol.accurate and len(history) > 1 and history[0]["cost"] > 2.01
    assert abs(sol.final_time - 2.0) < 1e-5
    assert np.all(np.abs(sol.simulated_defect) < 1e-5)  # re-simulated in physical time on [0, T]


def test_hessian_colouring_gives_the_final_time_its_own_seed(min_time):
    # T multiplies every step: its row and column of the Lagrangian's Hessian are dense. Coloured as an ordinary
    # column it conflicts with everything (one product per variable); with a seed of its own the rest stays banded.
    from myriad.runtime.solvers.sparse import HessianColouring, hvp_batch_fn

    nlp = transcribe(min_time, Trapezoidal(intervals=60))
    data = default_data(min_time)
    z = np.asarray(nlp.initial_guess(data)) + 0.01 * np.random.default_rng(0).standard_normal(nlp.n_variables)
    lam = np.random.default_rng(1).standard_normal(nlp.n_constraints)

    def lagrangian(z_, lam_):
        return nlp.objective(z_, data) + lam_ @ nlp.constraints(z_, data)

    dense_h = np.asarray(jax.jit(jax.hessian(lagrangian))(z, lam))
    n = nlp.n_variables
    assert np.count_nonzero(dense_h[-1, :-1]) > n // 2  # the final time's row is dense
    rows, cols = np.nonzero(np.tril(np.abs(dense_h) > 0) | np.eye(n, dtype=bool))
    colouring = HessianColouring(rows, cols, n, batch=8)
    hvps = jax.jit(hvp_batch_fn(jax.grad(lagrangian)))
    values = colouring.values(lambda seeds: hvps(z, seeds, lam))
    np.testing.assert_allclose(values, dense_h[rows, cols], rtol=1e-12, atol=1e-12)
    assert colouring.n_colours <= 12  # measured 202 colours for 302 variables before T had its own seed


def test_no_recompilation_for_new_data_with_free_time_and_path_constraints():
    system = load(f"{SCHEMA2}/keep_out_zone.yaml")
    method = Trapezoidal(intervals=12)
    first = solve(system, method, Ipopt(), resimulate=False)
    compiles = []

    def listener(event, duration, **kwargs):
        if "backend_compile" in event:
            compiles.append(event)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        second = solve(system, method, Ipopt(), x0=[0.0, 0.2, 0.0, 0.0], resimulate=False)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert first.converged and second.converged and compiles == [] and second.compile_seconds == 0.0
    assert second.final_time != first.final_time and second.path_violation <= 1e-9


# ---- the methods that refuse a free final time or path constraints ---------------------------------------------------
def test_the_sweep_refuses_a_free_final_time_and_path_constraints(min_time):
    with pytest.raises(UnsupportedFeature, match=r"free final time \(T in \[0.1, 10\]\).*forward-backward sweep"):
        solve(min_time, ForwardBackwardSweep(intervals=20))
    with pytest.raises(UnsupportedFeature, match=r"path constraints \(wall\)"):
        ForwardBackwardSweep(intervals=20).solve(load(f"{SCHEMA2}/bryson_denham.yaml"))


def test_rl_env_and_sysid_dataset_refuse_a_free_final_time(min_time):
    with pytest.raises(UnsupportedFeature, match="RL environment"):
        Env(min_time)
    with pytest.raises(UnsupportedFeature, match="no horizon to sample trajectories on"):
        make_dataset(min_time)


def test_sweep_runner_refuses_indirect_methods_before_any_work():
    spec = f"{SCHEMA2}/bryson_denham.yaml"
    ok = SweepConfig(systems=(spec,), methods=(parse_method("solve:transcription=trapezoidal"),), seeds=(0,))
    ok.check_systems()  # a direct transcription enforces both
    for text, words in [("solve:transcription=fbsm", "fbsm"), ("mpc", "RL environment"), ("sysid", "sysid")]:
        config = SweepConfig(systems=(spec,), methods=(parse_method(text),), seeds=(0,))
        with pytest.raises(ValueError, match=words):
            config.check_systems()


def test_cli_refuses_the_sweep_on_a_schema2_spec_with_exit_2(capsys):
    assert main(["solve", f"{SCHEMA2}/min_time_double_integrator.yaml", "--transcription", "fbsm"]) == 2
    assert "free final time" in capsys.readouterr().err
