r"""Symmetric block-tridiagonal matrices: a factorisation that counts the inertia, and solves, in ``O(K s^3)``.

The matrix has diagonal blocks ``D_k`` (``K`` of them, each ``s x s``, symmetric) and couplings ``E_k =
M[block k, block k + 1]``. Block Gaussian elimination is a congruence, so by Sylvester's law the matrix's inertia is
the sum of the pivot blocks' inertias; each pivot is inverted by :func:`pivot`.

**Partitioned elimination** (why: a sequential sweep is one ``lax.scan`` step per block, and on a CPU a step pays
its kernels' launches, ~3 us, besides its arithmetic; on an accelerator the depth is what counts). Every ``L``-th
block is a separator; the ``L - 1`` blocks between two separators (a chunk) are eliminated first, all chunks at once
(``vmap``) in ``L - 1`` steps, carrying the fill towards the chunk's left separator; what is left is a block-
tridiagonal system on the ``P + 1`` separators, eliminated in turn. Depth ``~2 sqrt(K)`` instead of ``K``; about the
same arithmetic. The elimination order is a permutation (interiors, then separators), so the counted inertia is
still exact. On the 2-core CPU it gains 10-20 % (Van der Pol's Hermite-Simpson factorisation, blocks of 6: 1601
stages 12.2 -> 10.5 ms, 6401 stages 44.7 -> 40.1 ms, load 1.5): the eigendecompositions' arithmetic dominates there.

**Pivots** are inverted through their eigendecomposition, which also counts their inertia. Tried and dropped: two
Cholesky factors that certify the inertia ``(a, s - a, 0)`` where they exist, with the eigendecomposition as the
fallback. Vmapped across the chunks the unrolled factors ran no faster than batched eigendecompositions (1601 blocks
of 5: 6.9 against 7.3 ms), the fallback re-ran the whole elimination wherever a stage's own inertia differed from
``(a, s - a)`` (the matrix's may still be right: half of Van der Pol's Trapezoidal(400) factorisations), and they
doubled the program's XLA compile time (Hermite-Simpson(50): 17.1 against 8.2 s of CPU).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

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


def pivot(sym) -> tuple[jax.Array, jax.Array]:
    """``(S^{-1}, counts (positive, negative, zero))`` of a symmetric pivot block."""
    return _eigen_inverse(0.5 * (sym + sym.T))


# ---- sequential elimination --------------------------------------------------------------------------------------

class Chain(NamedTuple):
    """A sequentially eliminated chain: pivot inverses and gains ``G_k = S_k^{-1} E_k``."""

    sinv: jax.Array  # (K, s, s)
    gain: jax.Array  # (K - 1, s, s)


def _eliminate(d, e):
    """``(Chain, counts (K, 3))`` of blocks ``d`` (K, s, s) and couplings ``e`` (K - 1, s, s)."""
    e_prev = jnp.concatenate([jnp.zeros_like(d[:1]), e], axis=0)

    def step(sinv_prev, inp):
        d_k, e_k = inp
        sinv, counts = pivot(d_k - e_k.T @ sinv_prev @ e_k)
        return sinv, (sinv, counts)

    _, (sinv, counts) = jax.lax.scan(step, jnp.zeros_like(d[0]), (d, e_prev))
    return Chain(sinv, sinv[:-1] @ e), counts


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


def _chunk(d, e_chain, e_left, e_right):
    """One chunk's interiors eliminated, carrying their coupling ``X`` to the left separator: ``(Chain, counts,
    left separator's update, right separator's update, the separators' new coupling)``."""
    e_prev = jnp.concatenate([jnp.zeros_like(d[:1]), e_chain], axis=0)
    first = jnp.arange(d.shape[0]) == 0

    def step(carry, inp):
        sinv_prev, x_prev, u_left = carry
        d_t, e_t, is_first = inp
        x = jnp.where(is_first, e_left.T, -e_t.T @ sinv_prev @ x_prev)
        sinv, counts = pivot(d_t - e_t.T @ sinv_prev @ e_t)
        return (sinv, x, u_left + x.T @ sinv @ x), (sinv, counts)

    zero = jnp.zeros_like(d[0])
    (sinv_l, x_l, u_left), (sinv, counts) = jax.lax.scan(step, (zero, zero, zero), (d, e_prev, first))
    u_right = e_right.T @ sinv_l @ e_right
    return Chain(sinv, sinv[:-1] @ e_chain), jnp.sum(counts, axis=0), u_left, u_right, -x_l.T @ sinv_l @ e_right


def _padded(d, e, a: int, big_k: int):
    """``d``, ``e`` extended to ``big_k`` blocks by uncoupled blocks ``diag(+1 (a), -1 (s - a))``."""
    k, s = d.shape[0], d.shape[1]
    pad = jnp.diag(jnp.where(jnp.arange(s) < a, 1.0, -1.0).astype(d.dtype))
    d = jnp.concatenate([d, jnp.broadcast_to(pad, (big_k - k, s, s))], axis=0)
    return d, jnp.concatenate([e, jnp.zeros((big_k - k, s, s), e.dtype)], axis=0)


def _partitioned(d, e, a: int, stride_: int):
    """``(Factors, counts (3,))`` with separators every ``stride_`` blocks."""
    big_l, s = stride_, d.shape[1]
    n_chunks = -(-(d.shape[0] - 1) // big_l)
    d, e = _padded(d, e, a, n_chunks * big_l + 1)
    d_i = d[1:].reshape(n_chunks, big_l, s, s)[:, : big_l - 1]
    e_all = e.reshape(n_chunks, big_l, s, s)  # e[jL + t]: block jL + t to jL + t + 1
    e_left, e_chain, e_right = e_all[:, 0], e_all[:, 1: big_l - 1], e_all[:, big_l - 1]
    chunks, counts_i, u_left, u_right, coupling = jax.vmap(_chunk)(d_i, e_chain, e_left, e_right)
    zero = jnp.zeros_like(u_left[:1])
    d_s = d[::big_l] - jnp.concatenate([u_left, zero]) - jnp.concatenate([zero, u_right])
    seps, counts_s = _eliminate(d_s, coupling)
    return Factors(chunks, e_left, e_right, seps), jnp.sum(counts_i, axis=0) + jnp.sum(counts_s, axis=0)


def factor(d, e, a: int) -> tuple[Factors, jax.Array]:
    """``(Factors, inertia counts (positive, negative, zero))`` of the block-tridiagonal matrix with blocks ``d``
    (K, s, s) and couplings ``e`` (K - 1, s, s); ``a``: how many leading rows of each block are a stage's variables
    (the padding blocks carry ``+1`` there and ``-1`` on the rest, a known inertia subtracted here)."""
    k, s = d.shape[0], d.shape[1]
    stride_ = stride(k)
    if not stride_:
        chain, counts = _eliminate(d, e)
        return Factors(None, None, None, chain), jnp.sum(counts, axis=0)
    extra = -(-(k - 1) // stride_) * stride_ + 1 - k
    factors, counts = _partitioned(d, e, a, stride_)
    return factors, counts - jnp.array([a, s - a, 0]) * extra


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
