"""The solve entry point end to end: spec → compiled system → transcription → solver → re-simulation."""

import json
import math
from pathlib import Path

import jax
import jax.monitoring
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.integrators import RK4
from myriad.runtime.solve import solve, solve_batch
from myriad.runtime.solvers import SLSQP, Extragradient, Ipopt
from myriad.runtime.transcriptions import (
    ForwardBackwardSweep,
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
    default_data,
)

SPECS = Path(__file__).parent / "specs"


@pytest.fixture(scope="module")
def lq():
    return load(SPECS / "scalar_lq.yaml")


@pytest.fixture(scope="module")
def double_integrator():
    return load(SPECS / "double_integrator.yaml")


@pytest.mark.parametrize("transcription", [
    HermiteSimpson(intervals=20),
    Trapezoidal(intervals=200),
    MultipleShooting(intervals=10, steps_per_interval=4, integrator=RK4()),
    SingleShooting(intervals=50, integrator=RK4()),
], ids=lambda t: type(t).__name__)
def test_scalar_lq_reaches_tanh1(lq, transcription):
    sol = solve(lq, transcription, Ipopt())
    assert sol.converged, sol.message
    assert abs(sol.cost - math.tanh(1.0)) < 2e-4
    assert abs(sol.simulated_cost - math.tanh(1.0)) < 2e-4
    t = sol.times
    np.testing.assert_allclose(sol.states[:, 0], np.cosh(1 - t) / np.cosh(1), atol=2e-3)


def test_scalar_lq_sweep(lq):
    sol = solve(lq, ForwardBackwardSweep(intervals=400))
    assert sol.converged, sol.message
    assert abs(sol.cost - math.tanh(1.0)) < 1e-8


@pytest.mark.parametrize("solver", [Ipopt(), SLSQP()], ids=["ipopt", "slsqp"])
def test_double_integrator_minimum_energy_is_12(double_integrator, solver):
    sol = solve(double_integrator, HermiteSimpson(intervals=10), solver)
    assert sol.converged, sol.message
    assert abs(sol.cost - 12.0) < 1e-6
    assert max(abs(d) for d in sol.defect) < 1e-8
    np.testing.assert_allclose(sol.controls[:, 0], 6 - 12 * sol.times, atol=1e-4)


@pytest.mark.parametrize("solver", [Ipopt(), SLSQP(), Extragradient(max_iter=3000)],
                         ids=["ipopt", "slsqp", "extragradient"])
def test_infeasible_problem_is_never_a_success(solver):
    sol = solve(load(SPECS / "unreachable.yaml"), Trapezoidal(intervals=20), solver, resimulate=False)
    assert not sol.converged
    assert sol.constraint_violation > 1e-2
    assert sol.message


@pytest.mark.slow
def test_published_setting_meets_targets_on_a_subset():
    # The full 18-system table runs in `myriad bench`; here a few quick ones, against the published targets.
    for name in ("simple_case", "van_der_pol", "mould_fungicide", "bacteria"):
        system = load(name)
        sol = solve(system, SingleShooting(intervals=100), Ipopt())
        target = system.reference["target"]
        assert sol.converged, (name, sol.message)
        assert sol.cost <= target + 0.005 * abs(target), (name, sol.cost, target)
        assert max((abs(d) for d in sol.defect), default=0.0) <= 1e-6


@pytest.mark.slow
def test_transcriptions_agree_on_a_lenhart_system():
    system = load("cancer_treatment")
    costs = {}
    for tr in (MultipleShooting(intervals=50, steps_per_interval=2), Trapezoidal(intervals=200),
               HermiteSimpson(intervals=50)):
        sol = solve(system, tr, Ipopt())
        assert sol.converged, sol.message
        costs[type(tr).__name__] = sol.simulated_cost
    sweep = solve(system, ForwardBackwardSweep(intervals=1000))
    assert sweep.converged, sweep.message
    costs["sweep"] = sweep.simulated_cost
    ref = costs["HermiteSimpson"]
    for name, c in costs.items():
        assert abs(c - ref) <= 0.01 * abs(ref), (name, costs)


def test_solvers_agree_on_a_smooth_lenhart_system():
    system = load("mould_fungicide")
    tr = Trapezoidal(intervals=50)
    costs = {type(s).__name__: solve(system, tr, s, resimulate=False) for s in (Ipopt(), SLSQP(), Extragradient())}
    for name, sol in costs.items():
        assert sol.converged, (name, sol.message)
    ref = costs["Ipopt"].cost
    for name, sol in costs.items():
        assert abs(sol.cost - ref) <= 0.01 * abs(ref), (name, sol.cost, ref)


def test_no_recompilation_between_solves_with_same_shapes():
    system = load("mould_fungicide")
    tr = SingleShooting(intervals=40)
    solve(system, tr, Ipopt(), resimulate=False)  # warm: compiles once
    compiles = []

    def listener(event, duration, **kwargs):
        if "backend_compile" in event:
            compiles.append(event)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        sol = solve(system, tr, Ipopt(), params={"r": 0.35}, x0=[1.2], resimulate=False)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert sol.converged
    assert compiles == []
    assert sol.compile_seconds == 0.0


def test_default_data_is_host_arrays_and_device_arrays_reuse_its_program():
    system = load("mould_fungicide")
    data = default_data(system, params={"r": 0.35})
    # Host leaves: a compiled program takes them as they are (a device array per leaf cost ~70 us a solve).
    assert all(isinstance(leaf, np.ndarray) and leaf.dtype == np.float64 for leaf in jax.tree.leaves(data))
    on_device = jax.tree.map(jax.numpy.asarray, data)
    traced = default_data(system, params={"r": on_device.params["r"]}, x0=on_device.x0)
    assert isinstance(traced.params["r"], jax.Array) and isinstance(traced.x0, jax.Array)  # kept, not copied back
    tr = SingleShooting(intervals=40)
    host = tr.solve_problem(system, Ipopt(), data)
    device = tr.solve_problem(system, Ipopt(), on_device)
    assert host.converged and device.compile_seconds == 0.0
    np.testing.assert_array_equal(host.controls, device.controls)


@pytest.mark.slow
def test_solve_batch_matches_single_solves():
    system = load("mould_fungicide")
    tr = Trapezoidal(intervals=20)
    rs = np.array([0.25, 0.3, 0.35, 0.4])
    batch = solve_batch(system, tr, Extragradient(), params={"r": rs})
    assert len(batch) == 4
    for r, b in zip(rs, batch):
        single = solve(system, tr, Ipopt(), params={"r": r}, resimulate=False)
        assert b.converged, b.message
        assert abs(b.cost - single.cost) <= 1e-3 * abs(single.cost)


def test_cli_solve_writes_json_and_plot(tmp_path):
    from myriad.runtime.cli import main

    out, png = tmp_path / "sol.json", tmp_path / "sol.png"
    rc = main(["solve", "simple_case", "--transcription", "hermite_simpson", "--controls", "20", "--json", str(out),
               "--plot", str(png)])
    assert rc == 0
    rec = json.loads(out.read_text())
    for key in ("system", "transcription", "solver", "integrator", "cost", "defect", "converged", "compile_seconds",
                "solve_seconds"):
        assert key in rec
    assert rec["converged"] and abs(rec["cost"] - (-1.3544)) < 0.01
    assert png.stat().st_size > 10_000


def test_cli_usage_errors():
    from myriad.runtime.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["solve", "simple_case", "--transcription", "nope"])
    assert exc.value.code == 2
    assert main(["solve", "no_such_system"]) == 2


def test_a_parameter_baked_into_final_values_and_bounds_cannot_be_overridden():
    # Predator-Prey's required z(T) = B and bound z <= B are compiled as 5: a solve with B = 4 would still target 5.
    with pytest.raises(ValueError, match=r"predator_prey: parameter `B` = 4.0 differs from the spec's 5.*final values"):
        solve("predator_prey", params={"B": 4.0})
    with pytest.raises(ValueError, match=r"parameter `B`"):
        solve_batch("predator_prey", params={"B": np.array([5.0, 4.0])})
    assert load("predator_prey").structural_params == ("B", "M")
    assert load("van_der_pol").structural_params == ()
    # The spec's own value is accepted (nothing would be lost).
    data = default_data(load("predator_prey"), {"B": 5.0, "d1": 0.2})
    assert float(data.params["d1"]) == 0.2
