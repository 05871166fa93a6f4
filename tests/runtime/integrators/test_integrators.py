"""Integrators against mathematics: convergence orders, control interpolation, cost-augmented rollouts, simulate."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime.integrators import (
    RK4,
    AbstractIntegrator,
    Adaptive,
    DormandPrince,
    Euler,
    Heun,
    Midpoint,
    rollout,
    rollout_with_cost,
)
from myriad.runtime.simulate import simulate

from .._problems import DoubleIntegrator, ScalarLQ


# A nonlinear, explicitly time-dependent ODE with a known solution, driven by the control u(t) = t:
#   x1' = u x1,            x1(0) = 1    ->  x1 = exp(t^2 / 2)
#   x2' = u x1^2 + cos t,  x2(0) = 1/2  ->  x2 = (exp(t^2) - 1) / 2 + sin t + 1/2
# The control is linear in t, so its node interpolation is exact and every error measured is the integrator's; an
# integrator that ignored u1 (held u0 over the step) would drop to order 1.
def _field(x, u, t):
    return jnp.stack([u[0] * x[0], u[0] * x[0] ** 2 + jnp.cos(t)])


def _exact(t):
    return np.array([math.exp(t**2 / 2), (math.exp(t**2) - 1) / 2 + math.sin(t) + 0.5])


_X0 = np.array([1.0, 0.5])


def _final_error(integrator, n_steps):
    ts = np.linspace(0.0, 1.0, n_steps + 1)
    xs = rollout(integrator, _field, jnp.asarray(_X0), 0.0, 1.0 / n_steps, jnp.asarray(ts[:, None]))
    return float(np.max(np.abs(np.asarray(xs[-1]) - _exact(1.0))))


def _slope(ns, errors):
    """Least-squares slope of log(error) against log(h), h = 1/N: the observed order."""
    return float(np.polyfit(np.log(1.0 / np.asarray(ns, dtype=float)), np.log(errors), 1)[0])


@pytest.mark.parametrize(
    "integrator, ns",
    [(Euler(), (32, 64, 128, 256)), (Heun(), (8, 16, 32, 64)), (Midpoint(), (8, 16, 32, 64)), (RK4(), (8, 16, 32, 64))],
    ids=lambda v: type(v).__name__ if isinstance(v, AbstractIntegrator) else "",
)
def test_convergence_order(integrator, ns):
    order = _slope(ns, [_final_error(integrator, n) for n in ns])
    assert abs(order - integrator.order) <= 0.25, f"{type(integrator).__name__}: observed order {order:.3f}"


def test_adaptive_matches_exact_solution():
    # Coarse node grid: the adaptive solver subdivides each interval on its own.
    assert _final_error(Adaptive(), 4) < 1e-8


def test_adaptive_reports_failure_as_nan():
    xs = rollout(Adaptive(max_steps=1), _field, jnp.asarray(_X0), 0.0, 1.0, jnp.array([[0.0], [1.0]]))
    assert np.all(np.isnan(np.asarray(xs[-1])))


def test_dormand_prince_matches_exact_solution_and_its_tolerance():
    # Coarse node grid: each interval is subdivided; the global error follows the tolerance down.
    errors = [_final_error(DormandPrince(rtol=r, atol=r * 1e-2), 4) for r in (1e-5, 1e-8, 1e-11)]
    assert errors[1] < 1e-8 and errors[2] < 1e-11
    assert errors[0] > 10 * errors[1] > 100 * errors[2]


def test_dormand_prince_agrees_with_diffrax_on_van_der_pol():
    # Two independent adaptive methods (diffrax's Tsit5, this Dormand-Prince pair) at the same tolerance.
    f = lambda x, u, t: jnp.stack([x[1], (1.0 - x[0] ** 2) * x[1] - x[0] + u[0]])  # noqa: E731
    us = jnp.asarray(np.sin(np.linspace(0.0, 10.0, 21))[:, None])
    x0 = jnp.array([1.0, 0.0])
    a = np.asarray(rollout(Adaptive(), f, x0, 0.0, 0.5, us))
    b = np.asarray(rollout(DormandPrince(), f, x0, 0.0, 0.5, us))
    np.testing.assert_allclose(b, a, rtol=1e-7, atol=1e-8)


def test_dormand_prince_backwards_and_batched():
    ts = np.linspace(0.0, 1.0, 5)
    us = jnp.asarray(ts[:, None])
    xs = rollout(DormandPrince(), _field, jnp.asarray(_X0), 0.0, 0.25, us)
    back = rollout(DormandPrince(), _field, xs[-1], 1.0, -0.25, us[::-1])
    np.testing.assert_allclose(np.asarray(back[-1]), _X0, rtol=1e-7)  # two runs at rtol 1e-8
    # vmap: members finish after different numbers of steps; each gets its own answer.
    x0s = jnp.asarray(_X0) * jnp.array([[1.0], [0.5], [1.5]])
    batch = jax.vmap(lambda x0: rollout(DormandPrince(), _field, x0, 0.0, 0.25, us)[-1])(x0s)
    for x0, xb in zip(x0s, batch):
        np.testing.assert_allclose(np.asarray(xb), np.asarray(rollout(DormandPrince(), _field, x0, 0.0, 0.25, us)[-1]),
                                   rtol=1e-14)


def test_dormand_prince_forward_mode_matches_finite_differences():
    # Forward mode through the while loop (reverse mode is Adaptive's job); rtol 1e-10 so that the step-size
    # decisions, which are not differentiated, change the value by far less than the difference quotient resolves.
    integ = DormandPrince(rtol=1e-12, atol=1e-14)
    us = jnp.asarray(np.linspace(0.0, 1.0, 3)[:, None])
    final = lambda x0: rollout(integ, _field, x0, 0.0, 0.5, us)[-1]  # noqa: E731
    x0, v = jnp.asarray(_X0), jnp.array([0.3, -0.7])
    _, tangent = jax.jvp(final, (x0,), (v,))
    eps = 1e-6
    fd = (np.asarray(final(x0 + eps * v)) - np.asarray(final(x0 - eps * v))) / (2 * eps)
    np.testing.assert_allclose(np.asarray(tangent), fd, rtol=1e-6)


def test_dormand_prince_reports_failure_as_nan():
    xs = rollout(DormandPrince(max_steps=1), _field, jnp.asarray(_X0), 0.0, 1.0, jnp.array([[0.0], [1.0]]))
    assert np.all(np.isnan(np.asarray(xs[-1])))
    # A field that turns non-finite: every retry shrinks the step, none is accepted, the result is NaN.
    blows_up = lambda x, u, t: jnp.where(t > 0.5, jnp.nan, 1.0) * x  # noqa: E731
    x1 = DormandPrince(max_steps=50).step(blows_up, jnp.array([1.0]), 0.0, 1.0, jnp.zeros(1), jnp.zeros(1))
    assert np.isnan(np.asarray(x1)).all()
    with pytest.raises(ValueError, match="rtol and atol"):
        DormandPrince(rtol=0.0)
    with pytest.raises(ValueError, match="max_steps"):
        DormandPrince(max_steps=0)


@pytest.mark.parametrize("integrator", [Heun(), Midpoint(), RK4()], ids=lambda i: type(i).__name__)
def test_linear_control_is_integrated_exactly(integrator):
    # x' = u with u linear over the step: every method of order >= 2 gives x0 + h (u0 + u1) / 2.
    x1 = integrator.step(lambda x, u, t: u, jnp.array([1.0]), 0.3, 0.5, jnp.array([2.0]), jnp.array([-4.0]))
    np.testing.assert_allclose(np.asarray(x1), [1.0 + 0.5 * (2.0 - 4.0) / 2], rtol=0, atol=1e-15)
    x1 = Euler().step(lambda x, u, t: u, jnp.array([1.0]), 0.3, 0.5, jnp.array([2.0]), jnp.array([-4.0]))
    np.testing.assert_allclose(np.asarray(x1), [2.0])


def test_heun_cost_is_the_published_quadrature():
    # The augmented Heun step evaluates L at the Euler predictor, not at the corrected state:
    #   C_{k+1} = C_k + h/2 (L(x_k, u_k, t_k) + L(x_k + h f_k, u_{k+1}, t_{k+1})).
    f = lambda x, u, t: -x + u  # noqa: E731
    L = lambda x, u, t: x[0] ** 2 + t * u[0] ** 2  # noqa: E731
    us = np.array([[0.5], [-1.0], [2.0], [0.25]])
    h = 0.2
    xs, cost = rollout_with_cost(Heun(), f, L, jnp.array([1.5]), 0.0, h, jnp.asarray(us))
    x, c = np.array([1.5]), 0.0
    for k in range(3):
        fk = -x + us[k]
        xp = x + h * fk
        c += h / 2 * (x[0] ** 2 + k * h * us[k, 0] ** 2 + xp[0] ** 2 + (k + 1) * h * us[k + 1, 0] ** 2)
        x = x + h / 2 * (fk + (-xp + us[k + 1]))
        np.testing.assert_allclose(np.asarray(xs[k + 1]), x, rtol=1e-14)
        np.testing.assert_allclose(float(cost[k + 1]), c, rtol=1e-14)


def test_backward_rollout_inverts_forward():
    ts = np.linspace(0.0, 1.0, 33)
    us = jnp.asarray(ts[:, None])
    xs = rollout(RK4(), _field, jnp.asarray(_X0), 0.0, 1.0 / 32, us)
    back = rollout(RK4(), _field, xs[-1], 1.0, -1.0 / 32, us[::-1])
    np.testing.assert_allclose(np.asarray(back[-1]), _X0, atol=1e-7)


def test_simulate_known_solutions():
    di = DoubleIntegrator()
    ts = np.linspace(0.0, 1.0, 21)
    # u = 6 - 12 t is linear: RK4 integrates the cubic states and the quadratic cost exactly.
    sim = simulate(di, di.u_exact(ts), integrator=RK4())
    np.testing.assert_allclose(float(sim.cost), 12.0, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(sim.states), di.x_exact(ts), atol=1e-13)
    assert float(sim.max_defect) < 1e-13
    np.testing.assert_allclose(np.asarray(sim.times), ts)
    # Adaptive re-simulation of the same controls gives the same answer.
    sim = simulate(di, di.u_exact(ts), integrator=Adaptive())
    np.testing.assert_allclose(float(sim.cost), 12.0, rtol=1e-8)


def test_simulate_free_final_state_params_and_x0():
    lq = ScalarLQ()
    ts = np.linspace(0.0, 1.0, 11)
    # Heun on 10 steps, 1-D controls accepted for a single control. Free final states have a NaN defect.
    sim = simulate(lq, lq.u_exact(ts)[:, 0])
    assert np.isnan(np.asarray(sim.defect)).all() and float(sim.max_defect) == 0.0
    np.testing.assert_allclose(float(sim.cost), float(sim.running_cost + sim.terminal_cost))
    assert abs(float(sim.cost) - lq.J_STAR) < 1e-2
    # u = 0: x stays at x0 and the cost is q x0^2 T (same shapes: no recompilation).
    sim = simulate(lq, np.zeros(11), params={"q": 3.0}, x0=np.array([2.0]))
    np.testing.assert_allclose(float(sim.cost), 12.0, rtol=1e-14)
    with pytest.raises(ValueError, match="controls must have shape"):
        simulate(lq, np.zeros((11, 2)))


def test_integrator_configs_are_static():
    # Registry completeness, frozen dataclasses and orders: tests/runtime/test_registries.py.
    assert Adaptive(rtol=1e-6) != Adaptive()
    with pytest.raises(ValueError, match="unknown method"):
        Adaptive(method="euler")
    # Frozen configuration works as a static jit argument.
    step = jax.jit(lambda integ, x: integ.step(lambda x, u, t: -x, x, 0.0, 0.1, x, x), static_argnums=0)
    np.testing.assert_allclose(np.asarray(step(RK4(), jnp.array([1.0]))), [math.exp(-0.1)], rtol=1e-6)
