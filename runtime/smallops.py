r"""Small array operations that stay fast under ``vmap`` on a CPU: products of small matrices, and gathers and
scatter-adds whose index is a static NumPy array.

Why: under ``vmap`` over a batch, ``a @ b`` of per-member ``5 x 5`` matrices is a batched ``dot`` that XLA:CPU runs
as one small matrix product per member, ``x[index]`` / ``x.at[index].add(v)`` with an index *array* become ``gather``
/ ``scatter`` kernels, and a broadcast product summed by ``jnp.sum`` goes to YNNPACK: each several times slower than
elementwise work (profiles of vmapped Epidemic NLPs, 2026-12-03: `git show 3c72bf5:runtime/smallops.py`). An
unrolled sum of products is elementwise work that XLA fuses; a long contraction (a row of the Jacobian, 101 long)
stays an XLA dot, the fastest.
An index whose columns are arithmetic progressions (single shooting's ``k m + j``, a permutation's runs) is a few
strided slices (:func:`take`) or interior-padded copies (:func:`add_at`); any other index still works, one
slice per element.
"""

from __future__ import annotations

import functools
import operator

import jax.numpy as jnp
import numpy as np
from jax import lax

__all__ = ["matmul", "matvec", "take", "add_at"]


UNROLL = 8  # contractions up to this length are unrolled sums of products; longer ones are XLA dots


def matmul(a, b):
    """``a @ b`` (leading axes broadcast); a short contraction as an unrolled sum of broadcast products."""
    k = a.shape[-1]
    if k > UNROLL or k == 0:
        return jnp.matmul(a, b)
    return functools.reduce(operator.add, [a[..., :, i, None] * b[..., None, i, :] for i in range(k)])


def matvec(a, v):
    """``a @ v`` for a matrix ``a`` (..., r, c) and a vector ``v`` (..., c), as :func:`matmul`."""
    k = a.shape[-1]
    if k > UNROLL or k == 0:
        return jnp.matmul(a, v[..., None])[..., 0]
    return functools.reduce(operator.add, [a[..., :, i] * v[..., i, None] for i in range(k)])


def _runs(flat: np.ndarray) -> list[tuple[int, int, int, int]]:
    """``flat`` cut into maximal arithmetic runs with a positive step: ``(position, start, step, count)``."""
    out, i, n = [], 0, flat.size
    while i < n:
        j = i
        step = int(flat[i + 1] - flat[i]) if i + 1 < n else 1
        if step > 0:
            while j + 1 < n and flat[j + 1] - flat[j] == step:
                j += 1
        else:
            step = 1
        out.append((i, int(flat[i]), step, j - i + 1))
        i = j + 1
    return out


def _static(index) -> np.ndarray:
    index = np.asarray(index)
    if not np.issubdtype(index.dtype, np.integer):
        raise TypeError(f"a static index must be an integer NumPy array, got dtype {index.dtype}")
    return index


def _column_major(index: np.ndarray) -> np.ndarray:
    # Columns first: single shooting's (N, q) index is q runs this way and N q short runs row by row.
    return np.ravel(index, order="F")


def _reversed(axis: int, k: int, ndim: int) -> list[int]:
    """The permutation that reverses axes ``axis .. axis + k - 1`` (an index's axes, read column-major)."""
    return list(range(axis)) + [axis + k - 1 - i for i in range(k)] + list(range(axis + k, ndim))


def take(x, index, axis: int = 0):
    """``jnp.take(x, index, axis)`` for a static ``index`` (any shape, non-negative, in range)."""
    index = _static(index)
    axis = axis % x.ndim
    if index.size and (index.min() < 0 or index.max() >= x.shape[axis]):
        raise IndexError(f"take: index out of range for axis {axis} of size {x.shape[axis]}")
    parts = [lax.slice_in_dim(x, start, start + (count - 1) * step + 1, stride=step, axis=axis)
             for _, start, step, count in _runs(_column_major(index))]
    out = jnp.concatenate(parts, axis=axis) if parts else lax.slice_in_dim(x, 0, 0, axis=axis)
    # Undo the column-major order: reversed shape, then reversed axes.
    out = jnp.reshape(out, x.shape[:axis] + index.shape[::-1] + x.shape[axis + 1:])
    return jnp.transpose(out, _reversed(axis, index.ndim, out.ndim))


def add_at(size: int, index, values, axis: int = 0):
    """Zeros with ``size`` entries along ``axis`` and ``values`` added at ``index`` (static; repeats add up):
    ``jnp.zeros(...).at[..., index, ...].add(values)``, where ``values`` has ``index``'s axes in place of ``axis``."""
    index = _static(index)
    k = index.ndim
    values = jnp.asarray(values)
    axis = axis % (values.ndim - k + 1)
    if values.shape[axis:axis + k] != index.shape:
        raise ValueError(f"add_at: values' axes {axis}..{axis + k - 1} are {values.shape[axis:axis + k]}, the "
                         f"index's shape is {index.shape}")
    if index.size and (index.min() < 0 or index.max() >= size):
        raise IndexError(f"add_at: index out of range for size {size}")
    flat = jnp.reshape(jnp.transpose(values, _reversed(axis, k, values.ndim)),
                       values.shape[:axis] + (index.size,) + values.shape[axis + k:])
    zero = jnp.zeros((), values.dtype)
    total = None
    for pos, start, step, count in _runs(_column_major(index)):
        piece = lax.slice_in_dim(flat, pos, pos + count, axis=axis)
        config = [(0, 0, 0)] * piece.ndim
        config[axis] = (start, size - start - (count - 1) * step - 1, step - 1)
        piece = lax.pad(piece, zero, config)
        total = piece if total is None else total + piece
    if total is None:
        return jnp.zeros(values.shape[:axis] + (size,) + values.shape[axis + k:], values.dtype)
    return total
