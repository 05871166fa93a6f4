r"""Small dense matrices for the stage-wise Newton step (:mod:`.riccati`), written for a batch on a CPU.

A matrix is a nested list of *scalars* (per member), so that under ``vmap`` each entry is one contiguous ``(B,)``
vector and a stage's whole recursion is a few hundred elementwise vector operations, which XLA fuses (an array
``(B, k, k)`` of the 2-7 wide stage matrices is a loop of short, strided loops; measured in the solver-code note).
Entries may also be the Python floats ``0.0`` and ``1.0`` (the carried decisions' selection matrices): products with
them are elided when the program is traced.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["blocks", "array", "mm", "keep", "tr", "add", "scale", "cholesky", "cho_solve", "cholesky_array",
           "cho_solve_array"]

SMALL = 8  # arrays up to this size are factorised unrolled (elementwise); larger ones by LAPACK


def _zero(x) -> bool:
    return isinstance(x, float) and x == 0.0


def _one(x) -> bool:
    return isinstance(x, float) and x == 1.0


def _mul(x, y):
    if _zero(x) or _zero(y):
        return 0.0
    return y if _one(x) else x if _one(y) else x * y


def _sum(terms):
    terms = [t for t in terms if not _zero(t)]
    total = terms[0] if terms else 0.0
    for t in terms[1:]:
        total = total + t
    return total


def blocks(a) -> list:
    """``a`` (..., r, c) as ``r`` lists of ``c`` arrays of shape ``(...)``."""
    return [[a[..., i, j] for j in range(a.shape[-1])] for i in range(a.shape[-2])]


def array(m: list, like) -> jax.Array:
    """The nested list ``m`` as an array (..., r, c), Python floats broadcast to ``like``'s shape and dtype."""
    def entry(x):
        return jnp.full(jnp.shape(like), x, like.dtype) if isinstance(x, float) else x

    return jnp.stack([jnp.stack([entry(x) for x in row], axis=-1) for row in m], axis=-2)


def mm(a: list, b: list) -> list:
    return [[_sum([_mul(a[i][k], b[k][j]) for k in range(len(b))]) for j in range(len(b[0]))] for i in range(len(a))]


def keep(*ms: list):
    """``ms`` computed once: XLA:CPU would otherwise fuse every entry that reads them with the whole expression
    behind them, and recompute shared products once per reader (an optimisation barrier; Python floats stay)."""
    arrays = [x for m in ms for row in m for x in row if not isinstance(x, float)]
    kept = iter(jax.lax.optimization_barrier(arrays))
    out = tuple([[x if isinstance(x, float) else next(kept) for x in row] for row in m] for m in ms)
    return out[0] if len(ms) == 1 else out


def tr(a: list) -> list:
    return [list(col) for col in zip(*a)]


def add(*ms: list) -> list:
    return [[_sum([m[i][j] for m in ms]) for j in range(len(ms[0][0]))] for i in range(len(ms[0]))]


def scale(s, m: list) -> list:
    return [[_mul(s, x) for x in row] for row in m]


def cholesky(a: list, like) -> tuple[list, jax.Array]:
    """``(L, positive definite)`` of the symmetric ``a`` (its lower triangle and diagonal are read); a failed
    factor holds finite junk. ``like``: an array of the entries' shape (for the flag)."""
    k = len(a)
    ok = jnp.ones(jnp.shape(like), bool)
    low = [[0.0] * k for _ in range(k)]
    for j in range(k):
        d2 = a[j][j] - _sum([low[j][p] * low[j][p] for p in range(j)])
        ok = ok & (d2 > 0)  # False for NaN too
        d = jnp.sqrt(jnp.where(d2 > 0, d2, 1.0))
        low[j][j] = d
        for i in range(j + 1, k):
            low[i][j] = (a[i][j] - _sum([low[i][p] * low[j][p] for p in range(j)])) / d
    return low, ok


def cho_solve(low: list, b: list) -> list:
    """``(L L^T)^{-1} b`` by forward and backward substitution."""
    k = len(low)
    y = []
    for i in range(k):
        y.append([(b[i][j] - _sum([low[i][p] * y[p][j] for p in range(i)])) / low[i][i] for j in range(len(b[0]))])
    x = [None] * k
    for i in reversed(range(k)):
        x[i] = [(y[i][j] - _sum([low[p][i] * x[p][j] for p in range(i + 1, k)])) / low[i][i]
                for j in range(len(b[0]))]
    return x


def cholesky_array(a) -> tuple[jax.Array, jax.Array]:
    """``(lower factor, positive definite)`` of a symmetric array ``(..., k, k)``: unrolled up to ``SMALL``."""
    k = a.shape[-1]
    if not k:
        return a, jnp.ones(a.shape[:-2], bool)
    if k > SMALL:
        chol = jnp.linalg.cholesky(0.5 * (a + jnp.swapaxes(a, -1, -2)))
        return chol, jnp.all(jnp.isfinite(chol), axis=(-2, -1))
    low, ok = cholesky(blocks(0.5 * (a + jnp.swapaxes(a, -1, -2))), a[..., 0, 0])
    return array(low, a[..., 0, 0]), ok


def cho_solve_array(chol, b) -> jax.Array:
    """``(L L^T)^{-1} b`` for arrays ``chol`` (..., k, k) and ``b`` (..., k, r)."""
    k = chol.shape[-1]
    if not k:
        return b
    if k > SMALL:
        return jax.scipy.linalg.cho_solve((chol, True), b)
    return array(cho_solve(blocks(chol), blocks(b)), b[..., 0, 0])
