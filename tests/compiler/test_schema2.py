"""Schema 2 (path constraints, a free final time): what the compiler generates for them, checked against mathematics.

The example specs in ``schema2/`` are compiled and loaded; the generated path constraints and their Jacobians are
compared with sympy's evaluation of the IR, with central finite differences and with autodiff, in float64. Schema 1
specs must compile to the very same bytes (the committed modules), and a schema 1 problem restated as schema 2 must
be the same problem. Bad schema 2 specs are in ``bad_specs/`` (``s2_*``), checked by ``test_bad_specs.py``.
"""

from __future__ import annotations

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy

from myriad.compiler import compile_file, compile_spec
from myriad.compiler.build import DEFAULT_OUT, build
from myriad.runtime import load
from myriad.runtime.system import System, UnsupportedFeature

from ..helpers import ALL_SPECS, ROOT, sample_interval

HERE = Path(__file__).resolve().parent / "schema2"
EXAMPLES = sorted(HERE.glob("*.yaml"))


@pytest.fixture(scope="module")
def systems(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MYRIAD_CACHE", str(cache))
        return {p.stem: (compile_file(p), load(p)) for p in EXAMPLES}


def test_examples_exist():
    assert {p.stem for p in EXAMPLES} >= {"min_time_double_integrator", "bryson_denham", "keep_out_zone"}


def test_metadata(systems):
    _, s = systems["keep_out_zone"]
    assert s.schema == 2 and s.free_horizon and s.horizon_bounds == (1.0, 20.0)
    assert s.horizon == s.horizon_guess == 4.0  # `horizon` reads as the guess, so existing code keeps working
    assert s.path_constraint_names == ("keep_out", "power") and s.n_path == 2
    assert s.path_constraint_descriptions == ("stay outside the disc", "thrust power")
    assert s.path_constraint_kinds == ("state", "mixed")
    assert s.path_lower == (0.25, -2.0) and s.path_upper == (math.inf, 2.0)
    assert s.structural_params == ("r", "pmax")  # the bounds were evaluated with r and pmax

    _, bd = systems["bryson_denham"]
    assert not bd.free_horizon and bd.horizon_bounds is None and bd.horizon_guess is None and bd.horizon == 1.0
    assert bd.path_upper == (1 / 9,) and bd.path_lower == (-math.inf,) and bd.path_constraint_kinds == ("state",)

    _, mt = systems["min_time_double_integrator"]
    assert mt.free_horizon and mt.horizon_bounds == (0.1, 10.0) and mt.horizon == 1.5 and mt.n_path == 0


def test_system_without_path_constraints_returns_empty_arrays(systems):
    _, mt = systems["min_time_double_integrator"]
    x, u, p = jnp.zeros(2), jnp.zeros(1), mt.default_params()
    assert mt.path_constraints(x, u, 0.0, p).shape == (0,)
    assert mt.path_constraints_jac_x(x, u, 0.0, p).shape == (0, 2)
    assert mt.path_constraints_jac_u(x, u, 0.0, p).shape == (0, 1)
    vdp = load("van_der_pol")  # a schema 1 system inherits the same defaults
    assert vdp.n_path == 0 and not vdp.free_horizon and vdp.horizon_bounds is None and vdp.path_lower == ()
    assert vdp.path_constraints(jnp.zeros(2), jnp.zeros(1), 0.0, vdp.default_params()).shape == (0,)


def _points(sym, rng, n=5):
    xs = np.stack([sample_interval(lo, hi, x0, rng, n) for lo, hi, x0 in zip(sym.x_lower, sym.x_upper, sym.x0)], 1)
    us = np.stack([sample_interval(lo, hi, 0.0, rng, n) for lo, hi in zip(sym.u_lower, sym.u_upper)], 1)
    ts = rng.uniform(0, sym.horizon, size=n)
    ps = [{p: v * (1 + 0.1 * rng.uniform(-1, 1)) for p, v in zip(sym.params, sym.param_values)} for _ in range(n)]
    return xs, us, ts, ps


@pytest.mark.parametrize("name", ["keep_out_zone", "bryson_denham"])
def test_path_constraints_and_jacobians(systems, name):
    """g against sympy; dg/dx, dg/du against sympy's derivatives, central differences and autodiff (float64)."""
    c, s = systems[name]
    sym = c.symbolic
    rng = np.random.default_rng(0)
    for x, u, t, p in zip(*_points(sym, rng)):
        subs = {**dict(zip(sym.states, x)), **dict(zip(sym.controls, u)), sym.time: t, **p}
        params = {str(k): jnp.asarray(v) for k, v in p.items()}
        jx, ju = jnp.asarray(x), jnp.asarray(u)
        g = np.asarray(s.path_constraints(jx, ju, t, params))
        np.testing.assert_allclose(g, [float(e.evalf(30, subs=subs)) for e in sym.path], rtol=1e-12, atol=1e-14)
        jac_x = np.asarray(s.path_constraints_jac_x(jx, ju, t, params))
        jac_u = np.asarray(s.path_constraints_jac_u(jx, ju, t, params))
        want_x = [[float(sympy.diff(e, v).evalf(30, subs=subs)) for v in sym.states] for e in sym.path]
        want_u = [[float(sympy.diff(e, v).evalf(30, subs=subs)) for v in sym.controls] for e in sym.path]
        np.testing.assert_allclose(jac_x, want_x, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(jac_u, want_u, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(jac_x, jax.jacfwd(s.path_constraints, 0)(jx, ju, t, params), rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(jac_u, jax.jacfwd(s.path_constraints, 1)(jx, ju, t, params), rtol=1e-12, atol=1e-14)
        h = 1e-6
        for j in range(len(x)):
            e = np.eye(len(x))[j] * h
            fd = (np.asarray(s.path_constraints(jx + e, ju, t, params))
                  - np.asarray(s.path_constraints(jx - e, ju, t, params))) / (2 * h)
            np.testing.assert_allclose(jac_x[:, j], fd, rtol=1e-7, atol=1e-8)
        for j in range(len(u)):
            e = np.eye(len(u))[j] * h
            fd = (np.asarray(s.path_constraints(jx, ju + e, t, params))
                  - np.asarray(s.path_constraints(jx, ju - e, t, params))) / (2 * h)
            np.testing.assert_allclose(jac_u[:, j], fd, rtol=1e-7, atol=1e-8)


def test_terminal_cost_takes_the_final_time(systems):
    """`t` in a terminal cost is the final time T: phi = 0.5 t is 0.5 T whatever T the transcription chooses."""
    _, s = systems["keep_out_zone"]
    for T in (1.0, 3.7, 20.0):
        assert float(s.terminal_cost(jnp.zeros(4), T, s.default_params())) == pytest.approx(0.5 * T, rel=1e-15)


def test_optimal_control_with_path_constraints(systems):
    _, s = systems["keep_out_zone"]
    assert s.optimal_control_kind == "none" and "power" in s.optimal_control_note
    _, bd = systems["bryson_denham"]  # a pure state constraint: u* = -lam_v kept, valid off the wall
    assert bd.optimal_control_kind == "stationary" and "wall" in bd.optimal_control_note
    lam = jnp.array([0.3, -0.7])
    assert float(bd.optimal_control(jnp.zeros(2), lam, 0.0, bd.default_params())[0]) == pytest.approx(0.7)
    _, mt = systems["min_time_double_integrator"]
    assert mt.optimal_control_kind == "bang_bang"
    summary = dict(systems["min_time_double_integrator"][0].data.summary)
    assert summary["H(T)"].startswith("0 (free final time")  # H(T) = -dphi/dT = 0 for a pure minimum-time cost
    assert dict(systems["keep_out_zone"][0].data.summary)["H(T)"].startswith("-1/2")


def test_require_schema1_features(systems):
    with pytest.raises(UnsupportedFeature, match=r"path constraints \(keep_out, power\) and a free final time "
                                                 r"\(T in \[1, 20\]\), which trapezoidal does not enforce yet"):
        systems["keep_out_zone"][1].require_schema1_features("trapezoidal")
    with pytest.raises(UnsupportedFeature, match=r"has path constraints \(wall\), which the sweep"):
        systems["bryson_denham"][1].require_schema1_features("the sweep")
    with pytest.raises(NotImplementedError, match="a free final time"):
        systems["min_time_double_integrator"][1].require_schema1_features("x")
    load("van_der_pol").require_schema1_features("x")  # schema 1: nothing to refuse


def test_schema1_modules_unchanged():
    """Every shipped schema 1 spec compiles to the committed bytes (no schema 2 attribute is written into them)."""
    result = build(ALL_SPECS, DEFAULT_OUT, check=True)
    assert result.ok, result.diffs[:1]
    text = (DEFAULT_OUT / "harvest.py").read_text(encoding="utf-8")  # van_der_pol is schema 3 now
    assert "path_" not in text and "free_horizon" not in text


def test_schema1_problem_restated_as_schema2_is_the_same_problem(tmp_path):
    """`schema: 2` without the new fields: the same functions; the new attributes say "none", like the defaults."""
    src = (ROOT / "specs" / "harvest.yaml").read_text(encoding="utf-8")
    one, two = compile_spec(src, "harvest.yaml"), compile_spec(src.replace("schema: 1", "schema: 2"), "harvest.yaml")
    assert one.data.functions == two.data.functions
    extra = dict(two.data.metadata).keys() - dict(one.data.metadata).keys()
    assert extra == {"free_horizon", "horizon_bounds", "horizon_guess", "path_constraint_names",
                     "path_constraint_descriptions", "path_constraint_kinds", "path_lower", "path_upper"}
    namespace: dict = {}
    for attr in extra:
        literal = dict(two.data.metadata)[attr]
        assert eval(literal, {"math": math}, namespace) == getattr(System, attr), attr  # our own printed literal


def test_card_and_show_cover_the_new_fields(systems, capsys):
    from myriad.compiler.card import card_file, fingerprint
    from myriad.compiler.cli import main

    card = card_file(HERE / "keep_out_zone.yaml", results_path=None)
    assert "Final time T free: a decision variable in [1, 20], guess 4" in card
    assert "| `keep_out` | state | [0.25 (`r**2`), inf] | stay outside the disc |" in card
    assert r"\text{(keep\_out)}" in card and r"\phi = \frac{T}{2}" in card
    # The fingerprint (which keys recorded results) changes with a path bound and with a horizon bound.
    c = systems["keep_out_zone"][0]
    text = (HERE / "keep_out_zone.yaml").read_text(encoding="utf-8")
    for old, new in (("bounds: [-pmax, pmax]", "bounds: [-pmax, 1]"), ("bounds: [1, 20]", "bounds: [1, 30]")):
        assert fingerprint(compile_spec(text.replace(old, new), "keep_out_zone.yaml").symbolic) != \
            fingerprint(c.symbolic), old
    assert main(["show", str(HERE / "keep_out_zone.yaml")]) == 0
    out = capsys.readouterr().out
    assert "T free in [1, 20], guess 4" in out and "path keep_out = 0.25 <= (x - 1)**2 + (y - 1)**2 <= inf" in out


def test_unprintable_path_constraint_is_reported_at_its_expression():
    """log(0) in one branch passes the checks but cannot be printed: a SpecError at that constraint, not a crash."""
    from myriad.compiler import SpecError

    text = (HERE / "bryson_denham.yaml").read_text(encoding="utf-8")
    line = 'wall: {expression: x, bounds: [-.inf, l], description: the wall (a second-order pure state constraint)}'
    assert line in text
    bad = text.replace(line, line + '\n  cap: {expression: "-log(where(pi >= l, 0, u)) + x", bounds: [-.inf, 1]}')
    with pytest.raises(SpecError) as info:
        compile_spec(bad, "bryson_denham.yaml")
    assert info.value.loc.path == ("path_constraints", "cap", "expression")
    assert info.value.loc.line == bad.splitlines().index('  cap: {expression: "-log(where(pi >= l, 0, u)) + x", '
                                                         'bounds: [-.inf, 1]}') + 1
    assert "cannot generate code" in info.value.message
