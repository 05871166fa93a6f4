"""Sparse derivatives by column colouring: Jacobians and Hessians in a handful of JVPs instead of one per variable.

A transcription's Jacobian and Lagrangian Hessian are banded (each defect touches one or two grid intervals), so
most columns never share a row. Columns that share no row may be given one colour and probed together:

.. math::
    (J S)_{r,\\,k} = \\sum_{j:\\ \\mathrm{colour}(j)=k} J_{r j} = J_{r,\\,j(r, k)}

where ``S`` is the ``n x K`` 0/1 seed matrix of the colouring and ``j(r, k)`` the only column of colour ``k`` that
is non-zero in row ``r``. ``J S`` costs ``K`` forward-mode JVPs, and ``K`` is about the bandwidth, not ``n``. The
Hessian is treated as the Jacobian of the gradient (forward-over-reverse Hessian-vector products), with the same
distance-2 colouring of its columns (Curtis-Powell-Reid), so every non-zero is read off directly.

References:
    Curtis, Powell & Reid (1974), On the estimation of sparse Jacobian matrices. Gebremedhin, Manne & Pothen
    (2005), What color is your Jacobian? Graph coloring for computing derivatives. SIAM Review 47(4).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

__all__ = [
    "color_columns",
    "compressed_jacobian_fn",
    "compressed_hessian_fn",
    "dense_hessian_fn",
    "hessian_structure",
]


def color_columns(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A greedy colouring of the columns of a sparsity pattern such that no two columns of one colour share a row.

    Args:
        rows, cols: the structurally non-zero entries.
        shape: (n_rows, n_cols).

    Returns:
        colours (n_cols,) int, numbered from 0.
    """
    n_rows, n_cols = shape
    pattern = sp.csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=shape)
    # Columns j, k conflict iff some row holds both: (P^T P)_{jk} != 0.
    conflict = (pattern.T @ pattern).tocsr()
    colours = np.full(n_cols, -1, dtype=np.int64)
    for j in range(n_cols):  # natural order: near-optimal for the banded patterns transcriptions produce
        neighbours = conflict.indices[conflict.indptr[j] : conflict.indptr[j + 1]]
        taken = set(colours[neighbours].tolist())
        colour = 0
        while colour in taken:
            colour += 1
        colours[j] = colour
    return colours


def _seeds(colours: np.ndarray) -> np.ndarray:
    n_colours = int(colours.max()) + 1 if colours.size else 0
    seeds = np.zeros((n_colours, colours.size))
    seeds[colours, np.arange(colours.size)] = 1.0
    return seeds


def compressed_jacobian_fn(
    fn: Callable[[Any, Any], Any], rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
) -> Callable[[Any, Any], Any]:
    """``(w, data) -> values`` of ``d fn / d w`` at the entries ``(rows, cols)``, by coloured JVPs.

    Entries outside the pattern are assumed zero; the pattern must therefore be a superset of the true one.
    """
    colours = color_columns(rows, cols, shape)
    seeds = jnp.asarray(_seeds(colours))
    take_colour, take_row = jnp.asarray(colours[cols]), jnp.asarray(rows)

    def values(w, data):
        jvp = lambda v: jax.jvp(lambda w_: fn(w_, data), (w,), (v,))[1]  # noqa: E731
        compressed = jax.vmap(jvp)(seeds)  # (K, n_rows): row k is J @ seed_k
        return compressed[take_colour, take_row]

    return values


def compressed_hessian_fn(
    grad_fn: Callable[..., Any], rows: np.ndarray, cols: np.ndarray, n: int
) -> Callable[..., Any]:
    """``(w, *args) -> values`` of the Hessian (the Jacobian of ``grad_fn(w, *args)``) at ``(rows, cols)``.

    ``(rows, cols)`` may be the lower triangle only: the colouring is done on the symmetric completion, so the
    columns of one colour share no row of the full matrix and each requested entry is recovered exactly.
    """
    full_rows = np.concatenate([rows, cols])
    full_cols = np.concatenate([cols, rows])
    colours = color_columns(full_rows, full_cols, (n, n))
    seeds = jnp.asarray(_seeds(colours))
    take_colour, take_row = jnp.asarray(colours[cols]), jnp.asarray(rows)

    def values(w, *args):
        hvp = lambda v: jax.jvp(lambda w_: grad_fn(w_, *args), (w,), (v,))[1]  # noqa: E731
        compressed = jax.vmap(hvp)(seeds)  # (K, n): row k is H @ seed_k
        return compressed[take_colour, take_row]

    return values


def dense_hessian_fn(grad_fn: Callable[..., Any], n: int, batch_size: int = 64) -> Callable[..., Any]:
    """``(w, *args) -> H`` (n, n), one Hessian-vector product per column, ``batch_size`` at a time.

    Only used once per NLP to detect the sparsity pattern; ``lax.map`` in batches bounds the memory to
    ``batch_size`` simultaneous products instead of ``n``.
    """

    def hessian(w, *args):
        def column(i):
            e = jnp.zeros(n, dtype=w.dtype).at[i].set(1.0)
            return jax.jvp(lambda w_: grad_fn(w_, *args), (w,), (e,))[1]

        return jax.lax.map(column, jnp.arange(n), batch_size=min(n, batch_size)).T

    return hessian


def hessian_structure(dense_hessians: list[np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower-triangle pattern of the union of the non-zeros of some numerically evaluated Hessians.

    Samples that contain a NaN or an infinity are skipped (a NaN spreads through the whole reverse pass and would
    make the pattern dense); when no sample is finite the dense lower triangle is returned, which is always
    correct. The diagonal is always included: it is cheap and IPOPT regularises on it.

    Returns:
        (rows, cols) with rows >= cols, sorted row-major.
    """
    finite = [h for h in dense_hessians if np.all(np.isfinite(h))]
    if finite:
        nonzero = np.zeros((n, n), dtype=bool)
        for h in finite:
            nonzero |= h != 0
        nonzero |= nonzero.T
        nonzero |= np.eye(n, dtype=bool)
    else:
        nonzero = np.ones((n, n), dtype=bool)
    rows, cols = np.nonzero(np.tril(nonzero))
    return rows.astype(np.int64), cols.astype(np.int64)
