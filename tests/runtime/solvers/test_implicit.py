"""The implicit-function rule (``runtime/solvers/implicit.py``) stage by stage against its dense reference and against
finite differences of re-solves.

Where an NLP has a stage structure the rule's KKT matrix ``[[H_ff, J_af^T], [J_af, 0]]`` is assembled and factorised
stage by stage (the interior point's block-tridiagonal factorisation). Checked: at random points, multipliers and
free / active sets of every staged transcription (path rows, a free final time, graded grids), the pulled-back
cotangents equal the dense solve's; through a whole collocation solve the gradient of the optimal cost is the
Lagrangian's partial derivative (the envelope theorem) and the controls' derivative in x0 is the central difference
of re-solves, single and vmapped; a singular restriction is refused, not answered.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.data import ProblemData, default_data
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.solvers.base import ScaledProblem
from myriad.runtime.solvers.implicit import Active, kkt_vjp
from myriad.runtime.status import Status
from myriad.runtime.transcriptions import HermiteSimpson

from .._stage_cases import case, random_point

jax.config.update("jax_enable_x64", True)


def _masks(nlp, seed, fixed):
    """Random active rows (every equality, a fifth of the inequalities), variables on a bound (a fraction ``fixed``)."""
    rng = np.random.default_rng(seed)
    free = rng.random(nlp.n_variables) >= fixed
    equality = np.asarray(nlp.c_lower) == np.asarray(nlp.c_upper)
    return free, equality | (rng.random(nlp.n_constraints) > 0.8)


@pytest.mark.parametrize("name", ["trapezoidal-path", "hermite_simpson-free-time",
                                  "multiple_shooting-free-time-graded"])
def test_stage_solve_equals_the_dense_reference(name):
    """Every variable free, then a few on a bound (seeds whose restriction the dense solve finds singular, an
    equality row left with no free variable, are skipped: at least three must remain)."""
    _, _, nlp, data = case(name)
    problem = ScaledProblem.from_nlp(nlp)
    z, y = random_point(nlp, data, seed=3)
    rng = np.random.default_rng(5)
    w_bar, y_bar = rng.standard_normal(nlp.n_variables), rng.standard_normal(nlp.n_constraints)

    @jax.jit
    def pull(d, w, free, active, y_):
        at = Active(jnp.where(active, y_, 0.0), free, active)
        return kkt_vjp(problem, d, w, at, w_bar, y_bar, stages=True), kkt_vjp(problem, d, w, at, w_bar, y_bar,
                                                                                stages=False)

    compared = 0
    for seed, fixed in [(4, 0.0), (5, 0.0), (6, 0.03), (7, 0.03), (8, 0.03), (9, 0.03)]:
        free, active = _masks(nlp, seed, fixed)
        (staged, ok_staged), (dense, ok_dense) = pull(data, z / nlp.z_scale, free, active, y)
        if not bool(ok_dense):
            continue
        assert bool(ok_staged), seed
        flat_s, flat_d = jax.tree.leaves(staged), jax.tree.leaves(dense)
        scale = max(float(jnp.max(jnp.abs(a))) for a in flat_d)
        assert scale > 0.0
        for a, b in zip(flat_s, flat_d):
            np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-9 * scale)
        compared += 1
    assert compared >= 3


def test_a_singular_restriction_is_refused():
    """Every variable on its bound and a row active: the restricted KKT matrix is singular (an active row with no free
    variable), and the rule says so instead of answering."""
    _, _, nlp, data = case("trapezoidal-vdp")
    problem = ScaledProblem.from_nlp(nlp)
    z, y = random_point(nlp, data, seed=1)
    at = Active(jnp.asarray(y), jnp.zeros(nlp.n_variables, bool), jnp.ones(nlp.n_constraints, bool))
    w_bar = np.ones(nlp.n_variables)
    y_bar = np.ones(nlp.n_constraints)
    _, ok = jax.jit(lambda d, w: kkt_vjp(problem, d, w, at, w_bar, y_bar))(data, z / nlp.z_scale)
    assert not bool(ok)


@pytest.mark.slow
def test_collocation_gradients_envelope_finite_differences_and_batches():
    """Mould Fungicide on Hermite-Simpson(10) with the banded step: d(optimal cost)/d(params) is the Lagrangian's
    partial derivative at the solution to 1e-7; d(a weighted sum of the controls)/d(x0) is the central difference of
    re-solves to 1e-5 for each member of a vmapped batch."""
    system = load("mould_fungicide")
    nlp = HermiteSimpson(intervals=10).transcribe(system)
    data = default_data(system)
    solver = InteriorPoint()
    assert solver.kkt_method(nlp) == "banded"
    solve_fn = solver.solve_fn(nlp)
    z0 = nlp.initial_guess(data)
    out = solve_fn(data, z0)
    assert int(out.status) == Status.CONVERGED
    n_controls = nlp.unravel(out.z, data)[2].size
    weights = jnp.asarray(np.random.default_rng(2).standard_normal(n_controls))

    def outputs(params, x0):
        dat = ProblemData(params, x0)
        sol = solve_fn(dat, z0)
        return jnp.stack([sol.objective, jnp.dot(weights, nlp.unravel(sol.z, dat)[2].ravel())])

    x0s = jnp.stack([data.x0, 0.9 * data.x0, 1.1 * data.x0])
    jac = jax.jit(jax.vmap(jax.jacrev(outputs, argnums=(0, 1)), in_axes=(None, 0)))
    d_params, d_x0 = jac(data.params, x0s)

    def lagrangian(params):
        dat = ProblemData(params, data.x0)
        return nlp.objective(out.z, dat) + jnp.dot(out.multipliers, nlp.constraints(out.z, dat))

    envelope = jax.grad(lagrangian)(data.params)
    for key in data.params:
        g, e = float(d_params[key][0, 0]), float(envelope[key])
        assert abs(g - e) <= 1e-7 * max(1.0, abs(e)), (key, g, e)
    eps = 1e-5 * max(1.0, float(jnp.max(jnp.abs(data.x0))))
    shifted = jnp.concatenate([x0s + eps, x0s - eps])
    values = np.asarray(jax.jit(jax.vmap(outputs, in_axes=(None, 0)))(data.params, shifted))
    fd = (values[:3, 1] - values[3:, 1]) / (2 * eps)
    np.testing.assert_allclose(np.asarray(d_x0[:, 1, 0]), fd, rtol=1e-5, atol=1e-5)
