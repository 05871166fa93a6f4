"""The interior point's stage-wise Newton step (``interior_point.riccati``) against dense linear algebra.

The Riccati recursion factorises the same matrices as the dense method (``kkt.py``): ``H + Sigma + delta_w I`` with
``rho A^T A`` (the certificate) or ``A^T diag(w) A`` (the restoration phase). So its steps must solve the dense KKT
system built from the chain rule's Hessian (``np.linalg.solve``), the matrix it accepts must have inertia
``(n_x, m, 0)`` (``np.linalg.eigvalsh``), and on real single-shooting NLPs its derivatives, ``delta_w`` and step must
be those of the dense path; a solve takes the same iterations to the same optimum.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load, solve, solve_batch
from myriad.runtime.data import default_data
from myriad.runtime.integrators import Heun
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.solvers.base import ScaledProblem
from myriad.runtime.solvers.interior_point import kkt, rules
from myriad.runtime.solvers.interior_point.problem import Layout
from myriad.runtime.solvers.interior_point.riccati import Riccati, StageHessian, chain
from myriad.runtime.solvers.interior_point.rules import CHECK_COND, condition_bound, residual_ratio
from myriad.runtime.transcriptions import SingleShooting
from myriad.runtime.transcriptions.base import transcribe

pytestmark = pytest.mark.slow  # not in `make test-fast`: every test compiles Riccati and dense KKT programs

jax.config.update("jax_enable_x64", True)


def _random_stages(seed, n_steps=7, n_y=3, n_u=2, m=3, n_s=1, shared="heun", negative=0.0):
    """Random stage data, and the Hessian of the barrier problem by the chain rule (``S_{k+1} = A_k S_k + B_k P_k``,
    ``H = sum_k [S_k; P_k]^T W_k [S_k; P_k] + S_N^T G_yy S_N``), with ``A = [G S_N, J_s]``."""
    rng = np.random.default_rng(seed)
    width = n_u if shared == "disjoint" else 2 * n_u  # Heun's steps read u_k and u_{k+1}; disjoint ones u_k
    index = np.arange(n_steps)[:, None] * n_u + np.arange(width)[None, :]
    if shared == "global":  # every step reads z[:n_u] too (a parameter-like decision carried to the end)
        index = np.concatenate([np.broadcast_to(np.arange(n_u), (n_steps, n_u)), n_u + index[:, :n_u]], axis=1)
    n = int(index.max()) + 1
    a = 0.6 * rng.standard_normal((n_steps, n_y, n_y))
    b = rng.standard_normal((n_steps, n_y, width))
    w = rng.standard_normal((n_steps, n_y + width, n_y + width))
    w = w @ np.swapaxes(w, 1, 2) / (n_y + width) - negative * np.eye(n_y + width)
    g = rng.standard_normal((n_y, n_y))
    g_yy, g_rows = g @ g.T / n_y, rng.standard_normal((m, n_y))
    sens, hess = np.zeros((n_y, n)), np.zeros((n, n))
    for k in range(n_steps):
        pick = np.zeros((width, n))
        pick[np.arange(width), index[k]] = 1.0
        jk = np.vstack([sens, pick])
        hess += jk.T @ w[k] @ jk
        sens = a[k] @ sens + b[k] @ pick
    hess += sens.T @ g_yy @ sens
    j_s = np.zeros((m, n_s))
    j_s[m - n_s + np.arange(n_s), np.arange(n_s)] = -rng.uniform(0.5, 2.0, n_s)  # slack rows: c - s
    hess_x = np.zeros((n + n_s, n + n_s))
    hess_x[:n, :n] = hess
    stages = StageHessian(*map(jnp.asarray, (a, b, w, g_yy, g_rows)))
    return (Riccati(index, n, n_s), stages, hess_x, jnp.asarray(rng.uniform(0.0, 1.0, n + n_s)),
            jnp.asarray(np.hstack([g_rows @ sens, j_s])))


def _inertia(matrix):
    ev = np.linalg.eigvalsh(matrix)
    return int((ev > 0).sum()), int((ev < 0).sum())


def test_chain_reads_shared_and_disjoint_steps():
    heun = np.arange(5)[:, None] * 2 + np.arange(4)[None, :]
    carry, new, sel = chain(heun, 12)
    assert carry.tolist() == [0, 1] and new.tolist() == [2, 3] and sel.tolist() == [2, 3]
    carry, new, _ = chain(np.arange(10).reshape(5, 2), 10)
    assert carry.size == 0 and new.tolist() == [0, 1]
    assert chain(heun, 13) is None  # a decision no step reads
    carry, new, sel = chain(np.stack([np.zeros(4, int), 1 + np.arange(4)], axis=1), 5)  # every step reads z[0]
    assert carry.tolist() == [0] and new.tolist() == [1] and sel.tolist() == [0]
    assert chain(np.array([[0, 1], [1, 2], [0, 3]]), 4) is None  # z[0] again after a step without it


@pytest.mark.parametrize("shared, negative", [("heun", 1.5), ("disjoint", 0.0), ("global", 1.5)])
def test_step_and_inertia_against_dense(shared, negative):
    ric, stages, hess, sigma, jac = _random_stages(0, shared=shared, negative=negative)
    n_x, m = hess.shape[0], jac.shape[0]
    rng = np.random.default_rng(1)
    v = jnp.asarray(rng.standard_normal(n_x))
    # Every JAX call here one compiled program: op by op they took most of the test's seconds.
    np.testing.assert_allclose(jax.jit(ric.hvp)(stages, v), hess @ v, rtol=1e-12, atol=1e-12)

    factors, delta_w, ok = jax.jit(ric.factorize_with_inertia)(stages, sigma, jac, 1e-3, 0.0)
    _, delta_w_dense, _ = jax.jit(kkt.factorize_with_inertia)(jnp.asarray(hess), sigma, jac, 1e-3, 0.0)
    assert ok and float(delta_w) == float(delta_w_dense)
    h_s = hess + np.diag(np.asarray(sigma)) + float(delta_w) * np.eye(n_x)
    big = np.block([[h_s, np.asarray(jac).T], [np.asarray(jac), -float(factors.delta_c) * np.eye(m)]])
    assert _inertia(big) == (n_x, m)
    if float(delta_w) > 0:  # the schedule's previous value would not have done
        smaller = big - (1 - 1 / rules.GROW_FIRST) * float(delta_w) * np.diag(np.r_[np.ones(n_x), np.zeros(m)])
        assert _inertia(smaller) != (n_x, m)
    r1, r2 = rng.standard_normal(n_x), rng.standard_normal(m)
    solve = jax.jit(ric.solve, static_argnames="presolved")
    dx, dl = solve(factors, jac, jnp.asarray(r1), jnp.asarray(r2))
    expected = np.linalg.solve(big, np.concatenate([r1, r2]))
    np.testing.assert_allclose(np.concatenate([dx, dl]), expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    # r1 solved with the Schur complement's columns: the same step (H^-1 (r1 + rho A^T r2), split by linearity).
    pre, _, _ = jax.jit(ric.factorize_with_inertia)(stages, sigma, jac, 1e-3, 0.0, jnp.asarray(r1))
    dx_p, dl_p = solve(pre, jac, jnp.asarray(r1), jnp.asarray(r2), presolved=True)
    np.testing.assert_allclose(np.concatenate([dx_p, dl_p]), expected, rtol=1e-10,
                               atol=1e-10 * np.abs(expected).max())


def test_refinement_only_where_the_residual_asks():
    """Where the factors are doubted (``check``), the refinement step is taken where IPOPT's residual ratio exceeds
    1e-10: factors of a nearby matrix (Sigma off by 1e-6 relative) leave a residual of that size, which one step
    reduces to its square; exact factors need none. Undoubted factors are trusted: no residual, no refinement."""
    ric, stages, hess, sigma, jac = _random_stages(0, shared="heun", negative=0.0)
    n_x, m = hess.shape[0], jac.shape[0]
    rng = np.random.default_rng(2)
    r1, r2 = rng.standard_normal(n_x), rng.standard_normal(m)
    exact, delta_w, _ = jax.jit(ric.factorize_with_inertia)(stages, sigma, jac, 1e-3, 0.0)
    assert not bool(exact.check)  # the first rho, no delta_c, a well-conditioned Schur complement
    near, _, _ = jax.jit(ric.factorize_with_inertia)(stages, sigma * (1 + 1e-6), jac, 1e-3, 0.0)
    near = near._replace(d=exact.d)  # the residual is measured against the exact matrix
    h_s = hess + np.diag(np.asarray(sigma)) + float(delta_w) * np.eye(n_x)
    big = np.block([[h_s, np.asarray(jac).T], [np.asarray(jac), -float(exact.delta_c) * np.eye(m)]])
    expected = np.linalg.solve(big, np.concatenate([r1, r2]))
    once = np.concatenate(ric._once(near, jac, jnp.asarray(r1), jnp.asarray(r2)))
    trusted = np.concatenate(ric.solve(near, jac, jnp.asarray(r1), jnp.asarray(r2)))
    refined = np.concatenate(ric.solve(near._replace(check=jnp.array(True)), jac, jnp.asarray(r1), jnp.asarray(r2)))
    scale = np.abs(expected).max()
    assert np.abs(once - expected).max() > 1e-9 * scale  # the unrefined step is off ...
    np.testing.assert_array_equal(trusted, once)  # ... and is what an undoubted factorisation gives ...
    assert np.abs(refined - expected).max() < 1e-10 * scale  # ... while a doubted one takes the refinement
    res = big @ np.concatenate(ric._once(exact, jac, jnp.asarray(r1), jnp.asarray(r2))) - np.concatenate([r1, r2])
    ratio = residual_ratio((r1, r2), (expected[:n_x], expected[n_x:]), (res[:n_x], res[n_x:]))
    assert float(ratio) < 1e-10  # exact factors: no refinement is needed
    checked = np.concatenate(ric.solve(exact._replace(check=jnp.array(True)), jac, jnp.asarray(r1), jnp.asarray(r2)))
    np.testing.assert_array_equal(checked, np.concatenate(ric._once(exact, jac, jnp.asarray(r1), jnp.asarray(r2))))
    assert float(residual_ratio((np.zeros(2),), (np.zeros(2),), (np.array([3.0, -4.0]),))) == 4.0


def test_factors_are_doubted_after_a_retry_or_with_nearly_dependent_rows():
    """``check`` is set where the certificate raised rho or delta_w (negative curvature), and where two constraint
    rows are nearly parallel (the unit-diagonal Schur complement's condition bound above CHECK_COND), not where the
    rows are only scaled differently."""
    ric, stages, hess, sigma, jac = _random_stages(0, shared="heun", negative=1.5)
    f, delta_w, ok = jax.jit(ric.factorize_with_inertia)(stages, sigma, jac, 1e-3, 0.0)
    assert ok and float(delta_w) > 0 and bool(f.check)
    ric, stages, hess, sigma, jac = _random_stages(0, shared="heun", negative=0.0)
    scaled = jac * jnp.asarray([1e-6, 1.0, 1e4])[:, None]
    f, _, _ = jax.jit(ric.factorize_with_inertia)(stages, sigma, scaled, 1e-3, 0.0)
    assert not bool(f.check) and float(condition_bound(f.chol_s)) < 1e3
    n = jac.shape[1] - 1  # the decisions (the last column is the slack)
    parallel = jac.at[1, :n].set(jac[0, :n] * (1.0 + 1e-5 * jnp.arange(n, dtype=jac.dtype) / n))
    f, _, _ = jax.jit(ric.factorize_with_inertia)(stages, sigma, parallel, 1e-3, 0.0)
    assert float(condition_bound(f.chol_s)) > CHECK_COND and bool(f.check)
    chol = np.linalg.cholesky(np.array([[4.0, 2.0], [2.0, 2.0]]))  # unit diagonal: [[1, 1/sqrt2], [., 1]]
    assert abs(float(condition_bound(jnp.asarray(chol))) - 2.0) < 1e-12  # 1 / (1 - 1/2)


def test_restoration_system_against_dense():
    """``H_s + A^T diag(w) A`` positive definite at the least ``delta_w`` of the schedule, and its step."""
    ric, stages, hess, sigma, jac = _random_stages(2, negative=1.5, n_s=2)
    n_x, m = hess.shape[0], jac.shape[0]
    weights = jnp.asarray(np.random.default_rng(3).uniform(0.1, 10.0, m))
    factors, delta_w, ok = jax.jit(ric.factorize_weighted)(stages, sigma, jac, weights, 0.0)
    base = hess + np.diag(np.asarray(sigma)) + np.asarray(jac).T @ np.diag(np.asarray(weights)) @ np.asarray(jac)
    assert ok and (np.linalg.eigvalsh(base).min() > 0) == (float(delta_w) == 0.0)
    assert np.linalg.eigvalsh(base + float(delta_w) * np.eye(n_x)).min() > 0
    r1, r2 = np.random.default_rng(4).standard_normal(n_x), np.random.default_rng(5).standard_normal(m)
    dx, dl = ric.solve_weighted(factors, jac, weights, jnp.asarray(r1), jnp.asarray(r2))
    big = np.block([[hess + np.diag(np.asarray(sigma)) + float(delta_w) * np.eye(n_x), np.asarray(jac).T],
                    [np.asarray(jac), -np.diag(1.0 / np.asarray(weights))]])
    expected = np.linalg.solve(big, np.concatenate([r1, r2]))
    np.testing.assert_allclose(np.concatenate([dx, dl]), expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("name", ["mould_fungicide", "epidemic", "rocket_landing"])
def test_real_points_against_the_dense_path(name):
    """At a point of the published NLP (rocket landing: six terminal rows), the stage-wise and the dense barrier
    problem agree: values, gradient, Jacobian, Hessian products, ``delta_w`` and the Newton step."""
    system = load(name)
    problem = ScaledProblem.from_nlp(transcribe(system, SingleShooting(intervals=100, integrator=Heun())))
    data = default_data(system)
    stagewise, dense = Layout(problem, "riccati"), Layout(problem, "dense")
    rng = np.random.default_rng(0)
    w0 = jnp.asarray(problem.to_w(transcribe(system, SingleShooting(intervals=100, integrator=Heun()))
                                  .initial_guess(data)))
    x = dense.start(w0 * (1.0 + 0.05 * rng.standard_normal(w0.shape)), data)
    lam, row_scale = jnp.asarray(rng.standard_normal(dense.m)), jnp.asarray(rng.uniform(0.5, 1.0, dense.m))
    sigma = jnp.asarray(rng.uniform(0.0, 2.0, dense.n_x))

    def point(layout):
        y = layout.multipliers(lam, 0.7, row_scale)
        return layout.point(x, *layout.derivatives(x[:layout.n], y, data), 0.7, row_scale)

    ps, pd = jax.jit(lambda: point(stagewise))(), jax.jit(lambda: point(dense))()
    for field in ("f", "grad", "g", "jac"):
        np.testing.assert_allclose(getattr(ps, field), getattr(pd, field), rtol=1e-12, atol=1e-12, err_msg=field)
    v = jnp.asarray(rng.standard_normal(dense.n_x))
    scale = np.abs(np.asarray(pd.hess)).max()
    np.testing.assert_allclose(stagewise.riccati.hvp(ps.hess, v), pd.hess @ v, rtol=1e-11, atol=1e-11 * scale)

    ric = stagewise.riccati
    fs, dws, oks = jax.jit(ric.factorize_with_inertia)(ps.hess, sigma, ps.jac, 1e-2, 0.0)
    fd, dwd, okd = jax.jit(kkt.factorize_with_inertia)(pd.hess, sigma, pd.jac, 1e-2, 0.0)
    assert bool(oks) and bool(okd) and float(dws) == float(dwd)
    m, n_x = dense.m, dense.n_x
    big = np.block([[np.asarray(pd.hess) + np.diag(np.asarray(sigma)) + float(dws) * np.eye(n_x), np.asarray(pd.jac).T],
                    [np.asarray(pd.jac), -float(fs.delta_c) * np.eye(m)]])
    assert _inertia(big) == (n_x, m)
    r1, r2 = -ps.grad, -ps.g
    step_s = np.concatenate(jax.jit(ric.solve)(fs, ps.jac, r1, r2))
    step_d = np.concatenate(jax.jit(kkt.solve)(fd, pd.jac, r1, r2))
    np.testing.assert_allclose(step_s, step_d, rtol=1e-10, atol=1e-10 * np.abs(step_d).max())


def test_a_vmapped_batch_agrees_with_ipopt():
    """End to end (the loop, restoration-free here, the line search's second-order correction): ``solve_batch``'s
    default on a CPU vmaps the stage-wise solve; each member as IPOPT solves it."""
    system, transcription = load("van_der_pol"), SingleShooting(intervals=100, integrator=Heun())
    solver = InteriorPoint()
    nlp = transcribe(system, transcription)
    assert solver.kkt_method(nlp, vmapped=True) == "riccati" and solver.kkt_method(nlp) == "dense"
    if jax.default_backend() == "cpu":
        assert solver.batch_strategy(nlp) == "vmap" and InteriorPoint(kkt="dense").batch_strategy(nlp) == "map"
    x0 = np.asarray(system.arrays()["x0"], float)[None, :] * np.array([[1.0], [1.05]])
    batch = solve_batch(system, transcription, solver, x0=x0)
    for member, x in zip(batch, x0):
        ref = solve(system, transcription, Ipopt(), x0=x, resimulate=False)
        assert member.converged and ref.converged and member.iterations <= 2 * ref.iterations
        assert abs(member.cost - ref.cost) <= 1e-8 * abs(ref.cost)
        # The report and the trajectory come from batched programs (one dispatch for all members): each member's
        # own, as a single solve's Solution has them.
        np.testing.assert_allclose(member.states, ref.states, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(member.controls, ref.controls, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(member.interval_errors, ref.interval_errors, rtol=1e-3, atol=1e-12)
        assert member.constraint_violation <= 1e-8 and member.defect == pytest.approx(ref.defect, abs=1e-8)


def test_kkt_riccati_refuses_an_nlp_without_stages():
    from myriad.runtime import Trapezoidal

    nlp = transcribe(load("van_der_pol"), Trapezoidal(intervals=10))
    problem = ScaledProblem.from_nlp(nlp)
    with pytest.raises(ValueError, match="stage-wise"):
        Layout(problem, "riccati")
    assert not Layout.stagewise(problem) and InteriorPoint().kkt_method(nlp, vmapped=True) == "banded"
