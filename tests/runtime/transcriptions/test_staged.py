"""Single shooting's stage-by-stage Lagrangian derivatives (runtime/transcriptions/staged.py) against JAX's own.

The staged Hessian is a rearrangement (second-order adjoint, a telescoped sum) of the same chain rule that
``jax.hessian`` applies to the rollout, so the two must agree to rounding at any point, feasible or not, for any
multipliers, on any grid and integrator.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.data import default_data
from myriad.runtime.integrators import RK4, Heun
from myriad.runtime.solve import solve
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.transcriptions import SingleShooting
from myriad.runtime.transcriptions.base import transcribe
from myriad.runtime.transcriptions.staged import staged_derivatives

pytestmark = pytest.mark.slow  # not in `make test-fast`: Hessians and interior-point solves, both ways

SCHEMA2 = "tests/compiler/schema2"


def _point(nlp, seed):
    """A random point inside the box (standard normal where a bound is infinite) and random multipliers."""
    rng = np.random.default_rng(seed)
    lo, hi = nlp.z_lower, nlp.z_upper
    box = np.isfinite(lo) & np.isfinite(hi)
    z = np.where(box, np.where(box, lo, 0) + rng.uniform(0.2, 0.8, lo.shape) * np.where(box, hi - lo, 0),
                 rng.normal(size=lo.shape))
    return jnp.asarray(z), jnp.asarray(rng.normal(size=nlp.n_constraints))


def _reference(nlp, data):
    """JAX's own F, c, gradient, Jacobian and Lagrangian Hessian at (z, lam), one compiled program (op by op they
    took seconds a point)."""
    def reference(z, lam):
        def lagrangian(z_):
            f, c = nlp.evaluate(z_, data)
            return f + jnp.dot(lam, jnp.reshape(c, (-1,)))

        f, c = nlp.evaluate(z, data)
        return (f, c, jax.grad(lambda z_: nlp.evaluate(z_, data)[0])(z),
                jax.jacfwd(lambda z_: nlp.evaluate(z_, data)[1])(z), jax.hessian(lagrangian)(z))

    return jax.jit(reference)


@pytest.mark.parametrize("name, transcription", [
    ("rocket_landing", SingleShooting(intervals=30, integrator=Heun())),  # 6 rows, 2 controls, trig dynamics
    ("bear_populations", SingleShooting(intervals=25, integrator=RK4())),  # 3 controls, a terminal cost
    ("harvest", SingleShooting(intervals=30, integrator=Heun())),  # no rows at all
    ("epidemic", SingleShooting(intervals=20, integrator=RK4(), grid=tuple(np.linspace(0, 1, 21) ** 1.3))),
    ("cartpole", SingleShooting(intervals=25, integrator=Heun(), grid=tuple(np.linspace(0, 1, 26) ** 0.8))),
])
def test_staged_derivatives_equal_jax_hessian(name, transcription):
    system = load(name)
    nlp = transcribe(system, transcription)
    assert nlp.lagrangian_derivatives is not None
    data = default_data(system)
    staged, reference = jax.jit(nlp.lagrangian_derivatives), _reference(nlp, data)
    for seed in range(2):
        z, lam = _point(nlp, seed)
        got = staged(z, lam, data)
        want = reference(z, lam)
        for label, g, w in zip(("F", "c", "gradient", "Jacobian", "Hessian"), got, want):
            g, w = np.asarray(g), np.reshape(np.asarray(w), np.shape(g))
            assert np.all(np.isfinite(g)), label
            np.testing.assert_allclose(g, w, rtol=1e-11, atol=1e-11 * max(np.max(np.abs(w), initial=0.0), 1.0),
                                       err_msg=f"{name}: {label}")
        np.testing.assert_array_equal(np.asarray(got[4]), np.asarray(got[4]).T)


def test_shared_inputs_and_a_nonlinear_terminal():
    """Steps that read overlapping decisions (here every step reads z[0] as well) and a terminal with curvature."""
    def step(k, y, v):
        t = jnp.asarray(k, y.dtype) * 0.3
        return y + 0.1 * jnp.array([jnp.sin(y[1] * v[0]) + v[1] ** 2, y[0] * v[2] - jnp.cos(t + v[0])])

    def terminal(y):
        return jnp.exp(0.3 * y[0]) + y[1] ** 3, jnp.array([y[0] * y[1], y[1]])

    n_steps = 7
    index = np.stack([np.zeros(n_steps, int), 1 + np.arange(n_steps), 2 + np.arange(n_steps)], axis=1)
    z = jnp.asarray(np.random.default_rng(3).normal(size=n_steps + 2))
    lam = jnp.array([0.7, -1.3])
    y0 = jnp.array([0.2, -0.4])

    def rollout(z_):
        y = y0
        for k in range(n_steps):
            y = step(k, y, z_[index[k]])
        return terminal(y)

    # Each side one compiled program (op by op, the unrolled rollout's Hessian took seconds).
    f, c, grad, jac, hess = jax.jit(lambda z_, l_: staged_derivatives(step, terminal, y0, z_, index, l_))(z, lam)
    want_f, want_grad, want_jac, want = jax.jit(lambda z_: (
        rollout(z_)[0], jax.grad(lambda v: rollout(v)[0])(z_), jax.jacfwd(lambda v: rollout(v)[1])(z_),
        jax.hessian(lambda v: rollout(v)[0] + jnp.dot(lam, rollout(v)[1]))(z_)))(z)
    np.testing.assert_allclose(f, want_f, rtol=1e-14)
    np.testing.assert_allclose(grad, want_grad, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(jac, want_jac, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(hess, want, rtol=1e-11, atol=1e-12)


def test_not_staged_where_other_terms_reach_the_decisions():
    """A free final time, path rows and elastic slacks reach the Lagrangian outside the stages: no staged hook."""
    assert transcribe(load(f"{SCHEMA2}/min_time_double_integrator.yaml"),
                      SingleShooting(intervals=10)).lagrangian_derivatives is None
    assert transcribe(load(f"{SCHEMA2}/keep_out_zone.yaml"),
                      SingleShooting(intervals=10)).lagrangian_derivatives is None
    assert transcribe(load("bacteria"), SingleShooting(intervals=10, soft_state_bounds=100.0)
                      ).lagrangian_derivatives is None


def test_interior_point_solves_the_same_either_way():
    """The interior point with the staged derivatives and with forward over reverse: same iterations, same optimum."""
    import dataclasses

    from myriad.runtime.solvers.base import ScaledProblem
    from myriad.runtime.solvers.interior_point.loop import InteriorPointStepper
    from myriad.runtime.solvers.interior_point.problem import Layout

    system = load("van_der_pol")
    nlp = transcribe(system, SingleShooting(intervals=40, integrator=Heun()))
    data = default_data(system)
    z0 = jnp.asarray(nlp.initial_guess(data))
    staged = ScaledProblem.from_nlp(nlp)
    out = []
    for problem in (staged, dataclasses.replace(staged, derivatives=None)):
        solve_fn = InteriorPointStepper(Layout(problem), tol=1e-8, constr_viol_tol=1e-8, max_iter=200).stepper.solve
        out.append(jax.jit(solve_fn)(data, z0))
    assert int(out[0].status) == int(out[1].status) == 0
    assert int(out[0].iterations) == int(out[1].iterations)
    np.testing.assert_allclose(out[0].objective, out[1].objective, rtol=1e-10)
    np.testing.assert_allclose(out[0].z, out[1].z, rtol=1e-6, atol=1e-8)
    sol = solve(system, SingleShooting(intervals=40, integrator=Heun()), InteriorPoint())
    assert sol.converged


@pytest.mark.parametrize("sigma", [0.0, 0.37])
def test_ipopt_hessian_products_use_the_stages_with_its_objective_factor(sigma):
    """IPOPT's Hessian callback weights the objective by obj_factor (0 in its restoration phase): the staged
    products equal forward over reverse of sigma F + lam^T c."""
    import dataclasses

    from myriad.runtime.solvers.base import ScaledProblem
    from myriad.runtime.solvers.ipopt import _Derivatives
    from myriad.runtime.solvers.sparse import hvp_batch_fn

    system = load("hiv_treatment")
    nlp = transcribe(system, SingleShooting(intervals=30, integrator=Heun()))
    problem = ScaledProblem.from_nlp(nlp)
    data = default_data(system)
    w, lam = _point(nlp, 4)
    w = w / problem.scale
    seeds = jnp.asarray(np.random.default_rng(5).normal(size=(7, nlp.n_variables)))
    fns = _Derivatives(problem, None)
    assert fns.shared  # one program for IPOPT's point and Hessian callbacks
    got = seeds @ jax.jit(fns.staged._jitted)(w, sigma, lam, data, True)[1]
    plain = dataclasses.replace(problem, derivatives=None)

    def gradient(w_, s_, l_, d_):
        return jax.grad(lambda v: s_ * plain.evaluate(v, d_)[0] + jnp.dot(l_, plain.evaluate(v, d_)[1]))(w_)

    want = jax.jit(hvp_batch_fn(gradient))(w, seeds, sigma, lam, data)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * float(jnp.max(jnp.abs(want))))
    # The packed first-order part: F, its gradient, c and the dense Jacobian, row-major as the callbacks read it.
    packed, skipped = jax.jit(fns.staged._jitted)(w, sigma, lam, data, False)
    assert not np.any(skipped)  # a first-order call: the Hessian's part not computed
    (f, c), grad, jac = jax.jit(lambda w_: (*jax.value_and_grad(lambda v: plain.evaluate(v, data), has_aux=True)(w_),
                                            jax.jacfwd(lambda v: plain.evaluate(v, data)[1])(w_)))(w)
    want_packed = jnp.concatenate([jnp.reshape(f, (1,)), grad, jnp.ravel(c), jnp.ravel(jac)])
    np.testing.assert_allclose(packed, want_packed, rtol=1e-10, atol=1e-12 * float(jnp.max(jnp.abs(want_packed))))
