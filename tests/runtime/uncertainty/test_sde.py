"""The stochastic schemes: their noiseless limits are the ODE integrators to the bit, and on the Ornstein-Uhlenbeck
SDE (linear, so each scheme's exact mean and variance are known in closed form) Monte Carlo matches them, and
those converge to the SDE's at the stated weak orders."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.integrators import RK4, Euler, Heun
from myriad.runtime.uncertainty.sde import SCHEMES, EulerMaruyama, StochasticHeun, for_integrator, integrate

from ._systems import assert_mean_and_variance, ou_moments

THETA, SIGMA, X0, T = 2.0, 1.0, 1.0, 1.0


def test_without_noise_each_scheme_is_its_ode_integrator_to_the_bit():
    system = load("van_der_pol")
    p = system.default_params()

    def f(x, u, t):
        return system.dynamics(x, u, t, p)

    x, u, dw = jnp.array([0.3, -0.7]), jnp.array([0.2]), jnp.array([0.4, -1.1])
    for scheme, ode in ((StochasticHeun(), Heun()), (EulerMaruyama(), Euler())):
        np.testing.assert_array_equal(scheme.step(f, x, 0.5, 0.1, u, jnp.zeros(2), dw), ode.step(f, x, 0.5, 0.1, u, u))
        assert for_integrator(ode) == scheme
    with pytest.raises(ValueError, match="integrator='heun'"):
        for_integrator(RK4())
    assert {s.weak_order for s in SCHEMES.values()} == {1, 2}


@pytest.mark.parametrize("label", ["euler_maruyama", "heun"])
def test_monte_carlo_matches_each_schemes_closed_form_on_a_coarse_grid(label):
    n, m = 4, 100_000  # h = 0.25: theta h = 0.5, far from the limit, so a wrong scheme shows

    def final(key):
        return integrate(SCHEMES[label](), lambda x, u, t: -THETA * x + u, jnp.array([X0]), 0.0, T / n, n,
                         jnp.zeros(1), jnp.array([SIGMA]), key)[-1, 0]

    x = jax.jit(jax.vmap(final))(jax.random.split(jax.random.PRNGKey(2), m))
    assert_mean_and_variance(x, *ou_moments(THETA, SIGMA, X0, T, n, label))


@pytest.mark.parametrize("label", ["euler_maruyama", "heun"])
def test_the_closed_forms_converge_at_the_stated_weak_order(label):
    # The schemes' exact moments (matched by Monte Carlo above) against the SDE's: errors of the mean and the
    # variance halve p times per halving of h on fine grids.
    exact = np.array(ou_moments(THETA, SIGMA, X0, T))
    errors = np.array([np.abs(np.array(ou_moments(THETA, SIGMA, X0, T, n, label)) - exact) for n in (256, 512)])
    orders = np.log2(errors[0] / errors[1])
    np.testing.assert_allclose(orders, SCHEMES[label].weak_order, atol=0.02)


def test_integrate_uses_given_increments():
    dw = np.array([[0.1], [-0.2], [0.05]])
    xs = integrate(EulerMaruyama(), lambda x, u, t: -THETA * x, jnp.array([1.0]), 0.0, 0.1, 3, jnp.zeros(1),
                   jnp.array([0.5]), dw=dw)
    expected = [1.0]
    for w in dw[:, 0]:
        expected.append(expected[-1] * (1 - 0.2) + 0.5 * w)
    np.testing.assert_allclose(np.asarray(xs)[:, 0], expected, rtol=1e-15)
    assert math.isclose(float(xs[-1, 0]), expected[-1], rel_tol=1e-15)
