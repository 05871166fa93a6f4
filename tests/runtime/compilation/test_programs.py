"""The program store (``myriad.runtime.compilation.programs``): keys, a later process that traces nothing, and its
fallbacks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import RK4, Heun, MultipleShooting, SingleShooting, load
from myriad.runtime.compilation import programs
from myriad.runtime.solve import transcribe
from myriad.runtime.solvers import InteriorPoint

jax.config.update("jax_enable_x64", True)


@pytest.fixture
def store(tmp_path):
    previous = programs.program_folder()
    programs.set_program_folder(tmp_path / "programs")
    yield tmp_path / "programs"
    programs.set_program_folder(previous)


def test_describe_is_a_canonical_text_of_plain_configurations():
    a = programs.describe(SingleShooting(intervals=100, integrator=Heun()))
    assert a == programs.describe(SingleShooting(intervals=100, integrator=Heun()))
    others = [SingleShooting(intervals=99, integrator=Heun()), SingleShooting(intervals=100, integrator=RK4()),
              MultipleShooting(intervals=100), InteriorPoint(), InteriorPoint(tol=1e-9)]
    texts = [programs.describe(o) for o in others]
    assert None not in texts and len({a, *texts}) == 1 + len(others)
    assert programs.describe(InteriorPoint(tol=0.1 + 0.2)) != programs.describe(InteriorPoint(tol=0.3))  # repr, exact
    assert programs.describe(np.ones(3)) is None and programs.describe(lambda: 0) is None
    assert programs.describe((1, "a", None, 2.5)) == "[1,'a',None,2.5]"


def test_system_keys_name_the_generated_source():
    keys = {programs.system_key(load(name)) for name in ("van_der_pol", "simple_case", "pendulum")}
    assert None not in keys and len(keys) == 3

    class Handmade:  # not a spec-generated module: its behaviour is not pinned down by a file
        pass

    assert programs.system_key(Handmade()) is None
    nlp = transcribe(load("simple_case"), SingleShooting(intervals=10, integrator=Heun()))
    assert nlp.key is not None and programs.system_key(load("simple_case")) in nlp.key


def test_a_stored_program_is_read_back_without_tracing(store, monkeypatch):
    traces = []

    def f(x, data):
        traces.append(1)
        return jnp.sin(x) @ data["a"] + jnp.cumsum(x)

    args = (jnp.linspace(0.0, 1.0, 5), {"a": jnp.ones((5, 5))})
    expected = jax.jit(f)(*args)
    first = programs.lower(jax.jit(f), "test:f", args).compile()(*args)
    files = os.listdir(store)
    assert len(files) == 1 and files[0].endswith(".jaxexport")
    count = len(traces)
    second = programs.lower(jax.jit(f), "test:f", args).compile()(*args)
    assert len(traces) == count, "the stored program was traced again"
    np.testing.assert_array_equal(first, expected)
    np.testing.assert_array_equal(second, expected)
    # Another key or another shape is another program.
    programs.lower(jax.jit(f), "test:g", args)
    programs.lower(jax.jit(f), "test:f", (jnp.zeros(4), {"a": jnp.ones((4, 4))}))
    assert len(os.listdir(store)) == 3


def test_no_key_no_file_and_a_broken_file_is_replaced(store):
    f = jax.jit(lambda x: 2.0 * x)
    programs.lower(f, None, (jnp.ones(3),)).compile()
    assert not store.exists()
    programs.lower(f, "test:double", (jnp.ones(3),))
    (path,) = store.iterdir()
    path.write_bytes(b"not a program")
    out = programs.lower(f, "test:double", (jnp.ones(3),)).compile()(jnp.arange(3.0))
    np.testing.assert_array_equal(out, [0.0, 2.0, 4.0])
    assert path.read_bytes() != b"not a program"


def test_a_program_that_cannot_be_exported_is_lowered_as_usual(store):
    def f(x):  # a host callback has no serialised form
        return jax.pure_callback(lambda v: np.asarray(v) + 1.0, jax.ShapeDtypeStruct((3,), jnp.float64), x)

    out = programs.lower(jax.jit(f), "test:callback", (jnp.ones(3),)).compile()(jnp.ones(3))
    np.testing.assert_array_equal(out, [2.0, 2.0, 2.0])
    assert not store.exists() or not os.listdir(store)


def test_a_code_change_is_another_program(store, monkeypatch):
    f = jax.jit(lambda x: x + 1.0)
    programs.lower(f, "test:inc", (jnp.ones(2),))
    monkeypatch.setattr(programs, "_code_fingerprint", lambda: "another version of the package")
    programs.lower(f, "test:inc", (jnp.ones(2),))
    assert len(os.listdir(store)) == 2


# A fresh interpreter with the cache on (as the `myriad` commands have it) that solves and re-simulates a small
# problem and counts the calls of the system's vector field: they happen only while a program is traced.
_CHILD = textwrap.dedent("""
    import json, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    from myriad.runtime.compilation.jax_cache import enable_compilation_cache
    enable_compilation_cache(sys.argv[1])
    from myriad.runtime import Heun, SingleShooting, load, solve
    from myriad.runtime.solvers import SOLVERS

    system = load("bacteria")
    calls = []
    dynamics = type(system).dynamics
    type(system).dynamics = staticmethod(lambda *a: calls.append(1) or dynamics(*a))
    sol = solve(system, SingleShooting(intervals=12, integrator=Heun()), SOLVERS[sys.argv[2]]())
    print(json.dumps({"calls": len(calls), "cost": sol.cost, "simulated": sol.simulated_cost,
                      "error": sol.error_estimate, "converged": sol.converged}))
""")


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["ipopt", "interior_point"])
def test_a_second_process_traces_nothing(tmp_path, solver):
    def child():
        env = {k: v for k, v in os.environ.items() if k not in ("MYRIAD_JAX_CACHE", "JAX_COMPILATION_CACHE_DIR")}
        out = subprocess.run([sys.executable, "-c", _CHILD, str(tmp_path / "jax"), solver], capture_output=True,
                             text=True, env=env, timeout=600, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    first, second = child(), child()
    assert first["converged"] and first["calls"] > 0
    assert second["calls"] == 0, "the second process traced the system again"
    assert second == {**first, "calls": 0}  # bit for bit the same solve, simulation and error estimate


def test_compile_many_does_the_callers_work_while_xla_compiles_and_once_when_all_are_cached():
    import threading

    from myriad.runtime.compilation import CompiledFunction, compile_many

    calls, one = [], CompiledFunction(lambda x: 2.0 * x)

    def meanwhile():  # in the caller's thread, while the program is not yet compiled
        calls.append((threading.current_thread() is threading.main_thread(), one.is_compiled(np.ones(3))))

    assert compile_many([(one, (np.ones(3),))], meanwhile) > 0.0
    np.testing.assert_array_equal(one(np.ones(3)), 2.0 * np.ones(3))
    assert compile_many([(one, (np.ones(3),))], meanwhile) == 0.0  # cached: the work is still done, once
    assert calls == [(True, False), (True, True)]


def test_compiler_options_reach_every_compile_and_change_no_value():
    """`myriad bench` compiles at XLA's backend optimisation level 0: the options reach both compile paths (a bad one
    is refused by XLA), and the solve gives the same optimum to rounding."""
    from myriad.runtime.compilation import CompiledFunction, compile_many

    system = load("mould_fungicide")
    try:
        programs.set_compiler_options({"no_such_xla_option": 1})
        with pytest.raises(Exception, match="no_such_xla_option"):
            CompiledFunction(lambda x: x + 1.0).compile(np.ones(3))
        with pytest.raises(Exception, match="no_such_xla_option"):
            compile_many([(CompiledFunction(lambda x: 2.0 * x), (np.ones(3),)),
                          (CompiledFunction(lambda x: 3.0 * x), (np.ones(3),))])
        programs.set_compiler_options(programs.QUICK)
        assert programs.compiler_options() == programs.QUICK
        from myriad.runtime import solve

        quick = solve(system, SingleShooting(intervals=40, integrator=Heun()), resimulate=False)
    finally:
        programs.set_compiler_options(None)
    full = solve(system, SingleShooting(intervals=40, integrator=Heun()), resimulate=False)
    assert programs.compiler_options() is None and quick.converged and full.converged
    np.testing.assert_allclose(quick.cost, full.cost, rtol=1e-12)
    np.testing.assert_allclose(quick.controls, full.controls, rtol=1e-9, atol=1e-12)
