r"""The primal-dual Newton system, with inertia correction, by two dense Cholesky factorisations.

The step solves (Wächter & Biegler 2006, eq. 13, bound multipliers eliminated)

.. math::
    K \begin{pmatrix} d_x \\ d_\lambda \end{pmatrix} = \begin{pmatrix} r_1 \\ r_2 \end{pmatrix},\qquad
    K = \begin{pmatrix} H_s & A^\top \\ A & -\delta_c I \end{pmatrix},\quad H_s = W + \Sigma + \delta_w I,

and is a descent step only when ``K`` has inertia ``(n_x, m, 0)``. JAX has no symmetric indefinite (LDL^T)
factorisation, so the inertia is certified through Cholesky factorisations of an equivalent system instead: adding
``rho A^T`` times the second block row to the first (an exact row operation: the solution is unchanged),

.. math::
    H_\rho = H_s + \rho A^\top A, \qquad S = (1 - \rho\delta_c)\, A H_\rho^{-1} A^\top + \delta_c I,

and ``d_lambda = S^{-1}(A H_rho^{-1} r_1' - r_2)``, ``d_x = H_rho^{-1}(r_1' - (1 - rho delta_c) A^T d_lambda)`` with
``r_1' = r_1 + rho A^T r_2``. If both Cholesky factorisations succeed, ``K`` has the right inertia: ``H_rho > 0``
makes the reduced Hessian ``Z^T H_s Z`` positive definite, and ``S > 0`` means ``A`` has full row rank (or
``delta_c > 0``, when ``H_s + A^T A / delta_c > 0`` follows from ``rho <= 1 / delta_c``). The converse needs ``rho``
large enough (Debreu's lemma), so a failed ``H_rho`` is retried with ``rho`` 10^4 and 10^8 times larger before
``delta_w`` grows. One step of iterative refinement on ``K`` itself restores the accuracy that a large ``rho`` costs.
A large ``rho`` never certifies a wrong inertia (on the null space of ``A``, ``H_rho`` is ``H_s`` whatever ``rho``);
too small a ``rho`` makes ``delta_w`` grow where IPOPT's true inertia would not: with 10^4 as the last retry, Rocket
Landing's steps were regularised by ``delta_w`` 10^4-10^5 where IPOPT used 10^1-10^3, and it took 109 iterations
against IPOPT's 53 (51 with the 10^8 retry).

Cost: one ``n_x x n_x`` and one ``m x m`` Cholesky per attempt, dense. Fine for single shooting (``n_x`` about 100-200);
collocation's ``n_x`` of 500-1000 costs ``O(n_x^3)`` per iteration and the block-banded structure is not exploited.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve

__all__ = ["Factors", "factorize_with_inertia", "solve"]

# IPOPT's defaults (first_hessian_perturbation, min/max_hessian_perturbation, perturb_inc_fact(_first),
# perturb_dec_fact, jacobian_regularization_value and _exponent).
DELTA_W_FIRST, DELTA_W_MIN, DELTA_W_MAX = 1e-4, 1e-20, 1e40
GROW_FIRST, GROW, SHRINK = 100.0, 8.0, 1.0 / 3.0
DELTA_C_BAR, DELTA_C_EXPONENT = 1e-8, 0.25
RHO_RETRY, RHO_RETRIES = 1e4, 2  # H_rho is retried at rho0 * 1e4 and rho0 * 1e8
MAX_ATTEMPTS = 60


class Factors(NamedTuple):
    """The factorised system: enough to solve with any right-hand side (the step and the second-order correction)."""

    h_s: jax.Array  # H_s (for the refinement residual)
    chol_h: jax.Array  # lower Cholesky factor of H_rho
    hinv_at: jax.Array  # H_rho^{-1} A^T
    chol_s: jax.Array  # lower Cholesky factor of S
    rho: jax.Array
    delta_c: jax.Array


def _cholesky(matrix) -> tuple[jax.Array, jax.Array]:
    """``(lower factor, positive definite)``; the identity in place of a failed factor (NaN-free shapes).

    NOTE: later solves use the factor one right-hand side at a time: XLA:CPU's triangular solve with a matrix of
    right-hand sides (hence also ``jnp.linalg.inv``) took 17-32 ms at n = 101 (measured), one with a vector 0.05 ms.
    """
    k = matrix.shape[0]
    chol = jnp.linalg.cholesky(0.5 * (matrix + matrix.T))
    ok = jnp.all(jnp.isfinite(chol))
    return jnp.where(ok, chol, jnp.eye(k, dtype=matrix.dtype)), ok


def _factorize(h_s, jac, rho, delta_c) -> tuple[Factors, jax.Array, jax.Array]:
    """Factors and (H_rho positive definite, S positive definite)."""
    m = jac.shape[0]
    chol_h, ok_h = _cholesky(h_s + rho * (jac.T @ jac) if m else h_s)
    if m:
        # m right-hand sides: few for shooting; collocation's many rows make this the dearest part (see above).
        hinv_at = cho_solve((chol_h, True), jac.T)
        chol_s, ok_s = _cholesky((1.0 - rho * delta_c) * (jac @ hinv_at) + delta_c * jnp.eye(m, dtype=h_s.dtype))
    else:
        hinv_at, chol_s, ok_s = jnp.zeros((h_s.shape[0], 0), h_s.dtype), jnp.zeros((0, 0), h_s.dtype), jnp.array(True)
    return Factors(h_s, chol_h, hinv_at, chol_s, rho, delta_c), ok_h, ok_s


def _solve_once(f: Factors, jac, r1, r2):
    m = jac.shape[0]
    if not m:
        return cho_solve((f.chol_h, True), r1), r2
    beta = 1.0 - f.rho * f.delta_c
    t = cho_solve((f.chol_h, True), r1 + f.rho * (jac.T @ r2))
    dl = cho_solve((f.chol_s, True), jac @ t - r2)
    return t - beta * (f.hinv_at @ dl), dl


def solve(f: Factors, jac: jax.Array, r1: jax.Array, r2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(d_x, d_lambda)`` solving ``K (d_x, d_lambda) = (r1, r2)``, with one step of iterative refinement on ``K``."""
    dx, dl = _solve_once(f, jac, r1, r2)
    res1 = f.h_s @ dx + jac.T @ dl - r1
    res2 = jac @ dx - f.delta_c * dl - r2
    cx, cl = _solve_once(f, jac, res1, res2)
    return dx - cx, dl - cl


class _Attempt(NamedTuple):
    k: jax.Array
    delta_w: jax.Array
    delta_c: jax.Array
    rho: jax.Array
    done: jax.Array
    factors: Factors


def factorize_with_inertia(
    hess: jax.Array, sigma: jax.Array, jac: jax.Array, mu: jax.Array, delta_w_last: jax.Array
) -> tuple[Factors, jax.Array, jax.Array]:
    """IPOPT's inertia correction (Wächter & Biegler 2006, Algorithm IC) on the certificate of the module docstring.

    Tries ``delta_w = 0`` first (at ``rho``, ``10^4 rho`` and ``10^8 rho``), then ``delta_w`` from ``1e-4`` (or a
    third of the last iteration's), growing 100x (8x after a previous correction) up to ``1e40``; a rank-deficient
    ``A`` (``S`` fails while ``H_rho`` holds) gets ``delta_c = 1e-8 mu^(1/4)`` at the same ``delta_w``.

    Returns:
        ``(factors, delta_w, ok)``; ``ok`` is False when no ``delta_w`` up to the maximum gave the right inertia.
    """
    n_x, m = hess.shape[0], jac.shape[0]
    dtype = hess.dtype
    base = hess + jnp.diag(sigma)
    # rho: the Hessian's magnitude over the largest squared row norm of A, so that rho A^T A can dominate it.
    row_sq = jnp.max(jnp.sum(jac * jac, axis=1), initial=0.0) if m else jnp.zeros((), dtype)
    rho0 = (1.0 + jnp.max(jnp.abs(hess), initial=0.0)) / jnp.maximum(row_sq, 1e-12) if m else jnp.zeros((), dtype)
    # Attempts 0..RHO_RETRIES keep delta_w = 0 (rho, then larger); no retries for rho when there is no A.
    first_grown = 1 + RHO_RETRIES if m else 1

    def schedule(k, delta_w):
        """delta_w for attempt k, after delta_w at attempt k - 1."""
        start = jnp.where(delta_w_last > 0, jnp.maximum(DELTA_W_MIN, SHRINK * delta_w_last), DELTA_W_FIRST)
        grown = delta_w * jnp.where(delta_w_last > 0, GROW, GROW_FIRST)
        return jnp.where(k < first_grown, 0.0, jnp.where(k == first_grown, start, grown))

    def attempt(a: _Attempt) -> _Attempt:
        rho = rho0 * RHO_RETRY ** jnp.minimum(a.k, RHO_RETRIES).astype(dtype)
        rho = jnp.where(a.delta_c > 0, jnp.minimum(rho, 1e-2 / jnp.maximum(a.delta_c, 1e-300)), rho)
        factors, ok_h, ok_s = _factorize(base + a.delta_w * jnp.eye(n_x, dtype=dtype), jac, rho, a.delta_c)
        # S fails alone: A is (numerically) rank deficient; regularise it and retry the same delta_w.
        rank_deficient = ok_h & ~ok_s & (a.delta_c == 0)
        delta_c = jnp.where(rank_deficient, DELTA_C_BAR * mu**DELTA_C_EXPONENT, a.delta_c)
        done = ok_h & ok_s
        advance = ~done & ~rank_deficient
        k = jnp.where(advance, a.k + 1, a.k)
        delta_w = jnp.where(advance, schedule(a.k + 1, a.delta_w), a.delta_w)
        return _Attempt(k, delta_w, delta_c, rho, done, factors)

    def keep_trying(a: _Attempt):
        return ~a.done & (a.k < MAX_ATTEMPTS) & (a.delta_w <= DELTA_W_MAX)

    zero = jnp.zeros((), dtype)
    eye = jnp.eye(n_x, dtype=dtype)
    init_factors = Factors(eye, eye, jnp.zeros((n_x, m), dtype), jnp.eye(m, dtype=dtype), zero, zero)
    first = _Attempt(jnp.array(0), zero, zero, zero, jnp.array(False), init_factors)
    final = jax.lax.while_loop(keep_trying, attempt, first)
    return final.factors, final.delta_w, final.done
