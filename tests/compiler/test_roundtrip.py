"""Generated code against mathematics: sympy's own evaluation of the IR, autodiff of the generated functions."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy

from myriad.compiler import compile_file
from myriad.compiler.optimal_control import derive
from myriad.runtime import load

from ..helpers import ALL_SPECS, sample_interval

N_POINTS = 4


def _points(sym, seed):
    rng = np.random.default_rng(seed)
    xs = np.stack([sample_interval(lo, hi, x0, rng, N_POINTS)
                   for lo, hi, x0 in zip(sym.x_lower, sym.x_upper, sym.x0)], 1)
    us = np.stack([sample_interval(lo, hi, 0.0, rng, N_POINTS) for lo, hi in zip(sym.u_lower, sym.u_upper)], 1)
    ts = rng.uniform(0, sym.horizon, size=N_POINTS)
    lams = rng.normal(size=(N_POINTS, len(sym.states)))
    # Parameters near their nominal values, so the generated code is checked off the defaults too.
    ps = [{p: v * (1 + 0.1 * rng.uniform(-1, 1)) for p, v in zip(sym.params, sym.param_values)}
          for _ in range(N_POINTS)]
    return xs, us, ts, lams, ps


def _sympy_value(expr, subs):
    value = complex(expr.evalf(30, subs=subs))
    assert value.imag == 0
    return value.real


@pytest.fixture(scope="module", params=ALL_SPECS, ids=lambda p: p.stem)
def compiled(request):
    c = compile_file(request.param)
    return c, load(c.name)


def test_module_is_the_committed_one(compiled):
    c, system = compiled
    assert system.spec_sha256 == c.symbolic.spec.sha256


def test_dynamics_and_costs_match_sympy(compiled):
    c, system = compiled
    sym = c.symbolic
    d = derive(sym)
    xs, us, ts, _, ps = _points(sym, 0)
    for x, u, t, p in zip(xs, us, ts, ps):
        subs = {**dict(zip(sym.states, x)), **dict(zip(sym.controls, u)), sym.time: t, **p}
        params = {str(k): jnp.asarray(v) for k, v in p.items()}
        want_f = [_sympy_value(e, subs) for e in d.f]
        np.testing.assert_allclose(system.dynamics(x, u, t, params), want_f, rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(system.running_cost(x, u, t, params), _sympy_value(d.L, subs), rtol=1e-12)
        np.testing.assert_allclose(system.terminal_cost(x, t, params), _sympy_value(d.phi, subs), rtol=1e-12)


def test_sense_is_minimisation_form(compiled):
    c, system = compiled
    sym = c.symbolic
    sign = 1 if sym.spec.sense == "minimize" else -1
    xs, us, ts, _, ps = _points(sym, 1)
    x, u, t, p = xs[0], us[0], ts[0], ps[0]
    subs = {**dict(zip(sym.states, x)), **dict(zip(sym.controls, u)), sym.time: t, **p}
    params = {str(k): jnp.asarray(v) for k, v in p.items()}
    np.testing.assert_allclose(system.running_cost(x, u, t, params), sign * _sympy_value(sym.running, subs),
                               rtol=1e-12)


@pytest.mark.slow
def test_jacobians_match_autodiff(compiled):
    _, s = compiled
    xs, us, ts, lams, ps = _points(compiled[0].symbolic, 2)
    for x, u, t, lam, p in zip(xs, us, ts, lams, ps):
        params = {str(k): jnp.asarray(v) for k, v in p.items()}
        x, u, lam = jnp.asarray(x), jnp.asarray(u), jnp.asarray(lam)
        close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10)  # noqa: E731
        close(s.dynamics_jac_x(x, u, t, params), jax.jacfwd(s.dynamics, 0)(x, u, t, params))
        close(s.dynamics_jac_u(x, u, t, params), jax.jacfwd(s.dynamics, 1)(x, u, t, params))
        close(s.running_cost_grad_x(x, u, t, params), jax.grad(s.running_cost, 0)(x, u, t, params))
        close(s.running_cost_grad_u(x, u, t, params), jax.grad(s.running_cost, 1)(x, u, t, params))
        close(s.terminal_cost_grad_x(x, t, params), jax.grad(s.terminal_cost, 0)(x, t, params))
        close(s.terminal_costate(x, t, params), jax.grad(s.terminal_cost, 0)(x, t, params))

        def H(x, u):
            return s.running_cost(x, u, t, params) + lam @ s.dynamics(x, u, t, params)

        close(s.hamiltonian(x, u, lam, t, params), H(x, u))
        close(s.costate_dynamics(x, u, lam, t, params), -jax.grad(H, 0)(x, u))
        close(s.hamiltonian_grad_u(x, u, lam, t, params), jax.grad(H, 1)(x, u))


def test_optimal_control_minimises_the_hamiltonian(compiled):
    c, s = compiled
    if s.optimal_control_kind == "none":
        assert s.optimal_control_note, "a system without u* must say why"
        assert "optimal_control" not in type(s).__dict__
        return
    xs, us, ts, lams, ps = _points(c.symbolic, 3)
    lo, hi = np.asarray(s.u_lower), np.asarray(s.u_upper)
    for x, t, lam, p in zip(xs, ts, lams, ps):
        params = {str(k): jnp.asarray(v) for k, v in p.items()}
        u_star = np.asarray(s.optimal_control(x, lam, t, params))
        assert np.all(u_star >= lo - 1e-12) and np.all(u_star <= hi + 1e-12)
        h_star = float(s.hamiltonian(x, u_star, lam, t, params))
        # Controls are decoupled in H when u* exists: a grid over each control's box, others held at u*.
        for j in range(s.n_controls):
            a = lo[j] if np.isfinite(lo[j]) else u_star[j] - 10
            b = hi[j] if np.isfinite(hi[j]) else u_star[j] + 10
            for v in np.linspace(a, b, 41):
                u = u_star.copy()
                u[j] = v
                assert h_star <= float(s.hamiltonian(x, u, lam, t, params)) + 1e-9 * (1 + abs(h_star))


def test_derived_kinds_of_known_systems():
    kinds = {name: load(name).optimal_control_kind for name in ("bioreactor", "timber_harvest", "cancer_treatment",
                                                                "rocket_landing", "bear_populations")}
    assert kinds == {"bioreactor": "bang_bang", "timber_harvest": "bang_bang", "cancer_treatment": "stationary",
                     "rocket_landing": "none", "bear_populations": "stationary"}


def test_costate_equation_symbolic_cancer():
    """dλ/dt = −∂H/∂x written out by hand for Cancer Treatment (L = a x² + u², f = r x ln(1/x) − u δ x)."""
    c = compile_file(next(p for p in ALL_SPECS if p.stem == "cancer_treatment"))
    d = derive(c.symbolic)
    x, = c.symbolic.states
    u, = c.symbolic.controls
    r, a, delta = (next(s for s in c.symbolic.params if str(s) == n) for n in ("r", "a", "delta"))
    lam = d.lam[0]
    want = -(2 * a * x + lam * (r * sympy.log(1 / x) - r - u * delta))
    assert sympy.simplify(d.costate[0] - want) == 0
