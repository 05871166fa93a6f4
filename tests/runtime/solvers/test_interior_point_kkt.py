"""The interior point's Newton system (``interior_point.kkt``): the null-space method for many rows against dense
linear algebra, its inertia decisions against the reduced Hessian's eigenvalues, and a collocation NLP it unblocked."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import Trapezoidal, load, solve
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.solvers.interior_point import kkt, rules

jax.config.update("jax_enable_x64", True)


def _problem(seed: int, n: int, m: int, negative: float):
    """H symmetric with a negative-definite part of size ``negative`` on a random subspace, A random (full rank)."""
    rng = np.random.default_rng(seed)
    basis, _ = np.linalg.qr(rng.standard_normal((n, n)))
    eigenvalues = np.concatenate([np.full(int(n * 0.3), -negative), rng.uniform(0.5, 2.0, n - int(n * 0.3))])
    hess = basis @ np.diag(eigenvalues) @ basis.T
    return jnp.asarray(hess), jnp.asarray(rng.uniform(0.0, 1.0, n)), jnp.asarray(rng.standard_normal((m, n)))


def _reduced_min_eigenvalue(hess, sigma, jac):
    q, _ = np.linalg.qr(np.asarray(jac).T, mode="complete")
    z = q[:, jac.shape[0]:]
    return np.linalg.eigvalsh(z.T @ (np.asarray(hess) + np.diag(np.asarray(sigma))) @ z).min()


@pytest.mark.slow
@pytest.mark.parametrize("negative", [0.1, 50.0])
def test_nullspace_step_solves_the_kkt_system(negative):
    n, m = 30, 20
    assert kkt.uses_nullspace(n, m) and not kkt.uses_nullspace(n, 5)
    hess, sigma, jac = _problem(0, n, m, negative)
    factors, delta_w, ok = jax.jit(kkt.factorize_with_inertia)(hess, sigma, jac, 1e-3, 0.0)
    assert ok and bool(factors.nullspace)
    # Inertia (n, m, 0) iff the reduced Hessian is positive definite: delta_w is 0 exactly when it already is.
    reduced = _reduced_min_eigenvalue(hess, sigma, jac)
    if reduced > 0:
        assert float(delta_w) == 0.0
    else:
        assert float(delta_w) + reduced > 0 and float(delta_w) / rules.GROW_FIRST + reduced <= 0  # the schedule's first
    rng = np.random.default_rng(1)
    r1, r2 = jnp.asarray(rng.standard_normal(n)), jnp.asarray(rng.standard_normal(m))
    dx, dl = kkt.solve(factors, jac, r1, r2)
    big = np.block([[np.asarray(factors.h_s), np.asarray(jac).T], [np.asarray(jac), np.zeros((m, m))]])
    expected = np.linalg.solve(big, np.concatenate([r1, r2]))
    np.testing.assert_allclose(np.concatenate([dx, dl]), expected, rtol=1e-10, atol=1e-10)


def test_a_rank_deficient_jacobian_falls_back_to_the_certificate():
    n, m = 30, 20
    hess, sigma, jac = _problem(2, n, m, 0.1)
    jac = jac.at[-1].set(jac[0])  # a repeated row
    factors, _, ok = jax.jit(kkt.factorize_with_inertia)(hess, sigma, jac, 1e-3, 0.0)
    assert ok and not bool(factors.nullspace) and float(factors.delta_c) > 0
    r1 = jnp.ones(n)
    r2 = jac @ jnp.linspace(0.0, 1.0, n)  # consistent: the repeated rows agree
    dx, _ = kkt.solve(factors, jac, r1, r2)
    np.testing.assert_allclose(jac @ dx, r2, atol=1e-6)


@pytest.mark.slow
def test_hiv_treatment_on_collocation_converges_like_ipopt():
    # Before the null-space method: the 3000-iteration limit at -818.878, the certificate having grown delta_w to
    # 1e2-1e4 where the reduced Hessian needed 0-1.
    system, transcription = load("hiv_treatment"), Trapezoidal(intervals=50)
    ref = solve(system, transcription, Ipopt(), resimulate=False)
    ip = solve(system, transcription, InteriorPoint(), resimulate=False)
    assert ref.converged and ip.converged
    assert abs(ip.cost - ref.cost) <= 1e-8 * abs(ref.cost)
    assert ip.iterations <= 2 * ref.iterations
