"""Solves run on one BLAS thread whatever the caller's threading, the caller's limits come back after, and a thread
variable the user set wins (``runtime/compilation/blas.py``).

The caller's "default threading" is played by a limit of two threads set with threadpoolctl (the suite itself runs
with ``OPENBLAS_NUM_THREADS=1``, which the tests take out of the environment). The limit is read where it matters:
inside a compiled program, by a host callback that runs on XLA's threads, for the OpenBLAS that JAX's LAPACK
kernels call (SciPy's, whose file name lacks NumPy's ``64_`` suffix).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from myriad.runtime import load, solve
from myriad.runtime.compilation.blas import USER_VARIABLES, blas_threads, one_blas_thread
from myriad.runtime.method import AbstractMethod
from myriad.runtime.solvers import AbstractPureSolver

jax.config.update("jax_enable_x64", True)

CALLER = 2  # the caller's limit, as threaded OpenBLAS has it on a 2-core machine


def _jax_lapack_threads() -> int:
    """The thread limit of SciPy's OpenBLAS, the library jaxlib's CPU LAPACK kernels call."""
    (limit,) = [n for name, n in blas_threads().items() if name.startswith("libscipy_openblas") and "64_" not in name]
    return limit


@pytest.fixture
def threaded_caller(monkeypatch):
    for name in USER_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    with threadpool_limits(limits=CALLER, user_api="blas"):
        # A serial BLAS stays at one thread whatever the limit (Debian's openblas-serial under IPOPT, once cyipopt
        # is loaded): the one that matters is SciPy's, which jaxlib calls.
        assert _jax_lapack_threads() == CALLER
        before = blas_threads()
        yield
        assert blas_threads() == before, "the caller's limits were not restored"


class _Problem:
    key = None  # no program store


@dataclasses.dataclass(frozen=True)
class _ReadsBlas(AbstractPureSolver):
    """A pure solver whose whole program reads the BLAS limit from inside XLA (a host callback)."""

    label = "reads_blas"

    def pure_solve(self, problem: Any):
        def read(data, z0):
            shape = jax.ShapeDtypeStruct((), jnp.float64)
            seen = jax.pure_callback(lambda: np.float64(_jax_lapack_threads()), shape, vmap_method="sequential")
            return z0 * 0 + seen

        return read

    def start(self, problem: Any, data: Any, z0: Any = None) -> np.ndarray:
        return np.zeros(1)

    def report(self, problem: Any, output: Any, data: Any, compile_seconds: float, solve_seconds: float) -> Any:
        return int(np.asarray(output)[0])


def test_pure_solves_see_one_thread_inside_xla(threaded_caller):
    problem, solver = _Problem(), _ReadsBlas()
    assert solver._solve_single(problem, {"k": np.ones(1)}) == 1
    assert solver.solve_batch(problem, {"k": np.ones((3, 1))}) == [1, 1, 1]
    # The same program called outside a solve (a user's own jit of the pure solve) runs with the caller's limit.
    assert int(solver.solve_fn(problem)({"k": np.ones(1)}, np.zeros(1))[0]) == CALLER


class _Recorder(AbstractMethod):
    """A method that records the limit the public ``solve`` gives it (any method, any solver: SLSQP's and IPOPT's
    BLAS calls are host-side)."""

    label, quadrature = "recorder", "none"

    def __init__(self):
        self.seen: list[int] = []

    @classmethod
    def on_grid(cls, intervals: int, **options: Any) -> AbstractMethod:
        return cls()

    def solve_problem(self, system, solver, data, z0=None):
        self.seen.append(_jax_lapack_threads())
        return "solved"

    def solve_problems(self, system, solver, data):
        raise NotImplementedError


def test_solve_runs_on_one_thread(threaded_caller):
    method = _Recorder()
    assert solve(load("van_der_pol"), method, resimulate=False) == "solved"
    assert method.seen == [1]


def test_nested_blocks_restore_once(threaded_caller):
    with one_blas_thread():
        with one_blas_thread():
            assert _jax_lapack_threads() == 1
        assert _jax_lapack_threads() == 1, "the inner block restored the caller's limit while the outer still runs"
    assert _jax_lapack_threads() == CALLER


@pytest.mark.parametrize("variable", ["OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"])
def test_a_variable_the_user_set_wins(threaded_caller, monkeypatch, variable):
    monkeypatch.setenv(variable, str(CALLER))
    method = _Recorder()
    solve(load("van_der_pol"), method, resimulate=False)
    assert method.seen == [CALLER]
