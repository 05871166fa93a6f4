"""Transcriptions and the sweep against problems with known solutions.

NLPs are solved here with SciPy's SLSQP and JAX derivatives directly (the solver plugins are tested elsewhere), one
compiled function per NLP returning objective, gradient, constraints and Jacobian together, to keep compile time down.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.integrators import Heun
from myriad.runtime.simulate import simulate
from myriad.runtime.system import OptimalControlUnavailable
from myriad.runtime.transcriptions import (
    INDIRECT,
    TRANSCRIPTIONS,
    ForwardBackwardSweep,
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
    default_data,
)
from myriad.runtime.transcriptions.nominal_scales import nominal_scale

from .._nlp import _slope, _solve
from .._problems import BoundedReach, DoubleIntegrator, NoUStar, ScalarLQ


# ---- constraints at the analytic solution -------------------------------------------------------------------------
# The local error per interval: Heun's final state (global, order 2); multiple shooting's defect over S RK4 steps is
# dominated by the linear interpolation of the curved control, O(S h^3); trapezoid O(h^3); Hermite-Simpson O(h^5).
@pytest.mark.parametrize(
    "make, problem, ns, order",
    [
        (lambda n: SingleShooting(intervals=n), DoubleIntegrator, (8, 16, 32), 2),
        (lambda n: MultipleShooting(intervals=n // 4, steps_per_interval=4), ScalarLQ, (16, 32, 64), 3),
        (lambda n: Trapezoidal(intervals=n), ScalarLQ, (8, 16, 32), 3),
        (lambda n: HermiteSimpson(intervals=n), ScalarLQ, (4, 8, 16), 5),
    ],
    ids=["single_shooting", "multiple_shooting", "trapezoidal", "hermite_simpson"],
)
def test_constraints_vanish_at_analytic_solution(make, problem, ns, order):
    system = problem()
    data = default_data(system)
    errors = []
    for n in ns:
        tr = make(n)
        nlp = tr.transcribe(system)
        z = jnp.asarray(tr.sample(system, system.x_exact, system.u_exact))
        c = np.asarray(jax.jit(nlp.constraints)(z, data))
        errors.append(np.max(np.abs(c - nlp.c_lower)))
    assert abs(_slope(ns, errors) - order) <= 0.3, errors


def test_exact_discretisations_have_zero_defects():
    # u = 6 - 12 t is linear and the states cubic: RK4 shooting and Simpson are exact on the double integrator.
    system = DoubleIntegrator()
    data = default_data(system)
    for tr in (MultipleShooting(intervals=4, steps_per_interval=3), HermiteSimpson(intervals=5)):
        nlp = tr.transcribe(system)
        z = jnp.asarray(tr.sample(system, system.x_exact, system.u_exact))
        c, J = jax.jit(lambda z, d: (nlp.constraints(z, d), nlp.objective(z, d)))(z, data)
        assert np.max(np.abs(np.asarray(c))) < 1e-13
        assert abs(float(J) - 12.0) < 1e-12


# ---- solved NLPs ---------------------------------------------------------------------------------------------------
# (transcription, relative tolerance on J*): order-2 methods on 32 intervals, order-4 ones on fewer. Each problem is
# solved with every transcription except where another test already does it (Trapezoidal and Hermite-Simpson solve
# ScalarLQ in the order test); a solve costs about a second of compilation on two shared cores.
_METHODS = {
    "single_shooting": (SingleShooting(intervals=32), 1e-2),
    "multiple_shooting": (MultipleShooting(intervals=4, steps_per_interval=4), 1e-6),
    "trapezoidal": (Trapezoidal(intervals=32), 1e-2),
    "hermite_simpson": (HermiteSimpson(intervals=8), 1e-6),
}
_CASES = [(m, p) for m in _METHODS for p in (DoubleIntegrator, BoundedReach)] + [("single_shooting", ScalarLQ)]


@pytest.mark.parametrize("method, problem", _CASES, ids=[f"{m}-{p.name}" for m, p in _CASES])
def test_solution_reaches_known_optimum(method, problem):
    tr, rtol = _METHODS[method]
    system = problem()
    data = default_data(system)
    nlp = tr.transcribe(system)
    z, at = _solve(nlp, data)
    J = float(at(z)[0])
    assert abs(J - system.J_STAR) <= rtol * abs(system.J_STAR), (J, system.J_STAR)
    times, states, controls = jax.jit(nlp.unravel)(jnp.asarray(z), data)
    np.testing.assert_allclose(np.asarray(states[0]), np.asarray(system.x0))
    assert times.shape[0] == states.shape[0] == controls.shape[0]
    fixed = system.final_mask
    np.testing.assert_allclose(np.asarray(states[-1])[fixed], system.final_values[fixed], atol=1e-8)
    if problem is BoundedReach:  # the state bound binds at T only: u = 1/2 throughout
        np.testing.assert_allclose(np.asarray(controls), 0.5, atol=1e-6)
    if nlp.jacobian_sparsity is not None and nlp.n_constraints:
        # The declared pattern must contain every structural non-zero: check at a random point.
        A = at(np.random.default_rng(0).normal(size=nlp.n_variables))[3]
        declared = np.zeros(A.shape, dtype=bool)
        declared[nlp.jacobian_sparsity] = True
        assert not np.any((A != 0) & ~declared)
        assert declared.sum() < A.size  # and it is actually sparse


@pytest.mark.parametrize(
    "make, ns, order",
    [(lambda n: Trapezoidal(intervals=n), (8, 16, 32), 2), (lambda n: HermiteSimpson(intervals=n), (4, 8, 16), 4)],
    ids=["trapezoidal", "hermite_simpson"],
)
def test_cost_converges_at_method_order(make, ns, order):
    system = ScalarLQ()
    data = default_data(system)
    errors = []
    for n in ns:
        nlp = make(n).transcribe(system)
        z, at = _solve(nlp, data)
        errors.append(abs(float(at(z)[0]) - system.J_STAR))
    assert abs(_slope(ns, errors) - order) <= 0.5, errors


# ---- the published setting's semantics ------------------------------------------------------------------------------
def test_single_shooting_cost_is_simulated_heun_cost():
    system = BoundedReach()
    data = default_data(system)
    tr = SingleShooting(intervals=10)
    nlp = tr.transcribe(system)
    u = np.linspace(-1.0, 2.0, 11)[:, None]
    z = jnp.asarray(u.ravel())
    sim = simulate(system, u, integrator=Heun())
    J, c = jax.jit(lambda z, d: (nlp.objective(z, d), nlp.constraints(z, d)))(z, data)
    np.testing.assert_allclose(float(J), float(sim.cost), rtol=1e-14)
    # One bound row, on the final state, scaled by the nominal magnitude 0.5.
    np.testing.assert_allclose(np.asarray(c), np.asarray(sim.states[-1]) / 0.5, rtol=1e-14)
    assert (nlp.c_lower[0], nlp.c_upper[0]) == (-np.inf, 1.0)
    assert SingleShooting(intervals=10, enforce_final_state_bounds=False).transcribe(system).constraints is None


def test_no_bound_row_for_a_state_with_a_required_final_value():
    class Pinned(DoubleIntegrator):  # p(T) = 1 is also the upper bound of p: the bound row would duplicate it
        name = "pinned"
        spec_sha256 = "pinned"
        x_lower = (0.0, -10.0)
        x_upper = (1.0, 10.0)

    nlp = SingleShooting(intervals=4).transcribe(Pinned())
    # rows: p(T) - 1, v(T) - 0 (required), and no bound rows: both states are pinned.
    assert nlp.n_constraints == 2
    np.testing.assert_array_equal(nlp.c_lower, [0.0, 0.0])
    # Collocation: the final node's bounds are dropped for pinned states, kept on every other node.
    nlp = Trapezoidal(intervals=3).transcribe(Pinned())
    np.testing.assert_array_equal(nlp.z_lower[:6], [0.0, -10.0, 0.0, -10.0, -np.inf, -np.inf])
    np.testing.assert_array_equal(nlp.z_upper[:6], [1.0, 10.0, 1.0, 10.0, np.inf, np.inf])


# ---- layout, scaling, guesses ---------------------------------------------------------------------------------------
def test_nominal_scale_rules():
    lo = np.array([0.0, -2.0, -np.inf, 0.0, -np.inf])
    hi = np.array([1600.0, 1.0, np.inf, np.inf, np.inf])
    x0 = np.array([800.0, 0.5, 0.0, 1000.0, -3.0])
    np.testing.assert_array_equal(nominal_scale(lo, hi, x0), [1600.0, 2.0, 1.0, 1000.0, 3.0])
    np.testing.assert_array_equal(nominal_scale(lo, hi), [1600.0, 2.0, 1.0, 1.0, 1.0])


@pytest.mark.parametrize("method", list(TRANSCRIPTIONS))
def test_nlp_layout(method):
    system = BoundedReach()
    data = default_data(system)
    nlp = TRANSCRIPTIONS[method]().transcribe(system)  # default sizes
    n = nlp.n_variables
    for a in (nlp.z_lower, nlp.z_upper, nlp.z_scale):
        assert a.shape == (n,) and a.dtype == np.float64
    assert np.all(nlp.z_scale > 0)
    # x has no lower bound and it stays -inf (single shooting has no state variables)
    assert np.isneginf(nlp.z_lower).any() == (method != "single_shooting")
    assert set(np.unique(nlp.z_scale)) <= {0.5, 2.0}  # x from its bound 0.5, u from its bounds [-2, 2]
    z0 = np.asarray(nlp.initial_guess(data))
    assert z0.shape == (n,) and np.all(z0 >= nlp.z_lower) and np.all(z0 <= nlp.z_upper)
    times, states, controls = jax.jit(nlp.unravel)(jnp.asarray(z0), data)
    np.testing.assert_array_equal(np.asarray(controls), 0.0)  # the middle of [-2, 2]
    assert float(times[0]) == 0.0 and math.isclose(float(times[-1]), system.horizon)
    assert nlp.n_constraints == nlp.c_lower.shape[0] == nlp.c_upper.shape[0]


def test_initial_guess_interpolates_to_required_final_values():
    system = DoubleIntegrator()
    data = default_data(system)
    nlp = Trapezoidal(intervals=4).transcribe(system)
    _, states, _ = nlp.unravel(nlp.initial_guess(data), data)
    np.testing.assert_allclose(np.asarray(states), [[0, 0], [0.25, 0], [0.5, 0], [0.75, 0], [1, 0]])


# ---- compile once, run with new data --------------------------------------------------------------------------------
@pytest.mark.parametrize("method", list(TRANSCRIPTIONS))
def test_new_params_do_not_recompile(method):
    system = ScalarLQ()
    nlp = TRANSCRIPTIONS[method](intervals=4).transcribe(system)
    traces = []

    def fun(z, data):
        traces.append(1)  # a Python side effect: runs only while tracing
        c = nlp.constraints(z, data) if nlp.constraints is not None else jnp.zeros(0)
        return nlp.objective(z, data), c

    fun = jax.jit(fun)
    d1, d2 = default_data(system), default_data(system, params={"q": 3.0}, x0=np.array([2.0]))
    z = jnp.asarray(nlp.initial_guess(d1)) + 0.1
    F1, _ = fun(z, d1)
    F2, _ = fun(z, d2)
    assert len(traces) == 1 and float(F1) != float(F2)
    if method == "trapezoidal":  # ... and a batch of data is one vmap (once: each costs a compilation)
        batch = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), d1, d2)
        Fb, _ = jax.vmap(fun, in_axes=(None, 0))(z, batch)
        np.testing.assert_allclose(np.asarray(Fb), [float(F1), float(F2)], rtol=1e-14)


# ---- the forward-backward sweep ------------------------------------------------------------------------------------
def test_sweep_free_final_state():
    system = ScalarLQ()
    r = ForwardBackwardSweep(intervals=200).solve(system)
    assert r.converged and r.shooting_iterations == 0, r.message
    assert abs(r.cost - system.J_STAR) < 1e-6
    t = np.asarray(r.times)
    # O(h^2) in the trajectories (the linear interpolation of u), lambda = -2 u.
    np.testing.assert_allclose(np.asarray(r.controls), system.u_exact(t), atol=1e-5)
    np.testing.assert_allclose(np.asarray(r.costates), -2.0 * system.u_exact(t), atol=2e-5)
    np.testing.assert_allclose(np.asarray(r.states), system.x_exact(t), atol=1e-5)
    assert np.isnan(np.asarray(r.defect)).all()


@pytest.mark.parametrize("newton", [True, False], ids=["newton", "broyden"])
def test_sweep_shoots_on_fixed_final_states(newton):
    system = DoubleIntegrator()
    r = ForwardBackwardSweep(intervals=200, newton=newton).solve(system)
    assert r.converged, r.message
    if newton:
        # Linear dynamics, quadratic cost, no bounds: Pontryagin's conditions are affine in (u, lambda(T)), so one
        # Newton step (with an exact Jacobian) solves them.
        assert (r.newton_iterations, r.shooting_iterations) == (1, 0)
    else:
        assert r.shooting_iterations >= 1 and r.newton_iterations == 0
    assert abs(r.cost - system.J_STAR) < 1e-6
    assert np.max(np.abs(np.asarray(r.defect))) < 1e-8
    np.testing.assert_allclose(np.asarray(r.controls), system.u_exact(np.asarray(r.times)), atol=1e-6)


@pytest.mark.parametrize("newton", [True, False], ids=["newton", "sweep_only"])
def test_sweep_step_control_on_a_stiff_problem(newton):
    # ScalarLQ (x' = b u, L = q x^2 + u^2, T = 1) has G' = -q b^2 K*K, K the integral from 0, whose eigenvalues are
    # -q b^2 (T / ((k + 1/2) pi))^2: with q = 110 the sweep is stable only for omega < 2 / (1 + 4 q / pi^2) = 0.044,
    # so Lenhart's 1/2 diverges. Halving at every sign flip of the correction stops once no mode oscillates
    # (omega < 1 / (1 + |mu|)), hence within a factor 4 below the limit.
    q = 110.0
    limit = 2.0 / (1.0 + q * (2.0 / math.pi) ** 2)
    r = ForwardBackwardSweep(intervals=100, newton=newton).solve(ScalarLQ(), params={"q": q})
    assert r.converged, r.message
    assert limit / 4 <= r.relaxation < limit, r.relaxation
    # J* = P(0) x0^2 with P = sqrt(q)/b tanh(b sqrt(q) (T - t)), the Riccati solution.
    j_star = math.sqrt(q) * math.tanh(math.sqrt(q))
    assert abs(r.cost - j_star) < 1e-5 * j_star
    if newton:
        assert r.newton_iterations == 1  # linear problem: exact after one step, long before the sweep's ~1e3 sweeps


def test_sweep_converges_on_van_der_pol():
    # Unstable near the origin (growth rate a/2 = 1/2) over T = 10: the sweep's linearisation has an eigenvalue
    # near -1.8e4 at the solution, so the step control must bring omega to ~1e-4 before the sweep can approach it,
    # and Newton finishes. J* = 2.87331 from IPOPT on multiple shooting (50 x 4 RK4 steps), which the sweep with
    # N = 1000 matches to 2e-7.
    system = load("van_der_pol")
    r = ForwardBackwardSweep(intervals=500).solve(system)
    assert r.converged and r.newton_iterations >= 1, r.message
    assert r.relaxation < 2.5e-4
    assert abs(r.cost - 2.87331) < 1e-4 * 2.87331
    assert np.max(np.abs(np.asarray(r.defect))) < 1e-9
    # The returned controls minimise H along the returned trajectory: u = clip(-lambda_x0 / 2, -0.75, 1).
    lam = np.asarray(r.costates)
    np.testing.assert_allclose(np.asarray(r.controls)[:, 0], np.clip(-lam[:, 0] / 2, -0.75, 1.0), atol=1e-9)


def test_sweep_refuses_without_optimal_control():
    with pytest.raises(OptimalControlUnavailable, match="no_u_star.*H is not strictly convex"):
        ForwardBackwardSweep().solve(NoUStar())


def test_sweep_reports_non_convergence():
    r = ForwardBackwardSweep(intervals=50, max_iter=2).solve(ScalarLQ())
    assert not r.converged and "did not converge in 2 sweeps" in r.message
    r = ForwardBackwardSweep(intervals=50, max_newton_iter=0).solve(ScalarLQ())
    assert not r.converged and "Newton's method on Pontryagin's conditions did not converge" in r.message


def test_sweep_reports_violated_state_bounds():
    # The sweep has no state-constraint multipliers: on BoundedReach it finds the unconstrained extremal u = 1,
    # x(T) = 1 > 0.5, and must not call that a solution.
    r = ForwardBackwardSweep(intervals=50).solve(BoundedReach())
    np.testing.assert_allclose(np.asarray(r.controls), 1.0, atol=1e-8)
    assert not r.converged and "violates the bounds of state 'x' by 1" in r.message
    assert abs(r.bound_violation - 1.0) < 1e-8  # (1 - 0.5) / scale 0.5


# ---- registries ----------------------------------------------------------------------------------------------------
def test_invalid_method_configs_are_refused():
    # Registry completeness and frozen, hashable configs: tests/runtime/test_registries.py.
    assert set(INDIRECT.values()) == {ForwardBackwardSweep}
    with pytest.raises(ValueError):
        Trapezoidal(intervals=0)
    with pytest.raises(ValueError):
        ForwardBackwardSweep(relaxation=0.0)
