"""A batch spread over several devices (``pure._across``): each member gets what one device gives it.

JAX fixes its device count when it starts, so the check runs in a fresh process told to see two host devices
(``--xla_force_host_platform_device_count=2``), the way ``bench/batch_throughput.py`` uses both cores of a CPU."""

import os
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.slow  # not in `make test-fast`: a fresh process compiling for two host devices

SCRIPT = textwrap.dedent("""
    import os
    # Two host devices, and the suite's quick compilation (tests/conftest.py: the same programs, compiled faster)
    os.environ["XLA_FLAGS"] = ("--xla_force_host_platform_device_count=2 --xla_cpu_use_fusion_emitters=false "
                               "--xla_backend_optimization_level=0")
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    from myriad.runtime import load, solve, solve_batch
    from myriad.runtime.solvers import InteriorPoint
    from myriad.runtime.solvers.pure import _across, _vmapped_in_chunks

    assert len(jax.devices()) == 2, jax.devices()

    def member(data, z0):  # Newton's iteration for sqrt(a): a member-dependent number of steps
        body = lambda c: (0.5 * (c[0] + data["a"] / c[0]), c[1] + 1)
        return jax.lax.while_loop(lambda c: jnp.abs(c[0] ** 2 - data["a"]) > 1e-12 * data["a"], body, (z0, 0))

    for size in (1, 2, 5, 6):  # one member (no split), even, padded
        a = jnp.asarray([0.5, 2.0, 9.0, 1e4, 3.0, 7.0][:size])
        z0 = jnp.ones(size)
        expected = jax.vmap(member)({"a": a}, z0)
        for chunk in (None, 2):
            got = jax.jit(_across(_vmapped_in_chunks(member, chunk), jax.devices()))({"a": a}, z0)
            np.testing.assert_array_equal(got[0], expected[0])
            np.testing.assert_array_equal(got[1], expected[1])

    from myriad.runtime.solvers.interior_point.solver import CPU_CHUNK_SHARED
    assert InteriorPoint(batch="vmap").batch_chunk() == CPU_CHUNK_SHARED  # each device's chunk: shared caches

    # The wiring: solve_batch compiles one program for both devices; every member matches its own solve.
    system = load("simple_case")
    x0 = np.array([[0.9], [1.0], [1.1]])
    batch = solve_batch(system, solver=InteriorPoint(), x0=x0)
    for sol, x in zip(batch, x0):
        one = solve(system, solver=InteriorPoint(), x0=x)
        assert sol.converged and one.converged
        assert abs(sol.cost - one.cost) <= 1e-8 * abs(one.cost), (sol.cost, one.cost)
    print("ok")
""")


def test_batch_across_two_host_devices():
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    env.pop("XLA_FLAGS", None)
    run = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0 and run.stdout.strip().endswith("ok"), run.stderr[-3000:]
