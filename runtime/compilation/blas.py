"""One BLAS thread while myriad solves: the compiled programs' LAPACK calls must not depend on the caller's threading.

JAX's CPU kernels for dense factorisations (``cholesky``, ``eigh``, ``lu``, triangular solves: the interior point's
Newton steps) call the LAPACK that jaxlib takes from SciPy (``scipy.linalg.cython_lapack``, i.e. SciPy's bundled
OpenBLAS), which starts one thread per core. On small matrices those threads cost more than they save, and on a busy
machine they fight: Van der Pol, Hermite-Simpson(100), ``InteriorPoint(kkt="dense")`` took a median 0.40-0.54 s per
warm solve (0.8-1.1 s of CPU) with OpenBLAS's default two threads against 0.17-0.26 s (0.26 s of CPU) with one
(2-core machine, load 1-1.9); single shooting with 400 controls, dense, a median 3.6-10.7 s with two threads against
0.29-0.30 s with one (load 3.8-4.1: the threads spin while they wait); the issue recorded 31 s for the first.

:func:`one_blas_thread` limits every loaded BLAS to one thread (threadpoolctl) for the duration of a solve and restores
the caller's limits after it, so the user's own NumPy work outside a solve keeps its threads. OpenBLAS's limit is a
process-wide setting, not a per-thread one: it covers XLA's own threads, which run the kernels, and for the same
reason any BLAS call the caller's *other* threads make while a solve runs gets one thread too. Nested and concurrent
solves share one limit, set by the first to enter and restored by the last to leave.

The user's explicit choice wins: with any of :data:`USER_VARIABLES` in the environment (``OPENBLAS_NUM_THREADS=4``,
say, where threads may pay: large dense matrices on a quiet many-core machine, not measured here) nothing is
changed. Code that jits a pure solve into its own program (``solve_fn``, a learner's training step) runs it outside
:func:`myriad.runtime.solve`: wrap the calls in :func:`one_blas_thread` or set ``OPENBLAS_NUM_THREADS=1``.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["USER_VARIABLES", "blas_threads", "one_blas_thread"]

# The variables OpenBLAS (the first three, in its order), MKL and BLIS read for their thread counts.
USER_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")

_lock = threading.Lock()
_state = {"depth": 0, "limiter": None}


@functools.cache
def _controller():
    # SciPy's LAPACK (and so its OpenBLAS) is loaded first, as jaxlib does at its first LAPACK call (the first solve's
    # compile, inside the block): threadpoolctl sees only the libraries loaded when its controller is made, and the
    # controller is made once (1.4-9 ms each, against 16 us a limit). Here, not at the top: ``import myriad.runtime``
    # loads no SciPy (tests/runtime/test_cold_start.py); the first solve pays it once (60-70 ms measured).
    import scipy.linalg.cython_lapack  # noqa: F401
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def blas_threads() -> dict[str, int]:
    """Each loaded BLAS library's file name and its current thread limit (what a solve runs with inside
    :func:`one_blas_thread`)."""
    return {os.path.basename(info["filepath"]): info["num_threads"]
            for info in _controller().select(user_api="blas").info()}


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Limit every loaded BLAS to one thread inside the block (also a decorator), unless the user set a variable of
    :data:`USER_VARIABLES`; the limits found on entering are restored when the last nested or concurrent block
    leaves."""
    if any(name in os.environ for name in USER_VARIABLES):
        yield
        return
    with _lock:
        if _state["depth"] == 0:
            _state["limiter"] = _controller().limit(limits=1, user_api="blas")
        _state["depth"] += 1
    try:
        yield
    finally:
        with _lock:
            _state["depth"] -= 1
            if _state["depth"] == 0:
                _state["limiter"].restore_original_limits()
                _state["limiter"] = None
