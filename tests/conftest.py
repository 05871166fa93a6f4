"""Test-wide settings: float64 everywhere and strict dtype promotion, so silent float32 or int/float mixing fails."""

import os

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Threaded OpenBLAS inside SciPy's SLSQP thrashes a busy 2-core machine (175 s instead of 1.4 s measured).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# Tests that call the CLI in-process would otherwise turn on the persistent compilation cache in the user's
# ~/.cache for the rest of the worker; the cache's own tests name their folders explicitly.
os.environ.setdefault("MYRIAD_JAX_CACHE", "off")
# The suite is compile-bound, and XLA's CPU fusion emitters compile slower than its loop emitter: the Riccati and
# Neural-ODE end-to-end files took 164 s without this flag and 127-130 s with it (2-core AMD EPYC, 2026-12-04, two
# runs each). Both compile the same HLO program; `myriad bench --compile quick` turns them off too (programs.py).
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_use_fusion_emitters=false".strip()
# LLVM's lowest optimisation level, for the same reason (a test's programs run a few times; compiling them is most of
# its time): test_gradients.py and test_solvers.py 65 -> 51 s of CPU, the Riccati file 93 -> 70 s, e2e/test_gradients.py
# and solvers/test_interior_point.py 89 -> 67 s, every test passing (2-core AMD EPYC, 2026-12-05, one process each).
# `myriad bench --compile quick` sets it too (programs.QUICK).
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_backend_optimization_level=0".strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Empty the runtime's and JAX's program caches after each test file. A worker goes through hundreds of problems;
    kept, their programs' machine code reached Linux's 65,530 memory mappings per process (vm.max_map_count) near the
    end of `make test`, and XLA then crashed the worker (runtime/compilation/caches.py)."""
    yield
    from myriad.runtime.compilation.caches import clear_caches

    clear_caches()
