"""The error estimate of a direct solve (runtime/transcriptions/error.py), against mathematics.

On x' = -b x + u with u = 0 every method's step is a rational or polynomial function R(z) of z = -b h, so its local
error on an interval is exactly |e^z - R(z)| |x_k|: the estimate must equal it, and fall at the method's local order.
"""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.data import default_data
from myriad.runtime.integrators import RK4, Euler, Heun, Midpoint
from myriad.runtime.solve import solve
from myriad.runtime.transcriptions import HermiteSimpson, MultipleShooting, SingleShooting, Trapezoidal
from myriad.runtime.transcriptions.base import transcribe
from myriad.runtime.transcriptions.error import local_errors

from .._problems import Decay

B = Decay.param_values[0]  # the decay rate b
# The estimate's scale, 1 + max |x| over the solution: every trajectory here decays from x(0) = 1.
SCALE = 2.0


# One step of each method on x' = lam x, as a function of z = lam h.
_STEPS = {
    "euler": lambda z: 1 + z,
    "heun": lambda z: 1 + z + z**2 / 2,
    "midpoint": lambda z: 1 + z + z**2 / 2,
    "rk4": lambda z: 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24,
    "trapezoidal": lambda z: (1 + z / 2) / (1 - z / 2),
    "hermite_simpson": lambda z: (1 + z / 2 + z**2 / 12) / (1 - z / 2 + z**2 / 12),  # the (2, 2) Pade approximant
}
_ORDER = {"euler": 1, "heun": 2, "midpoint": 2, "rk4": 4, "trapezoidal": 2, "hermite_simpson": 4}
_NS = (10, 20, 40)


def _check_exact_and_order(name, estimates, exact):
    for n in _NS:
        # The reference (RK4, 16 substeps) is 16^4 times more accurate than one RK4 step: 1e-4 covers it.
        np.testing.assert_allclose(estimates[n].intervals, exact[n], rtol=1e-4, atol=1e-17)
        assert estimates[n].value == pytest.approx(exact[n].max(), rel=1e-4)
    slopes = [math.log2(estimates[a].value / estimates[b].value) for a, b in zip(_NS, _NS[1:])]
    # Local error O(h^{p+1}): halving h divides it by about 2^{p+1} (4 for Euler, 8 for Heun, 32 for RK4).
    np.testing.assert_allclose(slopes, _ORDER[name] + 1, atol=0.15)


@pytest.mark.parametrize("integrator", [Euler(), Heun(), Midpoint(), RK4()], ids=lambda i: i.label)
@pytest.mark.parametrize("multiple", [False, True], ids=["single", "multiple"])
def test_shooting_estimate_is_the_exact_local_error(integrator, multiple):
    system, estimates, exact = Decay(), {}, {}
    data = default_data(system)
    for n in _NS:
        # The rollout of zero controls is the method's own trajectory, x_k = R(z)^k, no solve needed; for multiple
        # shooting the node variables are put on it (continuity holds), which the check of states below confirms.
        R, h = _STEPS[integrator.label](-B / n), 1.0 / n
        if multiple:
            tr = MultipleShooting(intervals=n // 5, steps_per_interval=5, integrator=integrator)
            z = tr.sample(system, lambda t: (R ** np.rint(np.asarray(t) / h))[:, None], lambda t: np.zeros((len(t), 1)))
        else:
            tr, z = SingleShooting(intervals=n, integrator=integrator), np.zeros(n + 1)
        nlp = transcribe(system, tr)
        times, states, controls = (np.asarray(a) for a in nlp.unravel(jnp.asarray(z), data))
        np.testing.assert_allclose(states[:, 0], _STEPS[integrator.label](-B / n) ** np.arange(n + 1), rtol=1e-12)
        estimates[n] = local_errors(system, times, states, controls, data.params)
        exact[n] = abs(math.exp(-B / n) - _STEPS[integrator.label](-B / n)) * np.abs(states[:-1, 0]) / SCALE
    _check_exact_and_order(integrator.label, estimates, exact)


@pytest.mark.parametrize("method", [Trapezoidal, HermiteSimpson], ids=lambda m: m.label)
def test_collocation_estimate_is_the_exact_local_error(method):
    system, estimates, exact = Decay(), {}, {}
    data = default_data(system)
    for n in _NS:
        tr, R, h = method(intervals=n), _STEPS[method.label](-B / n), 1.0 / n
        z = tr.sample(system, lambda t: (R ** np.rint(np.asarray(t) / h))[:, None], lambda t: np.zeros((len(t), 1)))
        nlp = transcribe(system, tr)
        # x_k = R(z)^k is the collocation trajectory: its defects vanish.
        assert np.max(np.abs(np.asarray(nlp.constraints(jnp.asarray(z), data)))) < 1e-13
        times, states, controls = (np.asarray(a) for a in nlp.unravel(jnp.asarray(z), data))
        estimates[n] = local_errors(system, times, states, controls, data.params, midpoints=method is HermiteSimpson)
        exact[n] = abs(math.exp(-B / n) - R) * R ** np.arange(n) / SCALE
    _check_exact_and_order(method.label, estimates, exact)


def test_hermite_simpson_intervals_see_a_quadratic_control():
    # With b = 0, x' = u and u = t^2: Simpson's rule and the Hermite midpoint are exact, so the collocated
    # x = 1 + t^3 / 3 has no local error; reading the half-step grid as piecewise-linear controls would see some.
    system, n = Decay(), 10
    data = default_data(system, {"b": 0.0})
    tr = HermiteSimpson(intervals=n)
    z = tr.sample(system, lambda t: 1 + np.asarray(t)[:, None] ** 3 / 3, lambda t: np.asarray(t)[:, None] ** 2)
    nlp = transcribe(system, tr)
    assert np.max(np.abs(np.asarray(nlp.constraints(jnp.asarray(z), data)))) < 1e-14
    times, states, controls = (np.asarray(a) for a in nlp.unravel(jnp.asarray(z), data))
    assert local_errors(system, times, states, controls, data.params, midpoints=True).value < 1e-14
    assert local_errors(system, times, states, controls, data.params, midpoints=False).value > 1e-6
    with pytest.raises(ValueError, match="odd number of points"):
        local_errors(system, times[:-1], states[:-1], controls[:-1], data.params, midpoints=True)


@pytest.fixture(scope="module")
def simple_case():
    return load("simple_case")


@pytest.mark.parametrize("method", [
    lambda n: SingleShooting(intervals=n),
    Trapezoidal.on_grid,
    HermiteSimpson.on_grid,
], ids=["single_shooting_heun", "trapezoidal", "hermite_simpson"])
def test_a_solve_carries_its_estimate_and_it_falls_at_the_method_order(simple_case, method):
    # x' = -x^2 / 2 + 4u with a smooth optimal control; measured ratios for N = 10 -> 20: 8.2, 7.7, 29.2 (multiple
    # shooting with RK4: 31.4, left out for time; its grid is checked exactly above).
    expected = {"heun": 8, "trapezoidal": 8, "simpson": 32}
    sols = [solve(simple_case, method(n), resimulate=False) for n in (10, 20)]
    for sol, n in zip(sols, (10, 20)):
        assert sol.converged, sol.message
        assert sol.interval_errors.shape == (n,)
        assert sol.error_estimate == sol.interval_errors.max() > 0
        assert sol.record()["error_estimate"] == sol.error_estimate
    ratio = sols[0].error_estimate / sols[1].error_estimate
    assert 0.75 < ratio / expected[sols[0].integrator] < 1.35, ratio
    # Against the CLI's default tolerance 1e-6, N = 20 is fine enough for Hermite-Simpson only (2.9e-4, 7.9e-5,
    # 3.0e-8). (Its N = 10 estimate, 8.6e-7, sits too near 1e-6 to assert a side: it moved with the BLAS.)
    assert (sols[1].error_estimate < 1e-6) == (sols[1].integrator == "simpson")


def test_the_cli_warns_on_the_estimate_only_when_asked(capsys, tmp_path):
    # Hermite-Simpson on simple_case at N = 5: an estimate above 1e-6 (below 1e-3), and a re-simulation that agrees
    # within the default 1e-3: by default no warning (one warning must mean something); --error-tolerance asks for one.
    out = tmp_path / "coarse.json"
    argv = ["solve", "simple_case", "--transcription", "hermite_simpson", "--intervals", "5"]
    assert main(argv + ["--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err and "error estimate" in captured.out
    rec = json.loads(out.read_text())
    assert 1e-6 < rec["error_estimate"] < 1e-3
    assert rec["agreement"] is True and rec["agreement_gap"] <= rec["agreement_tolerance"] == 1e-3
    assert main(argv + ["--error-tolerance", "1e-6"]) == 0
    err = capsys.readouterr().err
    assert "myriad: warning: error estimate" in err and "exceeds the tolerance 1e-06" in err
    assert main(argv + ["--error-tolerance", "1e-3"]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("method", ["heun", "trapezoidal", "hermite_simpson"])
def test_the_estimate_follows_a_graded_grid(method):
    # On a random grid the method's trajectory is x_{k+1} = R(-b h_k) x_k and each interval's local error is
    # |exp(-b h_k) - R(-b h_k)| |x_k|, with its own h_k.
    system = Decay()
    data = default_data(system)
    widths = np.random.default_rng(3).uniform(0.5, 1.5, 12)
    grid = np.concatenate([[0.0], np.cumsum(widths) / widths.sum()])
    grid[-1] = 1.0
    h = np.diff(grid)
    R = _STEPS[method](-B * h)
    xs = np.concatenate([[1.0], np.cumprod(R)])
    if method == "heun":
        tr, z = SingleShooting.on_grid(grid, integrator=Heun()), np.zeros(13)
    else:
        tr = (Trapezoidal if method == "trapezoidal" else HermiteSimpson).on_grid(grid)
        z = tr.sample(system, lambda t: np.interp(t, grid, xs)[:, None], lambda t: np.zeros((len(t), 1)))
    nlp = transcribe(system, tr)
    times, states, controls = (np.asarray(a) for a in nlp.unravel(jnp.asarray(z), data))
    midpoints = method == "hermite_simpson"
    np.testing.assert_allclose(states[:: 2 if midpoints else 1, 0], xs, rtol=1e-12)
    estimate = local_errors(system, times, states, controls, data.params, midpoints=midpoints)
    np.testing.assert_allclose(estimate.interval_times, grid, rtol=0, atol=1e-15)
    np.testing.assert_allclose(estimate.intervals, np.abs(np.exp(-B * h) - R) * xs[:-1] / SCALE, rtol=1e-4, atol=1e-17)


def test_an_interval_whose_reference_diverges_has_an_infinite_error():
    # x' = -b x with b h = 5e7 on each interval: the reference's RK4 substeps (b h / 16 = 3e6, far outside RK4's
    # stability region, amplification ~ (b h / 16)^4 / 24 per substep) overflow. That is a step far too long, not a
    # missing estimate: +inf, so it warns and is refined first; a trajectory that is itself not finite gives NaN.
    system = Decay()
    params = default_data(system, {"b": 1e8}).params
    t, x, u = np.array([0.0, 0.5, 1.0]), np.array([[1.0], [0.5], [0.25]]), np.zeros((3, 1))
    est = local_errors(system, t, x, u, params)
    assert np.isinf(est.intervals).all() and est.value == math.inf
    x[1, 0] = np.nan
    assert math.isnan(local_errors(system, t, x, u, params).value)
