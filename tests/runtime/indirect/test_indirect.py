"""The indirect method as a pure solver: batches (vmap) against one-by-one solves, the refused NLP solver, and one
status per batch member.

The sweep's numerics (known solutions, step control, Newton, shooting, reports) are tested in test_transcriptions.py.
"""

import jax
import numpy as np
import pytest

from myriad.runtime import solve, solve_batch
from myriad.runtime.data import batch_data, default_data
from myriad.runtime.indirect import INDIRECT, ForwardBackwardSweep, SweepCode, SweepResult
from myriad.runtime.indirect.result import STATUS
from myriad.runtime.solvers import Extragradient, Ipopt
from myriad.runtime.status import Status

from .._problems import BoundedReach, DoubleIntegrator, ScalarLQ

jax.config.update("jax_enable_x64", True)

_FIELDS = ("states", "controls", "costates")


def _assert_same(batched: SweepResult, single: SweepResult, atol: float = 1e-12) -> None:
    assert (batched.status, batched.solver_code) == (single.status, single.solver_code)
    assert (batched.iterations, batched.newton_iterations, batched.shooting_iterations) == (
        single.iterations, single.newton_iterations, single.shooting_iterations)
    assert batched.relaxation == single.relaxation and batched.message == single.message
    assert abs(batched.cost - single.cost) <= atol * max(1.0, abs(single.cost))
    for name in _FIELDS:
        np.testing.assert_allclose(getattr(batched, name), getattr(single, name), rtol=0, atol=atol, err_msg=name)


@pytest.mark.slow
def test_solve_batch_over_parameters_equals_one_by_one_solves():
    # Stationary u*: relaxed sweeps, then Newton (GMRES inside the vmapped while loop).
    system, sweep = ScalarLQ(), ForwardBackwardSweep(intervals=50)
    qs = np.array([0.5, 1.0, 2.0, 4.0])
    batch = sweep.solve_batch(system, batch_data(system, params={"q": qs}))
    assert len(batch) == len(qs)
    for q, b in zip(qs, batch):
        _assert_same(b, sweep.solve(system, params={"q": q}))
        assert b.converged and b.status is Status.CONVERGED, b.message
    assert len({b.cost for b in batch}) == len(qs)  # the members really differ


@pytest.mark.slow
def test_solve_batch_over_initial_states_with_broyden_shooting():
    # Fixed final states without Newton: Broyden's iteration on lambda(T) around converged sweeps, per member.
    system, sweep = DoubleIntegrator(), ForwardBackwardSweep(intervals=40, newton=False)
    x0 = np.array([[0.0, 0.0], [0.25, 0.0], [0.0, 0.5]])
    batch = sweep.solve_batch(system, batch_data(system, x0=x0))
    for x, b in zip(x0, batch):
        single = sweep.solve(system, x0=x)
        _assert_same(b, single)
        assert b.converged and b.shooting_iterations >= 1, b.message
        np.testing.assert_allclose(b.states[0], x, rtol=0, atol=0)


def test_solve_fn_is_the_vmappable_pure_sweep():
    system, sweep = ScalarLQ(), ForwardBackwardSweep(intervals=50)
    data = default_data(system, params={"q": 2.0})
    z0 = sweep.start(system, data)
    assert z0.shape == (51, 1) and z0.dtype == np.float64
    out = sweep.solve_fn(system)(data, z0)
    assert Status(int(out.status)) is STATUS[SweepCode(int(out.solver_code))] is Status.CONVERGED
    default = sweep.solve_fn(system)(data, sweep.start(system, data))
    np.testing.assert_array_equal(np.asarray(out.controls), np.asarray(default.controls))
    # A start of the right shape is taken as the initial controls; another shape is refused.
    warm = sweep.solve(system, params={"q": 2.0}, z0=np.asarray(out.controls))
    assert warm.converged and warm.iterations <= 1, warm.message
    with pytest.raises(ValueError, match=r"initial controls\) has shape \(50, 1\), expected \(51, 1\)"):
        sweep.start(system, data, np.zeros((50, 1)))


def test_the_sweep_refuses_an_nlp_solver():
    system, sweep = ScalarLQ(), ForwardBackwardSweep(intervals=20)
    assert not sweep.uses_solver and INDIRECT[sweep.label] is ForwardBackwardSweep
    with pytest.raises(ValueError, match="takes no NLP solver, got Ipopt"):
        solve(system, sweep, Ipopt())
    with pytest.raises(ValueError, match="takes no NLP solver, got Extragradient"):
        solve_batch(system, sweep, Extragradient(), params={"q": np.array([1.0, 2.0])})


@pytest.mark.slow
def test_solve_batch_gives_each_member_its_own_status():
    # q = 110 makes the relaxed sweep stiff (omega must fall to ~0.016, ~1300 sweeps): with 200 sweeps it stops at
    # the iteration limit while q = 1 converges, in the same vmapped loop.
    system, sweep = ScalarLQ(), ForwardBackwardSweep(intervals=50, newton=False, max_iter=200)
    sols = solve_batch(system, sweep, params={"q": np.array([1.0, 110.0])})
    assert [s.status for s in sols] == [Status.CONVERGED, Status.ITERATION_LIMIT]
    assert [s.solver_code for s in sols] == [SweepCode.CONVERGED, SweepCode.MAX_ITER]
    assert [s.converged for s in sols] == [True, False]
    assert sols[1].iterations == 200 and "did not converge in 200 sweeps" in sols[1].message
    assert all(s.transcription == "fbsm" and s.solver == "sweep" and s.integrator == "rk4" for s in sols)
    assert sols[1].record()["status"] == "iteration_limit" and sols[1].record()["solver_code"] == 1

    # A state bound that only some initial states violate: the sweep checks it per member.
    system, sweep = BoundedReach(), ForwardBackwardSweep(intervals=20)
    sols = solve_batch(system, sweep, x0=np.array([[0.0], [-1.0]]))
    assert [s.status for s in sols] == [Status.STATE_BOUNDS_VIOLATED, Status.CONVERGED]
    assert [s.solver_code for s in sols] == [SweepCode.STATE_BOUNDS_VIOLATED, SweepCode.CONVERGED]
    single = solve(system, sweep, x0=np.array([0.0]), resimulate=False)
    assert single.status is Status.STATE_BOUNDS_VIOLATED and single.message == sols[0].message


def test_every_sweep_code_maps_to_a_status():
    assert set(STATUS) == set(SweepCode)
    assert STATUS[SweepCode.CONVERGED] is Status.CONVERGED
    assert [c for c in SweepCode if STATUS[c] is Status.CONVERGED] == [SweepCode.CONVERGED]
    assert STATUS[SweepCode.SHOOTING_FAILED] is STATUS[SweepCode.NEWTON_FAILED] is Status.NOT_CONVERGED
