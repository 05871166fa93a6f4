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
    "HessianColouring",
    "color_columns",
    "compressed_jacobian_fn",
    "dense_from_hvps",
    "hessian_structure",
    "hvp_batch_fn",
]


def color_columns(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A greedy colouring (``(n_cols,)`` ints from 0) of the columns of the pattern ``(rows, cols)`` of ``shape``
    such that no two columns of one colour share a row."""
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


def hvp_batch_fn(grad_fn: Callable[..., Any]) -> Callable[..., Any]:
    """``(w, seeds, *args) -> seeds @ H``: one forward-over-reverse Hessian-vector product per row of ``seeds``.

    ``H`` is the Jacobian of ``grad_fn(w, *args)``. The seeds are an argument, not a constant, so one compiled program
    serves both the pattern detection (identity seeds) and every later evaluation (colour seeds): a second-order
    program is the most expensive thing a solver compiles."""

    def hvps(w, seeds, *args):
        return jax.vmap(lambda v: jax.jvp(lambda w_: grad_fn(w_, *args), (w,), (v,))[1])(seeds)

    return hvps


def dense_from_hvps(hvps: Callable[[np.ndarray], np.ndarray], n: int, batch: int) -> np.ndarray:
    """The dense ``n x n`` Hessian from ``hvps(seeds (batch, n)) -> (batch, n)``, ``batch`` columns per call."""
    columns = []
    for start in range(0, n, batch):
        seeds = np.zeros((batch, n))
        idx = np.arange(start, min(start + batch, n))
        seeds[idx - start, idx] = 1.0
        columns.append(np.asarray(hvps(seeds))[: idx.size])
    return np.concatenate(columns).T  # row i of the stack is H e_i, the i-th column


class HessianColouring:
    """Recover the entries ``(rows, cols)`` of a symmetric Hessian from products with colour seeds.

    The colouring is done on the symmetric completion of the pattern (``(rows, cols)`` may be the lower triangle), and
    the ``K`` colour seeds are padded to whole batches of ``batch`` rows for :func:`hvp_batch_fn`'s program.

    A *dense* variable (a free final time multiplies every step, so its row and column touch everything) would
    conflict with every other column and force one colour per variable. Such a variable gets a seed of its own,
    ``H e_d`` is its whole column, entries in its row are read by symmetry from that column, and the rest is
    coloured as if it were absent: ``K`` stays about the bandwidth plus the number of dense variables.
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, n: int, batch: int):
        both_r, both_c = np.concatenate([rows, cols]), np.concatenate([cols, rows])
        counts = np.bincount(both_c[both_r != both_c], minlength=n)
        dense = counts > max(32, n // 4)
        keep = ~dense[both_r] & ~dense[both_c]
        colours = color_columns(both_r[keep], both_c[keep], (n, n))
        base = int(colours[~dense].max()) + 1 if (~dense).any() else 0
        colours[dense] = base + np.arange(int(dense.sum()))
        seeds = _seeds(colours)
        self.n_colours = seeds.shape[0]
        padded = np.zeros((-(-self.n_colours // batch) * batch, n))
        padded[: self.n_colours] = seeds
        self.seed_batches = [padded[i : i + batch] for i in range(0, padded.shape[0], batch)]
        # (colour, row) of each requested entry; in a dense variable's row, (H e_r)[c] = H[r, c] by symmetry.
        by_row = dense[rows] & ~dense[cols]
        self._take = (np.where(by_row, colours[rows], colours[cols]), np.where(by_row, cols, rows))

    def values(self, hvps: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """The requested entries, given ``hvps(seeds (batch, n)) -> (batch, n)`` at the point of interest."""
        compressed = np.concatenate([np.asarray(hvps(seeds)) for seeds in self.seed_batches])  # (K, n): S_k H
        return compressed[self._take]


def hessian_structure(dense_hessians: list[np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower-triangle pattern of the union of the non-zeros of some numerically evaluated Hessians.

    Samples that contain a NaN or an infinity are skipped (a NaN spreads through the whole reverse pass and would
    make the pattern dense); when no sample is finite the dense lower triangle is returned, which is always
    correct. The diagonal is always included: it is cheap and IPOPT regularises on it. ``(rows, cols)``, row-major.
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
