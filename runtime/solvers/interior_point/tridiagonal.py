r"""Symmetric block-tridiagonal matrices: a factorisation that counts the inertia, and solves, in ``O(K s^3)``.

The matrix has diagonal blocks ``D_k`` (``K`` of them, each ``s x s``, symmetric) and couplings ``E_k =
M[block k, block k + 1]``. Block Gaussian elimination is a congruence, so by Sylvester's law the matrix's inertia is
the sum of the pivot blocks' inertias; each pivot is inverted by :func:`pivot`.

**Partitioned elimination** (why: a sequential sweep is one ``lax.scan`` step per block, and on a CPU such a step
costs its kernels' launches, ~8 us, whatever the block's arithmetic; 1600 blocks took 12.5 ms where the arithmetic
alone, vmapped, took 0.3 ms). Every ``L``-th block is a separator; the ``L - 1`` blocks between two separators (a
chunk) are eliminated first, all chunks at once (``vmap``) in ``L - 1`` steps, carrying the fill towards the chunk's
left separator; what is left is a block-tridiagonal system on the ``P + 1`` separators, eliminated in turn. Depth
``~2 sqrt(K)`` instead of ``K``; the same arithmetic, about twice over. The elimination order is a permutation
(interiors, then separators), so the counted inertia is still exact.

**Pivots.** A pivot ``S = [P Q^T; Q R]`` (``a`` leading rows, the stage's variables) is first inverted from two
Cholesky factors, of ``P`` and of ``Q P^{-1} Q^T - R``: when both exist with pivots clear of zero, ``S``'s inertia is
``(a, s - a, 0)`` (Haynsworth) with no eigendecomposition (a LAPACK call of ~10 us against the unrolled factors'
fraction of that). Where a pivot is not so certified, the whole factorisation is redone with eigendecompositions
(``exact``), which count any inertia: one copy of each kind of pivot in the program (compile time).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from . import blocks as bl

__all__ = ["Factors", "factor", "solve", "pivot", "stride"]

# An eigenvalue of an (equilibrated) pivot block is zero below this times its largest magnitude; a certified
# Cholesky pivot must exceed it relative to its diagonal entry.
ZERO_PIVOT = 1e-13
# Below this many blocks the elimination is sequential (partitioning gains nothing).
PARTITION_MIN = 48


def stride(k: int) -> int:
    """The separators' spacing ``L`` for ``k`` blocks (0: sequential): about ``sqrt(k)``, balancing the chunks'
    depth against the separators'."""
    return 0 if k < PARTITION_MIN else max(2, int(round(k ** 0.5)))


# ---- pivots ------------------------------------------------------------------------------------------------------

def _eigen_inverse(sym) -> tuple[jax.Array, jax.Array]:
    """``(inverse, inertia counts (3,))`` by the eigendecomposition of ``D S D``, ``D`` giving each row unit largest
    magnitude (a congruence: same inertia). Why scaled: a variable near its bound puts ``Sigma ~ 1e10`` in a block
    whose rows' eigenvalues are ``~ -1 / Sigma``; an eigensolver resolves ``eps ||S||``, so unscaled they would read
    as zero. A zero eigenvalue's term is left out, so the inverse stays finite (its factorisation is rejected)."""
    d = _equilibration(sym)
    lam, vec = jnp.linalg.eigh(d[:, None] * sym * d[None, :])
    tol = ZERO_PIVOT * jnp.max(jnp.abs(lam), initial=0.0)
    nonzero = jnp.abs(lam) > tol
    inv_lam = jnp.where(nonzero, 1.0 / jnp.where(nonzero, lam, 1.0), 0.0)
    inv = d[:, None] * ((vec * inv_lam) @ vec.T) * d[None, :]
    return inv, jnp.stack([jnp.sum(lam > tol), jnp.sum(lam < -tol), jnp.sum(~nonzero)])


def _equilibration(sym) -> jax.Array:
    """``D`` (diagonal, as a vector) giving each row of ``D S D`` unit largest magnitude."""
    big = jnp.max(jnp.abs(sym), axis=-1)
    return 1.0 / jnp.sqrt(jnp.where(big > 0.0, big, 1.0))


def _cholesky_inverse(sym, a: int) -> tuple[jax.Array, jax.Array]:
    """``(S^{-1}, certified)`` from Cholesky factors of ``P`` and ``M = Q P^{-1} Q^T - R`` of the equilibrated
    ``D S D`` (the module docstring; equilibrated for the reason :func:`_eigen_inverse` gives)."""
    scale = _equilibration(sym)
    inv, ok = _cholesky_inverse_scaled(scale[:, None] * sym * scale[None, :], a)
    return scale[:, None] * inv * scale[None, :], ok


def _cholesky_inverse_scaled(sym, a: int) -> tuple[jax.Array, jax.Array]:
    """Two ways to two Cholesky factors, either of which certifies the inertia ``(a, b, 0)``: the rows first (``-R``
    and ``P - Q^T R^{-1} Q``: rows whose block is negative definite, the common case after the previous stage's
    elimination, certified where the variables are convex on the rows' null space only), or the variables first
    after a shift (:func:`_shifted`: rows with a singular block, such as a chunk's first stage's). Why only two:
    each is unrolled code in every copy of the elimination (a third, the plain variables-first order, cost 2 s of
    XLA compile time and is the shift's ``rho = 0``)."""
    s = sym.shape[0]
    if a in (0, s):  # definite alone: positive (all variables) or negative (all rows)
        sign = 1.0 if a else -1.0
        chol, ok = bl.cholesky_array(sign * sym)
        return sign * bl.cho_solve_array(chol, jnp.eye(s, dtype=sym.dtype)), ok & _clear(chol, sign * sym)
    inv_rows, ok_rows = _rows_first(sym, a)
    inv_shift, ok_shift = _shifted(sym, a)
    return jnp.where(ok_rows, inv_rows, inv_shift), ok_rows | ok_shift


def _shifted(sym, a: int) -> tuple[jax.Array, jax.Array]:
    """The variables first after the congruence ``C^T S C``, ``C = [I 0; rho Q I]``: its leading block is ``P + 2 rho
    Q^T Q + rho^2 Q^T R Q``, positive definite for a large ``rho`` wherever ``P`` is on the rows' null space and
    ``R`` is small (a chunk's first stage, which no elimination has updated yet: ``R = -delta_c``). A congruence keeps
    the inertia whatever ``rho``; ``rho`` only trades accuracy (the step's refinement)."""
    q, r = sym[a:, :a], sym[a:, a:]
    # 2 rho - rho^2 |R| >= rho: the shift adds at least rho Q^T Q (and rho = 0 keeps the plain variables-first order)
    rho = jnp.minimum(10.0 / jnp.maximum(jnp.max(jnp.sum(q * q, axis=1), initial=0.0), 1e-12),
                      1.0 / jnp.maximum(jnp.max(jnp.abs(r), initial=0.0), 1e-12))
    c = jnp.eye(sym.shape[0], dtype=sym.dtype).at[a:, :a].set(rho * q)
    inv_t, ok = _vars_first(c.T @ sym @ c, a)
    return c @ inv_t @ c.T, ok


def _clear(chol, mat) -> jax.Array:
    """Every Cholesky pivot squared above ``ZERO_PIVOT`` times its diagonal entry (no near-singular pivot)."""
    piv = jnp.diagonal(chol) ** 2 / jnp.maximum(jnp.abs(jnp.diagonal(mat)), 1e-300)
    return jnp.min(piv, initial=1.0) > ZERO_PIVOT


def _rows_first(sym, a: int) -> tuple[jax.Array, jax.Array]:
    p, q, r = sym[:a, :a], sym[a:, :a], sym[a:, a:]
    dtype = sym.dtype
    chol_n, ok_n = bl.cholesky_array(-r)
    k = bl.cho_solve_array(chol_n, q)  # N^{-1} Q, N = -R
    hat = p + q.T @ k
    chol_h, ok_h = bl.cholesky_array(hat)
    f = bl.cho_solve_array(chol_h, k.T)  # hat^{-1} Q^T N^{-1}
    h_inv = bl.cho_solve_array(chol_h, jnp.eye(a, dtype=dtype))
    n_inv = bl.cho_solve_array(chol_n, jnp.eye(r.shape[0], dtype=dtype))
    inv = jnp.concatenate([jnp.concatenate([h_inv, f], axis=1), jnp.concatenate([f.T, k @ f - n_inv], axis=1)],
                          axis=0)
    return inv, ok_n & ok_h & _clear(chol_n, -r) & _clear(chol_h, hat)


def _vars_first(sym, a: int) -> tuple[jax.Array, jax.Array]:
    p, q, r = sym[:a, :a], sym[a:, :a], sym[a:, a:]
    dtype = sym.dtype
    chol_p, ok_p = bl.cholesky_array(p)
    g = bl.cho_solve_array(chol_p, q.T)  # P^{-1} Q^T
    m = q @ g - r
    chol_m, ok_m = bl.cholesky_array(m)
    m_inv = bl.cho_solve_array(chol_m, jnp.eye(r.shape[0], dtype=dtype))
    gm = g @ m_inv
    p_inv = bl.cho_solve_array(chol_p, jnp.eye(a, dtype=dtype))
    inv = jnp.concatenate([jnp.concatenate([p_inv - gm @ g.T, gm], axis=1),
                           jnp.concatenate([gm.T, -m_inv], axis=1)], axis=0)
    return inv, ok_p & ok_m & _clear(chol_p, p) & _clear(chol_m, m)


def pivot(sym, a: int, mode: str) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(S^{-1}, counts (positive, negative, zero), certified)`` of a symmetric pivot block: ``mode`` ``"fast"``
    (Cholesky factors; counts ``(a, s - a, 0)``, meaningful only where certified), ``"exact"`` (eigenvalues) or
    ``"auto"`` (fast, else exact, by ``lax.cond``)."""
    sym = 0.5 * (sym + sym.T)
    s = sym.shape[0]
    if mode == "exact":
        inv, counts = _eigen_inverse(sym)
        return inv, counts, jnp.array(True)
    inv, ok = _cholesky_inverse(sym, a)
    certain = jnp.array([a, s - a, 0])
    if mode == "fast":
        return inv, certain, ok
    inv, counts = jax.lax.cond(ok, lambda: (inv, certain), lambda: _eigen_inverse(sym))
    return inv, counts, jnp.array(True)


# ---- sequential elimination --------------------------------------------------------------------------------------

class Chain(NamedTuple):
    """A sequentially eliminated chain: pivot inverses and gains ``G_k = S_k^{-1} E_k``."""

    sinv: jax.Array  # (K, s, s)
    gain: jax.Array  # (K - 1, s, s)


def _eliminate(d, e, a: int, mode: str):
    """``(Chain, counts (K, 3), certified (K,))`` of blocks ``d`` (K, s, s) and couplings ``e`` (K - 1, s, s)."""
    e_prev = jnp.concatenate([jnp.zeros_like(d[:1]), e], axis=0)

    def step(sinv_prev, inp):
        d_k, e_k = inp
        sinv, counts, ok = pivot(d_k - e_k.T @ sinv_prev @ e_k, a, mode)
        return sinv, (sinv, counts, ok)

    _, (sinv, counts, ok) = jax.lax.scan(step, jnp.zeros_like(d[0]), (d, e_prev))
    return Chain(sinv, sinv[:-1] @ e), counts, ok


def _chain_solve(c: Chain, r):
    """``M^{-1} r`` of an eliminated chain, ``r`` (K, s, q): forward, diagonal and backward sweeps."""
    def forward(y_prev, inp):
        r_k, g_prev = inp
        y = r_k - g_prev.T @ y_prev
        return y, y

    g_prev = jnp.concatenate([jnp.zeros_like(c.sinv[:1]), c.gain], axis=0)
    _, y = jax.lax.scan(forward, jnp.zeros_like(r[0]), (r, g_prev))
    w = c.sinv @ y

    def backward(x_next, inp):
        w_k, g_k = inp
        x = w_k - g_k @ x_next
        return x, x

    g_next = jnp.concatenate([c.gain, jnp.zeros_like(c.sinv[:1])], axis=0)
    _, x = jax.lax.scan(backward, jnp.zeros_like(r[0]), (w, g_next), reverse=True)
    return x


# ---- partitioned elimination -------------------------------------------------------------------------------------

class Factors(NamedTuple):
    """A factorised block-tridiagonal matrix: the chunks' chains and their couplings to the separators (None where
    the elimination was sequential), and the separators' chain (every block where sequential)."""

    chunks: Chain | None  # (P, L - 1, ...) stacked
    e_left: jax.Array | None  # (P, s, s) M[separator j, first interior of chunk j]
    e_right: jax.Array | None  # (P, s, s) M[last interior of chunk j, separator j + 1]
    seps: Chain


def _chunk(d, e_chain, e_left, e_right, a: int, mode: str):
    """One chunk's interiors eliminated, carrying their coupling ``X`` to the left separator: ``(Chain, counts,
    certified, left separator's update, right separator's update, the separators' new coupling)``."""
    e_prev = jnp.concatenate([jnp.zeros_like(d[:1]), e_chain], axis=0)
    first = jnp.arange(d.shape[0]) == 0

    def step(carry, inp):
        sinv_prev, x_prev, u_left = carry
        d_t, e_t, is_first = inp
        x = jnp.where(is_first, e_left.T, -e_t.T @ sinv_prev @ x_prev)
        sinv, counts, ok = pivot(d_t - e_t.T @ sinv_prev @ e_t, a, mode)
        return (sinv, x, u_left + x.T @ sinv @ x), (sinv, counts, ok)

    zero = jnp.zeros_like(d[0])
    (sinv_l, x_l, u_left), (sinv, counts, ok) = jax.lax.scan(step, (zero, zero, zero), (d, e_prev, first))
    u_right = e_right.T @ sinv_l @ e_right
    return (Chain(sinv, sinv[:-1] @ e_chain), jnp.sum(counts, axis=0), jnp.all(ok), u_left, u_right,
            -x_l.T @ sinv_l @ e_right)


def _padded(d, e, a: int, big_k: int):
    """``d``, ``e`` extended to ``big_k`` blocks by uncoupled blocks ``diag(+1 (a), -1 (s - a))``."""
    k, s = d.shape[0], d.shape[1]
    pad = jnp.diag(jnp.where(jnp.arange(s) < a, 1.0, -1.0).astype(d.dtype))
    d = jnp.concatenate([d, jnp.broadcast_to(pad, (big_k - k, s, s))], axis=0)
    return d, jnp.concatenate([e, jnp.zeros((big_k - k, s, s), e.dtype)], axis=0)


def _partitioned(d, e, a: int, stride_: int, mode: str):
    """``(Factors, counts (3,), chunk pivots certified)`` with separators every ``stride_`` blocks."""
    big_l, s = stride_, d.shape[1]
    n_chunks = -(-(d.shape[0] - 1) // big_l)
    d, e = _padded(d, e, a, n_chunks * big_l + 1)
    d_i = d[1:].reshape(n_chunks, big_l, s, s)[:, : big_l - 1]
    e_all = e.reshape(n_chunks, big_l, s, s)  # e[jL + t]: block jL + t to jL + t + 1
    e_left, e_chain, e_right = e_all[:, 0], e_all[:, 1: big_l - 1], e_all[:, big_l - 1]
    chunks, counts_i, ok_i, u_left, u_right, coupling = jax.vmap(
        lambda *args: _chunk(*args, a, mode))(d_i, e_chain, e_left, e_right)
    zero = jnp.zeros_like(u_left[:1])
    d_s = d[::big_l] - jnp.concatenate([u_left, zero]) - jnp.concatenate([zero, u_right])
    seps, counts_s, ok_s = _eliminate(d_s, coupling, a, mode)
    counts = jnp.sum(counts_i, axis=0) + jnp.sum(counts_s, axis=0)
    return Factors(chunks, e_left, e_right, seps), counts, jnp.all(ok_i) & jnp.all(ok_s)


def factor(d, e, a: int) -> tuple[Factors, jax.Array]:
    """``(Factors, inertia counts (positive, negative, zero))`` of the block-tridiagonal matrix with blocks ``d``
    (K, s, s) and couplings ``e`` (K - 1, s, s), ``a``: each block's leading rows that a certified pivot expects
    positive (the module docstring)."""
    k, s = d.shape[0], d.shape[1]
    stride_ = stride(k)
    if not stride_:
        chain, counts, _ = _eliminate(d, e, a, "auto")
        return Factors(None, None, None, chain), jnp.sum(counts, axis=0)
    extra = -(-(k - 1) // stride_) * stride_ + 1 - k  # the padding blocks' known inertia (a, s - a, 0) each
    known = jnp.array([a, s - a, 0]) * extra
    fast, counts, ok = _partitioned(d, e, a, stride_, "fast")

    def exact():
        f, c, _ = _partitioned(d, e, a, stride_, "exact")
        return f, c - known

    return jax.lax.cond(ok, lambda: (fast, counts - known), exact)


def solve(f: Factors, r) -> jax.Array:
    """``M^{-1} r`` for ``r`` of shape ``(K, s)`` or ``(K, s, q)``."""
    if r.ndim == 2:
        return solve(f, r[:, :, None])[:, :, 0]
    if f.chunks is None:
        return _chain_solve(f.seps, r)
    k, s, q = r.shape
    n_chunks = f.e_left.shape[0]
    big_l = f.chunks.sinv.shape[1] + 1
    r = jnp.concatenate([r, jnp.zeros((n_chunks * big_l + 1 - k, s, q), r.dtype)], axis=0)
    r_s = r[::big_l]
    r_i = r[1:].reshape(n_chunks, big_l, s, q)[:, : big_l - 1]
    z = jax.vmap(_chain_solve)(f.chunks, r_i)
    zero = jnp.zeros_like(r_s[:1])
    r_s = (r_s - jnp.concatenate([f.e_left @ z[:, 0], zero])
           - jnp.concatenate([zero, jnp.swapaxes(f.e_right, 1, 2) @ z[:, -1]]))
    x_s = _chain_solve(f.seps, r_s)
    r_i = r_i.at[:, 0].add(-jnp.swapaxes(f.e_left, 1, 2) @ x_s[:-1])
    r_i = r_i.at[:, -1].add(-f.e_right @ x_s[1:])
    x_i = jax.vmap(_chain_solve)(f.chunks, r_i)
    body = jnp.concatenate([x_s[:-1, None], x_i], axis=1).reshape(n_chunks * big_l, s, q)
    return jnp.concatenate([body, x_s[-1:]], axis=0)[:k]
