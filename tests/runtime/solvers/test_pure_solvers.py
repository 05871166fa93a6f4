"""The pure-JAX solver tier (``AbstractPureSolver``) as a contract: what differentiates, what batches, what compiles.

On Mould Fungicide's ``Trapezoidal(intervals=8)`` NLP, where the default extragradient converges in a few hundred to
a couple of thousand iterations depending on the growth rate ``r`` (measured: 274 at r = 0.6, 1677 at r = 0.1).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load, solve_batch
from myriad.runtime.data import ProblemData, batch_data, default_data
from myriad.runtime.solvers import SLSQP, SOLVERS, AbstractPureSolver, Extragradient, Ipopt
from myriad.runtime.status import Status
from myriad.runtime.transcriptions import Trapezoidal

from ...helpers import CompileCounter

jax.config.update("jax_enable_x64", True)

SYSTEM = "mould_fungicide"
TRANSCRIPTION = Trapezoidal(intervals=8)


@functools.cache
def problem():
    """The system, its NLP (one object for the whole module, so compiled programs are shared) and default data."""
    system = load(SYSTEM)
    return system, TRANSCRIPTION.transcribe(system), default_data(system)



# ---- differentiation -------------------------------------------------------------------------------------------------


def loss_of_solution(solve_fn, data, z0):
    """params -> sum of the solution's z: a scalar function of a pure solve."""
    return lambda params: jnp.sum(solve_fn(ProblemData(params, data.x0), z0).z)


def test_reverse_mode_through_a_pure_solve_raises():
    """jax.grad of a function of a pure solve raises JAX's while_loop error; it never returns a silent zero."""
    _, nlp, data = problem()
    solve_fn = Extragradient().solve_fn(nlp)
    z0 = nlp.initial_guess(data)
    with pytest.raises(ValueError, match="Reverse-mode differentiation does not work for lax.while_loop"):
        jax.grad(loss_of_solution(solve_fn, data, z0))(data.params)


def test_forward_mode_through_a_pure_solve_runs():
    """jax.jvp goes through the solve: finite tangents, not all zero (the solution moves with r), equal to central
    differences of the solve (a fixed program while the iteration count does not change: measured 2e-8 relative)."""
    _, nlp, data = problem()
    solve_fn = Extragradient().solve_fn(nlp)
    z0 = nlp.initial_guess(data)
    tangent = jax.tree.map(jnp.zeros_like, data.params)
    tangent["r"] = jnp.ones_like(tangent["r"])

    def solution(params):
        out = solve_fn(ProblemData(params, data.x0), z0)
        return out.z, out.iterations, out.converged

    (z, iterations, converged), (dz, _, _) = jax.jvp(solution, (data.params,), (tangent,))
    assert bool(converged)
    dz = np.asarray(dz)
    assert np.all(np.isfinite(dz)) and np.any(dz != 0)
    # The primal output is the plain solve's (up to rounding: the JVP program is compiled on its own).
    np.testing.assert_allclose(z, solve_fn(data, z0).z, rtol=1e-12, atol=0)

    eps = 1e-4
    plus, minus = (solve_fn(ProblemData({**data.params, "r": data.params["r"] + s * eps}, data.x0), z0)
                   for s in (1.0, -1.0))
    assert int(plus.iterations) == int(minus.iterations) == int(iterations), "the finite difference crosses a stop"
    fd = (np.asarray(plus.z) - np.asarray(minus.z)) / (2 * eps)
    assert np.max(np.abs(dz - fd)) <= 1e-6 * np.max(np.abs(fd))


# ---- batches -------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", [Ipopt(), SLSQP()], ids=lambda s: type(s).__name__)
def test_solve_batch_refuses_a_solver_that_is_not_pure(solver):
    pure = sorted(label for label, cls in SOLVERS.items() if issubclass(cls, AbstractPureSolver))
    assert pure, "no pure solver is registered"
    with pytest.raises(TypeError) as info:
        solve_batch(load(SYSTEM), TRANSCRIPTION, solver, params={"r": np.array([0.3, 0.4])})
    message = str(info.value)
    assert type(solver).__name__ in message
    for label in pure:
        assert label in message, message


@pytest.mark.slow
def test_batch_members_have_their_own_status():
    """One batch, three outcomes: a member that converges, one that hits the iteration limit and one with non-finite
    data. The limit is set between the two finite members' iteration counts, measured on the same batch first."""
    system, _, _ = problem()
    params = {"r": np.array([0.6, 0.1, 0.3])}
    x0 = np.array([[1.0], [1.0], [np.nan]])

    measured = solve_batch(system, TRANSCRIPTION, Extragradient(), params=params, x0=x0)
    assert [s.status for s in measured] == [Status.CONVERGED, Status.CONVERGED, Status.NOT_FINITE]
    fast, slow = measured[0].iterations, measured[1].iterations
    assert 0 < fast < slow and measured[2].iterations == 0
    limit = int(math.sqrt(fast * slow))

    limited = solve_batch(system, TRANSCRIPTION, Extragradient(max_iter=limit), params=params, x0=x0)
    assert [s.status for s in limited] == [Status.CONVERGED, Status.ITERATION_LIMIT, Status.NOT_FINITE]
    assert [s.converged for s in limited] == [True, False, False]
    assert [s.iterations for s in limited] == [fast, limit, 0]
    # A stopped member is frozen, whatever the others do: the converged one is the same solve as before.
    np.testing.assert_array_equal(limited[0].controls, measured[0].controls)
    assert limited[0].cost == measured[0].cost
    assert np.isfinite(limited[1].cost) and not np.isfinite(limited[2].cost)


# ---- compilation -----------------------------------------------------------------------------------------------------


def new_data(system, r: float, x0: float) -> ProblemData:
    return default_data(system, params={"r": r}, x0=[x0])


def test_second_solve_with_new_data_compiles_nothing():
    """Extragradient().solve: the second solve with new data of the same shapes reports and does no compilation, even
    when the parameters come as Python floats and x0 as NumPy (solve canonicalises them; a weakly typed float would
    otherwise trace a second program)."""
    system, nlp, data = problem()
    solver = Extragradient()
    first = solver.solve(nlp, new_data(system, 0.35, 1.0))
    assert first.success
    loose = ProblemData({**{k: float(v) for k, v in data.params.items()}, "r": 0.4}, np.array([1.3]))
    with CompileCounter() as counter:
        second = solver.solve(nlp, loose)
    assert second.success and second.compile_seconds == 0.0
    assert counter.events == []
    assert second.objective != first.objective  # it really solved the new problem


def test_second_solve_batch_with_new_data_compiles_nothing():
    system, nlp, _ = problem()
    solver = Extragradient()
    first = solver.solve_batch(nlp, batch_data(system, params={"r": [0.3, 0.4]}, x0=[[1.0], [1.1]]))
    with CompileCounter() as counter:
        second = solver.solve_batch(nlp, batch_data(system, params={"r": [0.5, 0.6]}, x0=[[0.9], [1.2]]))
    assert all(res.success for res in first + second)
    assert all(res.compile_seconds == 0.0 for res in second)
    assert counter.events == []
    assert len({res.objective for res in first + second}) == 4


def test_jitted_solve_fn_does_not_retrace_for_new_data():
    """A Python side effect in the objective counts traces: a second call with new data of the same shapes runs the
    compiled program without tracing the NLP's functions again."""
    system, base, data = problem()
    counter = {"traces": 0}

    def objective(z, d):
        counter["traces"] += 1
        return base.objective(z, d)

    nlp = dataclasses.replace(base, objective=objective)
    solve_fn = Extragradient().solve_fn(nlp)
    z0 = nlp.initial_guess(data)
    first = solve_fn(new_data(system, 0.3, 1.0), z0)
    traces = counter["traces"]
    assert traces > 0
    with CompileCounter() as compiles:
        second = solve_fn(new_data(system, 0.45, 1.2), z0)
        jax.block_until_ready(second)
    assert counter["traces"] == traces, "the second call retraced the objective"
    assert compiles.events == []
    if hasattr(solve_fn, "_cache_size"):
        assert solve_fn._cache_size() == 1
    assert bool(first.converged) and bool(second.converged)
    assert not np.allclose(first.z, second.z)


@pytest.mark.parametrize("chunk", [None, 1, 2, 3, 5, 8])
def test_vmapped_in_chunks_equals_one_vmap(chunk):
    """A batch in chunks (the last one padded with copies of the last member) gives each member what one vmap
    gives it, also for members whose loops stop at different iterations."""
    from myriad.runtime.solvers.pure import _vmapped_in_chunks

    def member(data, z0):  # Newton's iteration for sqrt(data["a"]): a member-dependent number of steps
        def body(c):
            z, k = c
            return 0.5 * (z + data["a"] / z), k + 1

        return jax.lax.while_loop(lambda c: jnp.abs(c[0] ** 2 - data["a"]) > 1e-12 * data["a"], body, (z0, 0))

    a = jnp.asarray([0.5, 2.0, 9.0, 1e4, 3.0])
    z0 = jnp.ones(5)
    expected = jax.vmap(member)({"a": a}, z0)
    got = jax.jit(_vmapped_in_chunks(member, chunk))({"a": a}, z0)
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])
    assert len(set(np.asarray(got[1]).tolist())) > 1  # the members did stop at different iterations



@pytest.mark.parametrize("slots", [1, 2, 3, 5, 7, 8])
def test_queued_equals_one_vmap(slots):
    """A batch with at most ``slots`` members in flight, each stopped member's place taken by the next waiting one,
    gives each member what one vmap of the whole solve gives it, in the members' order."""
    from myriad.runtime.solvers.stepper import Stepper, queued

    def step(data, state):  # Newton's iteration for sqrt(a): a member-dependent number of steps
        z, k, a = state
        return 0.5 * (z + a / z), k + 1, a

    stepper = Stepper(begin=lambda data, z0: (z0, 0, data["a"]), step=step,
                      running=lambda s: jnp.abs(s[0] ** 2 - s[2]) > 1e-12 * s[2],
                      end=lambda data, s: {"root": s[0], "steps": s[1], "twice": 2.0 * data["a"]})
    a = jnp.asarray([0.5, 2.0, 9.0, 1e4, 3.0, 1e8, 0.01])
    z0 = jnp.ones(7)
    expected = jax.vmap(stepper.solve)({"a": a}, z0)
    got = jax.jit(queued(stepper, slots))({"a": a}, z0)
    for key in expected:
        np.testing.assert_array_equal(got[key], expected[key])
    assert len(set(np.asarray(got["steps"]).tolist())) > 3  # the members did stop at different iterations
    np.testing.assert_allclose(got["root"], np.sqrt(a), rtol=1e-12)


def test_the_extragradient_stepper_drives_a_queued_batch():
    """The extragradient's stepper (the one its pure solve loops over) in a queue with 2 places for 3 members: each
    member stops where its own solve stops, at the same point."""
    from myriad.runtime.solvers.stepper import queued

    system, nlp, _ = problem()
    solver = Extragradient(max_iter=2000)
    data = batch_data(system, params={"r": jnp.asarray([0.6, 0.1, 0.3])})
    z0 = jnp.stack([jnp.asarray(nlp.initial_guess(jax.tree.map(lambda a: a[i], data))) for i in range(3)])
    expected = jax.jit(jax.vmap(solver.pure_solve(nlp)))(data, z0)
    got = jax.jit(queued(solver.batch_stepper(nlp), 2))(data, z0)
    np.testing.assert_array_equal(got.iterations, expected.iterations)
    assert len(set(np.asarray(got.iterations).tolist())) == 3  # the members did stop at different iterations
    np.testing.assert_allclose(got.z, expected.z, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(got.converged, expected.converged)
