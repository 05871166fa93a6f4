"""InteriorPoint (pure-JAX primal-dual interior point) against mathematics and against IPOPT.

A projection onto a scaled simplex has a closed-form optimum (z = max(a - t, 0) with sum z = b), so it checks the
solution, batching, recompilation and the implicit gradients exactly; IPOPT's optimum is the reference on transcribed
optimal-control problems at the published setting. Statuses: an infeasible box, a NaN objective, an iteration limit.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.bench import PUBLISHED_SETTING
from myriad.runtime.data import ProblemData, default_data
from myriad.runtime.nlp import NLP
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.solvers.base import canonical_data
from myriad.runtime.solvers.interior_point.solver import CPU_CHUNK
from myriad.runtime.status import Status

pytestmark = pytest.mark.slow  # not in `make test-fast`: interior-point solves, batches and implicit gradients

jax.config.update("jax_enable_x64", True)

INF = np.inf
N = 5


def _unravel(z, data):
    return jnp.zeros(1), z[None, :], jnp.zeros((1, 0))


def _nlp(objective, constraints, c_lo, c_up, z_lo, z_up, guess, name) -> NLP:
    f64 = lambda a: np.asarray(a, dtype=np.float64)  # noqa: E731
    return NLP(objective, constraints, f64(c_lo), f64(c_up), f64(z_lo), f64(z_up), lambda d: f64(guess), _unravel,
               name=name)


# ---- the simplex projection: min |z - a|^2 s.t. sum z = b, z >= 0 (a = params["a"], b = x0[0]) -----------------


@functools.cache
def simplex() -> NLP:
    return _nlp(lambda z, d: jnp.sum((z - d["params"]["a"]) ** 2), lambda z, d: jnp.stack([jnp.sum(z) - d["x0"][0]]),
                [0.0], [0.0], np.zeros(N), np.full(N, INF), np.full(N, 0.3), "simplex")


def simplex_data(a, b):
    return {"params": {"a": np.asarray(a, dtype=np.float64)}, "x0": np.array([b], dtype=np.float64)}


def simplex_exact(a, b):
    """z* = max(a - t, 0) with t from the sorted a (the textbook projection), and y* = 2 t (IPOPT's sign)."""
    u = np.sort(a)[::-1]
    k = max(j for j in range(1, N + 1) if u[j - 1] - (np.sum(u[:j]) - b) / j > 0)
    t = (np.sum(u[:k]) - b) / k
    z = np.maximum(a - t, 0.0)
    return z, float(np.sum((z - a) ** 2)), 2.0 * t


A0, B0 = np.array([0.9, 0.1, -0.3, 0.5, 0.05]), 1.0  # two variables end on their bound


def test_simplex_projection_reaches_the_closed_form_optimum():
    result = InteriorPoint().solve(simplex(), simplex_data(A0, B0))
    z_star, f_star, y_star = simplex_exact(A0, B0)
    assert result.success and result.status is Status.CONVERGED, result.message
    assert np.max(np.abs(result.z - z_star)) <= 1e-7  # the barrier leaves z within ~mu / multiplier (mu = 1e-9)
    assert abs(result.objective - f_star) <= 1e-8
    np.testing.assert_allclose(result.multipliers, [y_star], atol=1e-7)
    assert np.all(result.z >= 0.0)


def test_second_solve_with_new_data_compiles_nothing():
    solver, nlp = InteriorPoint(), simplex()
    solver.solve(nlp, simplex_data(A0, B0))
    events = []

    def listener(event, duration, **kwargs):
        if "backend_compile" in event:
            events.append(event)

    a = [0.2, 0.4, 0.1, -0.5, 0.3]
    new = {"params": {"a": jax.block_until_ready(jnp.asarray(a))}, "x0": np.array([0.7])}  # a jax array this time
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        second = solver.solve(nlp, new)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert events == [] and second.compile_seconds == 0.0
    z_star, _, _ = simplex_exact(np.array(a), 0.7)
    assert second.success and np.max(np.abs(second.z - z_star)) <= 1e-7


@pytest.mark.parametrize("strategy, chunk", [("vmap", None), ("map", None), ("vmap", 4)])
def test_batch_equals_one_at_a_time(strategy, chunk):
    """Vmapped at once, mapped, and vmapped four at a time with the places of stopped members refilled."""
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-0.5, 1.0, (6, N)), rng.uniform(0.5, 2.0, 6)
    solver, nlp = InteriorPoint(batch=strategy, chunk=chunk), simplex()
    assert solver.batch_strategy() == strategy
    batch = solver.solve_batch(nlp, {"params": {"a": a}, "x0": b[:, None]})
    if chunk:
        assert len({m.iterations for m in batch}) > 1  # places were freed at different iterations
    for i, member in enumerate(batch):
        single = solver.solve(nlp, simplex_data(a[i], b[i]))
        assert member.success and member.iterations == single.iterations
        np.testing.assert_allclose(member.z, single.z, rtol=0, atol=1e-12)
        np.testing.assert_allclose(member.z, simplex_exact(a[i], b[i])[0], atol=1e-7)
    assert len({round(m.objective, 8) for m in batch}) == 6


def test_batch_strategy_auto_maps_on_a_cpu_and_rejects_unknown_names():
    assert InteriorPoint().batch_strategy() == ("map" if jax.default_backend() == "cpu" else "vmap")
    with pytest.raises(ValueError, match="batch must be"):
        InteriorPoint(batch="pmap")
    # Chunks: only a vmapped batch is cut into them (CPU_CHUNK members on a CPU by default).
    assert InteriorPoint(batch="map").batch_chunk() is None
    assert InteriorPoint(batch="vmap").batch_chunk() == (CPU_CHUNK if jax.default_backend() == "cpu" else None)
    assert InteriorPoint(batch="vmap", chunk=None).batch_chunk() is None
    assert InteriorPoint(batch="vmap", chunk=16).batch_chunk() == 16
    for bad in (0, -3, 2.5, True, "big"):
        with pytest.raises(ValueError, match="chunk must be"):
            InteriorPoint(chunk=bad)


def optimal_cost(solve_fn, z0):
    def cost(a, b):
        return solve_fn({"params": {"a": jnp.asarray(a)}, "x0": jnp.reshape(jnp.asarray(b), (1,))}, z0).objective

    return cost


def test_gradient_of_the_optimal_cost_is_the_lagrangians_partial_derivative():
    """Envelope theorem: dF*/da = dL/da = -2 (z* - a) and dF*/db = dL/db = -y*, also against central differences."""
    nlp = simplex()
    solve_fn = InteriorPoint().solve_fn(nlp)
    z0 = nlp.initial_guess(None)
    grad_a, grad_b = jax.grad(optimal_cost(solve_fn, z0), argnums=(0, 1))(jnp.asarray(A0), jnp.float64(B0))
    z_star, _, y_star = simplex_exact(A0, B0)
    np.testing.assert_allclose(grad_a, -2.0 * (z_star - A0), atol=1e-6)
    np.testing.assert_allclose(grad_b, -y_star, atol=1e-6)
    eps, cost = 1e-6, lambda a, b: float(optimal_cost(solve_fn, z0)(a, b))  # noqa: E731
    fd_a = [(cost(A0 + eps * e, B0) - cost(A0 - eps * e, B0)) / (2 * eps) for e in np.eye(N)]
    np.testing.assert_allclose(grad_a, fd_a, atol=1e-5)
    # z* itself: the free entries move with a at slope 1 - 1/k, and the held ones not at all.
    jac = jax.jacrev(lambda a: solve_fn({"params": {"a": a}, "x0": jnp.array([B0])}, z0).z)(jnp.asarray(A0))
    free = z_star > 0
    expected = np.where(free[:, None] & free[None, :], np.eye(N) - 1.0 / free.sum(), 0.0)
    np.testing.assert_allclose(jac, expected, atol=1e-6)


def test_batched_gradients_equal_single_gradients():
    nlp = simplex()
    solve_fn = InteriorPoint().solve_fn(nlp)
    z0 = nlp.initial_guess(None)
    grad = jax.grad(optimal_cost(solve_fn, z0), argnums=0)
    a = jnp.asarray(np.random.default_rng(1).uniform(-0.5, 1.0, (4, N)))
    b = jnp.array([0.6, 1.0, 1.4, 2.0])
    batched = jax.vmap(grad)(a, b)
    for i in range(4):
        np.testing.assert_allclose(batched[i], grad(a[i], b[i]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(batched[i], -2.0 * (simplex_exact(np.asarray(a[i]), float(b[i]))[0] - a[i]),
                                   atol=1e-6)


def test_iteration_limit_is_a_failure_and_its_gradient_is_flagged():
    nlp, solver = simplex(), InteriorPoint(max_iter=2)
    result = solver.solve(nlp, simplex_data(A0, B0))
    assert not result.success and result.status is Status.ITERATION_LIMIT and result.iterations == 2
    grad = jax.grad(optimal_cost(solver.solve_fn(nlp), nlp.initial_guess(None)))(jnp.asarray(A0), jnp.float64(B0))
    assert np.all(np.isnan(grad)), "a non-converged solve must not give a silent gradient"


# ---- statuses ----------------------------------------------------------------------------------------------------


def test_infeasible_problem_is_reported_infeasible():
    # z1 + z2 = 1 cannot hold with both in [0, 0.1]: the closest point (0.1, 0.1) leaves a violation of 0.8.
    nlp = _nlp(lambda z, d: z @ z, lambda z, d: jnp.stack([z[0] + z[1]]), [1.0], [1.0], [0.0, 0.0], [0.1, 0.1],
               [0.05, 0.05], "infeasible")
    result = InteriorPoint().solve(nlp, {"params": {}, "x0": np.zeros(1)})
    assert result.status is Status.INFEASIBLE and not result.success
    assert result.constraint_violation == pytest.approx(0.8, abs=1e-6)
    assert result.iterations < 50


def test_a_nan_objective_is_reported_not_finite():
    # sqrt(z - 2) is NaN at the start z = 0 (no bound keeps z >= 2).
    nlp = _nlp(lambda z, d: jnp.sum(jnp.sqrt(z - 2.0)), None, [], [], [-INF], [INF], [0.0], "nan")
    result = InteriorPoint().solve(nlp, {"params": {}, "x0": np.zeros(1)})
    assert result.status is Status.NOT_FINITE and not result.success
    assert result.iterations == 0


# ---- transcribed optimal-control problems against IPOPT -----------------------------------------------------------


@functools.cache
def published(name):
    """The system, its published-setting NLP (one object: compiled programs are shared) and its default data."""
    system = load(name)
    return system, PUBLISHED_SETTING.transcribe(system), canonical_data(default_data(system))


def final_values(system, nlp, z, data):
    states = np.asarray(jax.jit(nlp.unravel)(jnp.asarray(z), data)[1])
    return (states[-1] - np.asarray(system.final_values))[system.final_mask]


@pytest.mark.parametrize("name", ["mould_fungicide", "van_der_pol"])
def test_agrees_with_ipopt_at_the_published_setting(name):
    """Costs to 1e-8 relative and the required final values to 1e-8 (van_der_pol has two); more systems and the whole
    table: bench/interior_point_table.py."""
    system, nlp, data = published(name)
    ref, ip = Ipopt().solve(nlp, data), InteriorPoint().solve(nlp, data)
    assert ref.success and ip.success, ip.message
    assert abs(ip.objective - ref.objective) <= 1e-8 * abs(ref.objective)
    np.testing.assert_allclose(final_values(system, nlp, ip.z, data), final_values(system, nlp, ref.z, data),
                               rtol=0, atol=1e-8)


def test_ocp_gradients_envelope_and_finite_differences():
    """d(optimal cost)/d(params) = dL/d(params) at the solution (envelope theorem) to 1e-6, and central differences
    of re-solves to 1e-5; d(controls)/d(x0) against central differences."""
    system, nlp, data = published("mould_fungicide")
    solve_fn = InteriorPoint().solve_fn(nlp)
    z0 = nlp.initial_guess(data)
    out = solve_fn(data, z0)
    assert int(out.status) == Status.CONVERGED
    weights = jnp.asarray(np.random.default_rng(2).standard_normal(nlp.n_variables))

    @jax.jit
    def outputs(params, x0):
        """(optimal cost, a weighted sum of the optimal controls)."""
        dat = ProblemData(params, x0)
        sol = solve_fn(dat, z0)
        return jnp.stack([sol.objective, jnp.dot(weights, nlp.unravel(sol.z, dat)[2].ravel())])

    (d_params, d_x0) = jax.jacrev(outputs, argnums=(0, 1))(data.params, data.x0)

    def lagrangian(params):
        dat = ProblemData(params, data.x0)
        return nlp.objective(out.z, dat) + jnp.dot(out.multipliers, nlp.constraints(out.z, dat))

    envelope = jax.grad(lagrangian)(data.params)
    for key in data.params:
        g, e = float(d_params[key][0]), float(envelope[key])
        assert abs(g - e) <= 1e-6 * max(1.0, abs(e)), (key, g, e)
    key = "r"
    eps = 1e-5 * max(1.0, abs(float(data.params[key])))
    shifted = lambda s: np.asarray(outputs({**data.params, key: data.params[key] + s}, data.x0))  # noqa: E731
    fd = (shifted(eps) - shifted(-eps)) / (2 * eps)
    assert abs(float(d_params[key][0]) - fd[0]) <= 1e-5 * max(1.0, abs(fd[0])), (float(d_params[key][0]), fd[0])
    eps = 1e-5 * max(1.0, float(jnp.max(jnp.abs(data.x0))))
    for i, e in enumerate(np.eye(data.x0.shape[0])):
        fd = (np.asarray(outputs(data.params, data.x0 + eps * e)) - np.asarray(outputs(data.params, data.x0 - eps * e)))
        fd = fd[1] / (2 * eps)
        assert abs(float(d_x0[1, i]) - fd) <= 1e-5 * max(1.0, abs(fd)), (float(d_x0[1, i]), fd)


def test_a_primal_dual_warm_start_reaches_the_same_optimum_in_fewer_steps():
    """``solution.warm`` restarts at the last point, multipliers and scaling (IPOPT's warm_start_init_point): on a
    nearby problem it reaches the cold solve's optimum (and the closed form) in fewer Newton steps, the gradient
    through it is the same, and a cold ``WarmStart`` is exactly the array start."""
    nlp = simplex()
    solver = InteriorPoint()
    solve_fn, cold = jax.jit(solver.pure_solve(nlp)), jax.jit(solver.cold_start(nlp))
    z0 = jnp.asarray(nlp.initial_guess(None))
    first = solve_fn(simplex_data(A0, B0), z0)
    near = simplex_data(np.asarray(A0) + 0.01 * np.arange(N), B0 * 1.01)
    from_cold, from_warm = solve_fn(near, z0), solve_fn(near, first.warm)
    assert int(from_cold.status) == int(from_warm.status) == Status.CONVERGED
    z_exact, f_exact, _ = simplex_exact(near["params"]["a"], near["x0"][0])
    np.testing.assert_allclose(from_warm.z, z_exact, atol=1e-7)
    assert abs(float(from_warm.objective) - float(from_cold.objective)) <= 1e-9 * max(1.0, f_exact)
    assert int(from_warm.iterations) < int(from_cold.iterations), (from_warm.iterations, from_cold.iterations)
    same = solve_fn(near, cold(near, z0))
    assert int(same.iterations) == int(from_cold.iterations) and np.array_equal(same.z, from_cold.z)
    grad = lambda start: jax.grad(lambda a: solve_fn({**near, "params": {"a": a}}, start).objective)(  # noqa: E731
        jnp.asarray(near["params"]["a"]))
    np.testing.assert_allclose(grad(first.warm), grad(z0), rtol=1e-6, atol=1e-9)
