"""InteriorPoint's solve in two programs (``InteriorPointStepper.staged``): the first without the restoration phase,
the second, with it, compiled only when a solve needs it.

What must hold: a solve equals the one-program solve (``solve_fn``) to the last bit, and a batch's members take its
iterations, whether or not they enter the restoration phase; the first program really stops where the phase starts
(else the second stage is never tested); the second program is compiled at its first need only, once per shapes.
Wächter & Biegler's example (tests/runtime/solvers/test_interior_point_restoration.py) restores from ``x1 < 0``;
from ``x = (-1, 2, 3)`` with ``b = -1`` it converges without the phase.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime.nlp import NLP
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.solvers.base import canonical_data

from ...helpers import CompileCounter

pytestmark = pytest.mark.slow  # not in `make test-fast`: about twenty programs of a small NLP compiled

jax.config.update("jax_enable_x64", True)

INF = np.inf


@functools.cache
def wachter_biegler() -> NLP:
    """min x1 s.t. x1^2 - x2 + a = 0, x1 - x3 - b = 0, x2, x3 >= 0; the start is data["x0"] (as in
    test_interior_point_restoration.py; one NLP object for this module, so its programs are shared)."""
    f64 = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731

    def constraints(z, d):
        return jnp.stack([z[0] ** 2 - z[1] + d["params"]["a"], z[0] - z[2] - d["params"]["b"]])

    return NLP(lambda z, d: z[0], constraints, f64([0, 0]), f64([0, 0]), f64([-INF, 0, 0]), f64([INF, INF, INF]),
               lambda d: d["x0"], lambda z, d: (jnp.zeros(1), z[None, :], jnp.zeros((1, 0))), name="wachter_biegler")


def wb_data(a, b, start=(-2.0, 1.0, 1.0)):
    return {"params": {"a": np.float64(a), "b": np.float64(b)}, "x0": np.asarray(start, dtype=np.float64)}



RESTORES = [wb_data(1.0, 0.5), wb_data(-1.0, -1.0)]
PLAIN = wb_data(1.0, -1.0, (-1.0, 2.0, 3.0))


def one_program(solver, nlp, data):
    """The solve as one program (the restoration phase inside the loop), as ``solve_fn`` gives it."""
    return jax.device_get(solver.solve_fn(nlp)(canonical_data(data), jnp.asarray(data["x0"])))


def first_stops(solver, nlp, data) -> bool:
    """Whether the first program alone stopped the solve for the restoration phase."""
    staged = solver.staged(nlp)
    out, _ = jax.jit(staged.first.solve)(canonical_data(data), jnp.asarray(data["x0"]))
    return bool(staged.pending(out))


def test_the_first_program_stops_exactly_where_the_restoration_phase_starts():
    solver, nlp = InteriorPoint(), wachter_biegler()
    assert all(first_stops(solver, nlp, d) for d in RESTORES)
    assert not first_stops(solver, nlp, PLAIN)


def test_single_solves_equal_the_one_program_solve_bit_for_bit():
    solver, nlp = InteriorPoint(), wachter_biegler()
    for data in [PLAIN, *RESTORES]:
        staged, whole = solver.solve(nlp, data), one_program(solver, nlp, data)
        assert staged.success and staged.iterations == int(whole.iterations)
        np.testing.assert_array_equal(staged.z, whole.z)
        np.testing.assert_array_equal(staged.multipliers, whole.multipliers)


def test_the_restoration_program_compiles_at_its_first_need_only():
    solver, nlp = InteriorPoint(tol=1e-9), wachter_biegler()  # a configuration of its own: nothing compiled yet
    programs = solver._programs(nlp).single
    assert solver.solve(nlp, PLAIN).success
    assert not programs.rest._executables, "a solve without restoration compiled the restoration program"
    first = solver.solve(nlp, RESTORES[0])
    assert first.success and first.compile_seconds > 0.0 and len(programs.rest._executables) == 1
    with CompileCounter() as counter:
        second = solver.solve(nlp, RESTORES[1])
    assert second.success and second.compile_seconds == 0.0 and counter.events == []


@pytest.mark.parametrize("strategy, chunk", [("vmap", None), ("vmap", 2), ("map", None)])
def test_a_batch_continues_its_restoring_members_and_equals_single_solves(strategy, chunk):
    nlp = wachter_biegler()
    solver = InteriorPoint(batch=strategy, chunk=chunk)
    members = [PLAIN, RESTORES[0], PLAIN, RESTORES[1]]
    batched = jax.tree.map(lambda *leaves: np.stack(leaves), *members)
    results = solver.solve_batch(nlp, batched)
    for result, data in zip(results, members):
        whole = one_program(InteriorPoint(), nlp, data)
        # A vmapped member's arithmetic is not the single program's to the last bit (before the two stages too).
        assert result.success and result.iterations == int(whole.iterations)
        np.testing.assert_allclose(result.z, whole.z, rtol=0, atol=1e-12)
    # Without a restoring member the batch never compiles the second program; a second batch compiles nothing.
    plain = jax.tree.map(lambda *leaves: np.stack(leaves), *[PLAIN] * 4)
    fresh = InteriorPoint(batch=strategy, chunk=chunk, tol=1e-9)
    assert all(r.success for r in fresh.solve_batch(nlp, plain))
    assert not fresh._programs(nlp).batched.rest._executables
    with CompileCounter() as counter:
        again = solver.solve_batch(nlp, batched)
    assert counter.events == [] and all(r.compile_seconds == 0.0 for r in again)
