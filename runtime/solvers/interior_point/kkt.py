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
too small a ``rho`` makes ``delta_w`` grow where IPOPT's true inertia would not (Rocket Landing: the notes).

Cost: one ``n_x x n_x`` and one ``m x m`` Cholesky per attempt, dense. Fine for single shooting (``n_x`` about 100-200);
collocation's ``n_x`` of 500-1000 costs ``O(n_x^3)`` per iteration and the block-banded structure is not exploited.

**Many rows (``2 m >= n_x``: collocation, multiple shooting): the null-space method.** There the certificate above
can fail where the inertia is right (HIV Treatment: the solver-code note), and ``delta_w`` grows needlessly. With a
QR factorisation ``A^T = [Q_1 Z] [R; 0]`` (``A`` of full row rank), ``K`` has inertia ``(n_x, m, 0)`` exactly when
``Z^T H_s Z`` is positive definite, and the step is

.. math::
    R^\top p = r_2,\quad Z^\top H_s Z\, q = Z^\top (r_1 - H_s Q_1 p),\quad d_x = Q_1 p + Z q,\quad
    R\, d_\lambda = Q_1^\top (r_1 - H_s d_x).

``Z^T (H + Sigma) Z`` is formed once per iteration and each attempt adds ``delta_w I`` to it (``Z`` is orthonormal), so
an attempt is one ``(n_x - m)``-sized Cholesky. An ``A`` with a (numerically) dependent row falls back to the
certificate above, whose ``delta_c`` handles it. For few rows the reduced Hessian costs more than ``H_rho`` (about
``n_x^3`` against ``n_x^3 / 3``), so single shooting keeps the certificate.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve, solve_triangular

from .rules import certified, regularized

__all__ = ["Factors", "cholesky", "factorize_with_inertia", "regularized_cholesky", "solve"]

# A is treated as rank deficient (null-space method off) when |R_ii| < RANK_TOL max(1, max |R_jj|).
RANK_TOL = 1e-10


class Factors(NamedTuple):
    """The factorised system, for any right-hand side: one of two methods holds (``nullspace``), the other's arrays
    are placeholders (empty null-space arrays for few rows: :func:`uses_nullspace`)."""

    h_s: jax.Array  # H_s (for the refinement residual)
    chol_h: jax.Array  # lower Cholesky factor of H_rho
    hinv_at: jax.Array  # H_rho^{-1} A^T
    chol_s: jax.Array  # lower Cholesky factor of S
    rho: jax.Array
    delta_c: jax.Array
    nullspace: jax.Array  # solved by the null-space method
    q1: jax.Array  # (n_x, m) range of A^T
    z: jax.Array  # (n_x, n_x - m) null space of A
    r: jax.Array  # (m, m) upper triangular, A^T = Q_1 R
    chol_red: jax.Array  # lower Cholesky factor of Z^T H_s Z


def uses_nullspace(n_x: int, m: int) -> bool:
    """The null-space method for problems with many rows (see the module docstring)."""
    return m > 0 and 2 * m >= n_x


def _placeholders(n_x: int, m: int, dtype) -> tuple:
    k = n_x - m if uses_nullspace(n_x, m) else 0
    mm = m if uses_nullspace(n_x, m) else 0
    return (jnp.zeros((n_x, mm), dtype), jnp.zeros((n_x, k), dtype), jnp.zeros((mm, mm), dtype),
            jnp.zeros((k, k), dtype))


def cholesky(matrix) -> tuple[jax.Array, jax.Array]:
    """``(lower factor, positive definite)``; the identity in place of a failed factor (NaN-free shapes).

    NOTE: later solves use the factor one right-hand side at a time: XLA:CPU's triangular solve with a matrix of
    right-hand sides (hence also ``jnp.linalg.inv``) is far slower (the solver-code note).
    """
    k = matrix.shape[0]
    chol = jnp.linalg.cholesky(0.5 * (matrix + matrix.T))
    ok = jnp.all(jnp.isfinite(chol))
    return jnp.where(ok, chol, jnp.eye(k, dtype=matrix.dtype)), ok


def _factorize(h_s, jac, rho, delta_c) -> tuple[Factors, jax.Array, jax.Array]:
    """Factors (the certificate's) and (H_rho positive definite, S positive definite)."""
    n_x, m = h_s.shape[0], jac.shape[0]
    chol_h, ok_h = cholesky(h_s + rho * (jac.T @ jac) if m else h_s)
    if m:
        # m right-hand sides: few for shooting; collocation's many rows make this the dearest part (see above).
        hinv_at = cho_solve((chol_h, True), jac.T)
        chol_s, ok_s = cholesky((1.0 - rho * delta_c) * (jac @ hinv_at) + delta_c * jnp.eye(m, dtype=h_s.dtype))
    else:
        hinv_at, chol_s, ok_s = jnp.zeros((h_s.shape[0], 0), h_s.dtype), jnp.zeros((0, 0), h_s.dtype), jnp.array(True)
    return Factors(h_s, chol_h, hinv_at, chol_s, rho, delta_c, jnp.array(False),
                   *_placeholders(n_x, m, h_s.dtype)), ok_h, ok_s


def _solve_nullspace(f: Factors, r1, r2):
    p = solve_triangular(f.r, r2, trans="T", lower=False)
    y = f.q1 @ p
    q = cho_solve((f.chol_red, True), f.z.T @ (r1 - f.h_s @ y))
    dx = y + f.z @ q
    return dx, solve_triangular(f.r, f.q1.T @ (r1 - f.h_s @ dx), lower=False)


def _solve_once(f: Factors, jac, r1, r2):
    if uses_nullspace(f.h_s.shape[0], jac.shape[0]):
        return jax.lax.cond(f.nullspace, lambda: _solve_nullspace(f, r1, r2), lambda: _solve_certified(f, jac, r1, r2))
    return _solve_certified(f, jac, r1, r2)


def _solve_certified(f: Factors, jac, r1, r2):
    m = jac.shape[0]
    if not m:
        return cho_solve((f.chol_h, True), r1), r2
    beta = 1.0 - f.rho * f.delta_c
    t = cho_solve((f.chol_h, True), r1 + f.rho * (jac.T @ r2))
    dl = cho_solve((f.chol_s, True), jac @ t - r2)
    return t - beta * (f.hinv_at @ dl), dl


def solve(f: Factors, jac: jax.Array, r1: jax.Array, r2: jax.Array, presolved: bool = False
          ) -> tuple[jax.Array, jax.Array]:
    """``(d_x, d_lambda)`` solving ``K (d_x, d_lambda) = (r1, r2)``, with one step of iterative refinement on ``K``.
    ``presolved`` is the stage-wise method's (``riccati.py``) and changes nothing here: a dense solve is two
    triangular solves."""
    dx, dl = _solve_once(f, jac, r1, r2)
    res1 = f.h_s @ dx + jac.T @ dl - r1
    res2 = jac @ dx - f.delta_c * dl - r2
    cx, cl = _solve_once(f, jac, res1, res2)
    return dx - cx, dl - cl


def factorize_with_inertia(
    hess: jax.Array, sigma: jax.Array, jac: jax.Array, mu: jax.Array, delta_w_last: jax.Array, r1: Any = None
) -> tuple[Factors, jax.Array, jax.Array]:
    """IPOPT's inertia correction (:func:`~.rules.certified`), by the null-space method for many rows and by the
    certificate of the module docstring otherwise: ``(factors, delta_w, ok)``, ``ok`` False when no ``delta_w`` up to
    the maximum gave the right inertia. ``r1`` is the stage-wise method's (``riccati.py``) and is not used here."""
    del r1
    base = hess + jnp.diag(sigma)
    n_x, m = hess.shape[0], jac.shape[0]
    if not uses_nullspace(n_x, m):
        return _certified(base, hess, jac, mu, delta_w_last)
    q, r_full = jnp.linalg.qr(jac.T, mode="complete")
    diag = jnp.abs(jnp.diagonal(r_full))
    full_rank = jnp.all(jnp.isfinite(r_full)) & (jnp.min(diag) > RANK_TOL * jnp.maximum(1.0, jnp.max(diag)))
    return jax.lax.cond(full_rank, lambda: _nullspace(base, q, r_full[:m], m, delta_w_last),
                        lambda: _certified(base, hess, jac, mu, delta_w_last))


def regularized_cholesky(matrix, delta_w_last) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(lower Cholesky factor of matrix + delta_w I, delta_w, ok)`` for the least ``delta_w`` of IPOPT's schedule
    (:func:`~.rules.regularized`: the null-space method's reduced Hessian, the restoration phase's system)."""
    eye = jnp.eye(matrix.shape[0], dtype=matrix.dtype)
    return regularized(lambda delta_w: cholesky(matrix + delta_w * eye), delta_w_last, matrix.dtype, eye)


def _nullspace(base, q, r, m, delta_w_last) -> tuple[Factors, jax.Array, jax.Array]:
    """The attempts on ``Z^T H_s Z = Z^T (H + Sigma) Z + delta_w I``: one Cholesky of size ``n_x - m`` each."""
    n_x, dtype = base.shape[0], base.dtype
    q1, z = q[:, :m], q[:, m:]
    chol, delta_w, done = regularized_cholesky(z.T @ base @ z, delta_w_last)
    zero = jnp.zeros((), dtype)
    eye = jnp.eye(n_x, dtype=dtype)
    factors = Factors(base + delta_w * eye, eye, jnp.zeros((n_x, m), dtype), jnp.eye(m, dtype=dtype), zero, zero,
                      jnp.array(True), q1, z, r, chol)
    return factors, delta_w, done


def _certified(base, hess, jac, mu, delta_w_last) -> tuple[Factors, jax.Array, jax.Array]:
    """The attempts on the Cholesky certificate of the module docstring (:func:`~.rules.certified`)."""
    n_x, m = hess.shape[0], jac.shape[0]
    dtype = hess.dtype
    # rho: the Hessian's magnitude over the largest squared row norm of A, so that rho A^T A can dominate it.
    row_sq = jnp.max(jnp.sum(jac * jac, axis=1), initial=0.0) if m else jnp.zeros((), dtype)
    rho0 = (1.0 + jnp.max(jnp.abs(hess), initial=0.0)) / jnp.maximum(row_sq, 1e-12) if m else jnp.zeros((), dtype)

    def factorize(k, delta_w, rho, delta_c):
        return _factorize(base + delta_w * jnp.eye(n_x, dtype=dtype), jac, rho, delta_c)

    zero = jnp.zeros((), dtype)
    eye = jnp.eye(n_x, dtype=dtype)
    init = Factors(eye, eye, jnp.zeros((n_x, m), dtype), jnp.eye(m, dtype=dtype), zero, zero, jnp.array(False),
                   *_placeholders(n_x, m, dtype))
    return certified(factorize, rho0, m, mu, delta_w_last, dtype, init)
