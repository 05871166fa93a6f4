"""End-to-end gradients: the unrolled planner against the solver's own iterates and against finite differences of
the K-step map; the implicit gradient against finite differences of the converged solution map and against the
unrolled gradient as K grows; a solve that did not converge never yields a gradient.

Each test compiles as few programs as it can (finite differences reuse the value of the differentiated program):
compilation, not arithmetic, is what these tests spend their time on."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.data import ProblemData, default_data
from myriad.runtime.e2e import UnrolledPlanner, default_planner_solver, make_implicit_solve
from myriad.runtime.learn.models import Parametric
from myriad.runtime.solvers import Extragradient
from myriad.runtime.solvers.interior_point import InteriorPoint
from myriad.runtime.transcriptions import SingleShooting
from myriad.runtime.transcriptions.base import transcribe

pytestmark = pytest.mark.slow  # not in `make test-fast`: unrolled and implicit gradients through whole solves

# A coarser grid than the published 100 keeps the programs small (20 is too coarse: Heun steps of 1 drive the tumour
# density negative at the guesses, where log(1/x) is NaN).
GRID = SingleShooting(intervals=50)


@pytest.fixture(scope="module")
def cancer():
    system = load("cancer_treatment")
    model = Parametric(system)
    theta = model.true_params()
    nlp = transcribe(model.as_system(theta), GRID)
    data = default_data(model.as_system(theta))
    weights = jnp.asarray(np.random.default_rng(0).normal(size=nlp.n_variables))
    planner = UnrolledPlanner(nlp)

    def data_of(th):
        return ProblemData({"spec": data.params["spec"], "model": th}, data.x0)

    run25 = jax.jit(lambda s: planner.run(s, data, 25))
    return dict(model=model, theta=theta, nlp=nlp, data=data, w=weights, data_of=data_of, planner=planner,
                reset=jax.jit(planner.reset), run25=run25)


def _relative(a, b):
    keys = sorted(b)
    a, b = np.asarray([a[k] for k in keys]), np.asarray([b[k] for k in keys])
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _fd(value, at, eps):
    return {k: (value({**at, k: at[k] + eps}) - value({**at, k: at[k] - eps})) / (2 * eps) for k in at}


def test_unrolled_steps_are_the_solvers_iterations(cancer):
    c = cancer
    planner, data, nlp = c["planner"], c["data"], c["nlp"]
    state = c["run25"](c["reset"](data))
    reference = jax.jit(dataclasses.replace(default_planner_solver(), max_iter=25, tol=1e-300).pure_solve(nlp))(
        data, nlp.initial_guess(data))
    assert int(reference.iterations) == 25
    # The same arithmetic in another program: equal up to XLA's fusion choices (measured: 2e-16).
    np.testing.assert_allclose(np.asarray(planner.z(state)), np.asarray(reference.z), rtol=1e-13, atol=1e-15)


def test_unrolled_gradient_matches_finite_differences_of_the_k_step_map(cancer):
    c = cancer
    planner, w, data_of = c["planner"], c["w"], c["data_of"]
    warm = c["run25"](c["reset"](c["data"]))  # a warm start in the middle of a solve
    at = c["model"].init_params()  # the guesses, far from the truth: the K-step map moves
    k_step = jax.jit(jax.value_and_grad(lambda th: jnp.dot(w, planner.z(planner.run(warm, data_of(th), 10)))))
    _, grad = k_step(at)
    fd = _fd(lambda th: k_step(th)[0], at, 1e-6)
    assert _relative(grad, fd) < 1e-6, (grad, fd)


def test_implicit_gradient_matches_the_converged_solution_map_and_the_unrolled_limit(cancer):
    c = cancer
    planner, w, data_of, theta, data = c["planner"], c["w"], c["data_of"], c["theta"], c["data"]
    isolve = make_implicit_solve(c["nlp"], Extragradient(tol=1e-11, max_iter=100_000))
    # A converged warm start whose step-rule state has seen the whole solve (AMSGrad's running maximum): from a
    # state reset *at* the solution, the rule's normaliser is tiny and the linearised steps blow up.
    state = c["reset"](data)
    for _ in range(120):
        state = c["run25"](state)
    assert float(planner.kkt(state)) < 1e-10
    z_star = planner.z(state)
    solution = jax.jit(jax.value_and_grad(lambda th: jnp.dot(w, isolve(data_of(th).params, data.x0, z_star).z)))
    _, implicit = solution(theta)
    fd = _fd(lambda th: solution(th)[0], theta, 1e-5)
    assert _relative(implicit, fd) < 1e-4, (implicit, fd)

    unrolled = jax.jit(jax.grad(lambda th, k: jnp.dot(w, planner.z(planner.run(state, data_of(th), 400, k)))))
    errors = [_relative(unrolled(theta, k), implicit) for k in (5, 50, 400)]
    assert errors[0] > errors[1] > errors[2] and errors[2] <= 1e-4, errors


def test_a_solve_that_did_not_converge_gives_nan_never_a_silent_gradient(cancer):
    c = cancer
    data, data_of, w = c["data"], c["data_of"], c["w"]
    isolve = make_implicit_solve(c["nlp"], Extragradient(tol=1e-12, max_iter=3))
    z0 = c["nlp"].initial_guess(data)

    def value(th):
        out = isolve(data_of(th).params, data.x0, z0)
        return jnp.dot(w, out.z), out.converged

    (_, converged), grad = jax.jit(jax.value_and_grad(value, has_aux=True))(c["theta"])
    assert not bool(converged)
    assert all(np.isnan(float(v)) for v in grad.values())


def test_the_interior_point_as_implicit_solver_matches_the_converged_solution_map(cancer):
    # Newton steps from the transcription's guess (no warm state needed), the solver's own implicit rule.
    c = cancer
    data, data_of, w, theta = c["data"], c["data_of"], c["w"], c["theta"]
    isolve = make_implicit_solve(c["nlp"], InteriorPoint(tol=1e-11))
    z0 = c["nlp"].initial_guess(data)

    def value(th):
        out = isolve(data_of(th).params, data.x0, z0)
        return jnp.dot(w, out.z), (out.converged, out.iterations)

    solution = jax.jit(jax.value_and_grad(value, has_aux=True))
    (_, (converged, iterations)), implicit = solution(theta)
    assert bool(converged) and int(iterations) < 100, int(iterations)
    fd = _fd(lambda th: solution(th)[0][0], theta, 1e-5)
    assert _relative(implicit, fd) < 1e-4, (implicit, fd)
