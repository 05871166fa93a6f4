"""The CasADi export against the generated JAX code: the same f, L, phi (minimisation form), to rounding."""

import math
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest
import sympy

ca = pytest.importorskip("casadi")

from myriad.compiler.build import check_file  # noqa: E402
from myriad.compiler.casadi_export import CasadiExportError, export_file, sympy_to_casadi, to_casadi  # noqa: E402
from myriad.compiler.expressions import wrap_floor, wrap_mod  # noqa: E402
from myriad.runtime import load  # noqa: E402

from ..helpers import ALL_SPECS, ROOT, sample_interval  # noqa: E402

N_POINTS = 3
RTOL = 1e-12


def _points(cs, seed):
    rng = np.random.default_rng(seed)
    xs = np.stack([sample_interval(lo, hi, x0, rng, N_POINTS)
                   for lo, hi, x0 in zip(cs.x_lower, cs.x_upper, cs.x0)], 1)
    us = np.stack([sample_interval(lo, hi, 0.0, rng, N_POINTS) for lo, hi in zip(cs.u_lower, cs.u_upper)], 1)
    ts = rng.uniform(0.0, cs.horizon, size=N_POINTS)
    # Parameters off their nominal values (so a mix-up of their order cannot pass), within 10 %.
    ps = np.asarray(cs.param_values) * (1 + 0.1 * rng.uniform(-1, 1, size=(N_POINTS, cs.n_params)))
    return xs, us, ts, ps


def _assert_same(cs, system, seed=0):
    xs, us, ts, ps = _points(cs, seed)
    for x, u, t, p in zip(xs, us, ts, ps):
        params = {k: jnp.asarray(v) for k, v in zip(cs.param_names, p)}
        jx, ju, jt = jnp.asarray(x), jnp.asarray(u), jnp.asarray(t)
        want_f = np.asarray(system.dynamics(jx, ju, jt, params))
        want_L = float(system.running_cost(jx, ju, jt, params))
        want_phi = float(system.terminal_cost(jx, jt, params))
        got_f = np.asarray(cs.f(x, u, t, p)).ravel()
        got_L = float(cs.L(x, u, t, p))
        got_phi = float(cs.phi(x, t, p))
        assert np.all(np.isfinite(want_f)) and math.isfinite(want_L) and math.isfinite(want_phi)
        np.testing.assert_allclose(got_f, want_f, rtol=RTOL, atol=1e-300, err_msg=f"{cs.name}: f at x={x} u={u}")
        np.testing.assert_allclose(got_L, want_L, rtol=RTOL, atol=1e-300, err_msg=f"{cs.name}: L")
        np.testing.assert_allclose(got_phi, want_phi, rtol=RTOL, atol=1e-300, err_msg=f"{cs.name}: phi")


@pytest.mark.parametrize("path", ALL_SPECS, ids=lambda p: p.stem)
def test_casadi_matches_generated_jax(path):
    cs = to_casadi(check_file(path))
    system = load(path.stem)
    assert cs.name == system.name
    assert cs.horizon == system.horizon and cs.x0 == tuple(system.x0) and cs.x_final == tuple(system.x_final)
    assert (cs.x_lower, cs.x_upper) == (tuple(system.x_lower), tuple(system.x_upper))
    assert (cs.u_lower, cs.u_upper) == (tuple(system.u_lower), tuple(system.u_upper))
    assert cs.param_names == tuple(system.param_names) and cs.param_values == tuple(system.param_values)
    _assert_same(cs, system)


def test_every_whitelisted_construct_matches_jax(tmp_path, monkeypatch):
    # A spec that uses every function, condition and the angle-wrapping mod; with a payoff (maximize) to check
    # the sign, and a terminal cost.
    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path / "cache"))
    spec = tmp_path / "kitchen_sink.yaml"
    spec.write_text(textwrap.dedent("""\
        schema: 1
        name: kitchen_sink
        title: Kitchen sink
        description: Every expression construct of the spec language, for the CasADi export test.
        parameters:
          a: {value: 1.5}
          b: {value: -0.25}
        definitions:
          w: mod(x + pi, 2*pi) - pi
          s: where(x > 0 and not y < -1 or u == 0, sinh(u) + cosh(y/4), tanh(x) - 2**u)
        states:
          x: {initial: 0.5, bounds: [-3, 3]}
          y: {initial: -0.5, bounds: [-2, 2]}
        controls:
          u: {bounds: [-1, 1]}
        dynamics:
          x: a*w + s + exp(-x**2) + log(2 + y) + sqrt(3 + x) + atan2(y, x + 4) + sign(u - 0.1)*abs(y)**1.5
          y: sin(x) + cos(y)*tan(u/2) + asin(u/2) + acos(y/3) + atan(x*u) + min(x, y, b) + max(x, u) - clip(y, -0.5, b)
        cost:
          sense: maximize
          running: piecewise(t < 0.3, x*u, t >= 0.6 and y != 0, y/(1 + x**2), u**2/2) + mod(-x, b)
          terminal: x**3 - 1/(1 + y**2) + exp(1)
        horizon: 1
        """))
    cs = export_file(spec)
    system = load(spec)
    for seed in range(4):  # enough points to visit every branch of the conditions above
        _assert_same(cs, system, seed)
    # The branches: mod at negative values and exact multiples, the where at u == 0.
    p = cs.p0
    params = {k: jnp.asarray(v) for k, v in zip(cs.param_names, p)}
    for x, y, u, t in ((-2.5, 0.3, 0.0, 0.1), (math.pi, -1.5, 0.0, 0.7), (0.0, 0.0, -1.0, 0.5), (1.0, 1.9, 1.0, 0.9)):
        jx, ju = jnp.asarray([x, y]), jnp.asarray([u])
        np.testing.assert_allclose(np.asarray(cs.f([x, y], [u], t, p)).ravel(),
                                   np.asarray(system.dynamics(jx, ju, jnp.asarray(t), params)), rtol=RTOL)
        np.testing.assert_allclose(float(cs.L([x, y], [u], t, p)),
                                   float(system.running_cost(jx, ju, jnp.asarray(t), params)), rtol=RTOL)


def test_mod_has_the_sign_of_the_divisor_like_numpy_and_floor():
    x, m = sympy.symbols("x m", real=True)
    sx, sm = ca.SX.sym("x"), ca.SX.sym("m")
    fn = ca.Function("mod", [sx, sm], [sympy_to_casadi(wrap_mod(x, m), {x: sx, m: sm})])
    for a in (-7.5, -6.0, -0.1, 0.0, 0.1, 6.0, 7.5, 1e17):
        for b in (-2.0, 2.0, 2 * math.pi, -0.3):
            assert float(fn(a, b)) == float(np.mod(a, b)), (a, b)
    floor = ca.Function("floor", [sx], [sympy_to_casadi(wrap_floor(x), {x: sx})])
    assert [float(floor(a)) for a in (-1.5, -1.0, 0.0, 0.5, 2.0)] == [-2.0, -1.0, 0.0, 0.0, 2.0]


def test_unsupported_nodes_are_named():
    x = sympy.Symbol("x", real=True)
    sx = ca.SX.sym("x")
    with pytest.raises(CasadiExportError, match=r"`gamma`.*in dynamics\.x"):
        sympy_to_casadi(1 + sympy.gamma(x), {x: sx}, field="dynamics.x")
    with pytest.raises(CasadiExportError, match="`Integral`"):
        sympy_to_casadi(sympy.Integral(x, x), {x: sx})
    with pytest.raises(CasadiExportError, match="NaN"):
        sympy_to_casadi(x + sympy.nan, {x: sx})
    with pytest.raises(CasadiExportError, match="ImaginaryUnit"):
        sympy_to_casadi(x * sympy.I, {x: sx})
    with pytest.raises(CasadiExportError, match="without|default"):
        sympy_to_casadi(sympy.Piecewise((x, x > 0)), {x: sx})
    with pytest.raises(CasadiExportError, match="symbol `y` is not an argument"):
        sympy_to_casadi(x + sympy.Symbol("y", real=True), {x: sx})


def test_deep_expressions_do_not_hit_the_recursion_limit():
    x = sympy.Symbol("x", real=True)
    e = x
    for _ in range(sys.getrecursionlimit() // 2):  # a recursive walk (several frames per level) would overflow
        e = sympy.sin(e, evaluate=False)
    sx = ca.SX.sym("x")
    value = float(ca.Function("deep", [sx], [sympy_to_casadi(e, {x: sx})])(0.5))
    assert 0.0 < value < 0.5


def test_importing_the_export_loads_neither_casadi_nor_jax():
    code = "import sys, myriad.compiler.casadi_export; print(' '.join(sorted(m.split('.')[0] for m in sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    mods = set(out.stdout.split())
    assert "casadi" not in mods and "jax" not in mods


# -- schema 2: path constraints and a free final time, exported and posed with casadi.Opti -------------------------

SCHEMA2 = ROOT / "tests" / "compiler" / "schema2"


def test_path_constraints_match_generated_jax(tmp_path, monkeypatch):
    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path / "cache"))
    path = SCHEMA2 / "keep_out_zone.yaml"
    cs, system = export_file(path), load(path)
    assert cs.path_names == system.path_constraint_names == ("keep_out", "power")
    assert (cs.path_lower, cs.path_upper) == (system.path_lower, system.path_upper) == ((0.25, -2.0), (math.inf, 2.0))
    assert cs.free_horizon and cs.horizon_bounds == system.horizon_bounds == (1.0, 20.0) and cs.horizon == 4.0
    xs, us, ts, ps = _points(cs, 5)
    for x, u, t, p in zip(xs, us, ts, ps):
        params = {k: jnp.asarray(v) for k, v in zip(cs.param_names, p)}
        want = np.asarray(system.path_constraints(jnp.asarray(x), jnp.asarray(u), jnp.asarray(t), params))
        np.testing.assert_allclose(np.asarray(cs.g(x, u, t, p)).ravel(), want, rtol=RTOL)
    plain = to_casadi(check_file(ROOT / "specs" / "van_der_pol.yaml"))  # schema 1: no path constraints, T fixed
    assert plain.g([0, 1], [0], 0, plain.p0).shape == (0, 1) and not plain.free_horizon and plain.n_path == 0


def test_opti_minimum_time_converges_to_the_analytic_final_time():
    """Bang-bang double integrator, T* = 2: the trapezoidal optimum's T falls as 1/N^2 towards 2."""
    from myriad.compiler.casadi_opti import trapezoidal

    cs = export_file(SCHEMA2 / "min_time_double_integrator.yaml")
    Ts = []
    for N in (20, 40):
        problem = trapezoidal(cs, N)
        sol = problem.opti.solve()
        assert sol.stats()["success"]
        Ts.append(float(sol.value(problem.T)))
        assert float(sol.value(problem.J)) == pytest.approx(Ts[-1], rel=1e-9)  # running cost 1: J = T
    order = math.log2((Ts[0] - 2) / (Ts[1] - 2))
    assert 1.9 < order < 2.1, Ts
    assert abs((4 * Ts[1] - Ts[0]) / 3 - 2) < 1e-5, Ts  # Richardson extrapolation


def test_opti_state_path_constraint_meets_bryson_denham():
    """x <= l = 1/9 at every node; J* = 4 / (9 l) = 4, approached at second order."""
    from myriad.compiler.casadi_opti import trapezoidal

    cs = export_file(SCHEMA2 / "bryson_denham.yaml")
    Js = []
    for N in (40, 80):
        problem = trapezoidal(cs, N)
        sol = problem.opti.solve()
        assert sol.stats()["success"]
        Js.append(float(sol.value(problem.J)))
        wall = np.asarray(sol.value(problem.G)).ravel()
        assert wall.shape == (N + 1,) and wall.max() <= 1 / 9 + 1e-7
        assert wall.max() > 1 / 9 - 1e-7  # active: without the wall the optimum (J = 2) reaches x = 1/4
    assert 1.9 < math.log2((Js[0] - 4) / (Js[1] - 4)) < 2.1, Js
    assert abs((4 * Js[1] - Js[0]) / 3 - 4) < 1e-4, Js
