"""The pieces of an NLP that every transcription builds alike: initial guesses, state-bound and final-value rows,
path-constraint rows, the free final time as a variable, and Jacobian sparsity patterns.

Public because the indirect methods and the RL environments build the same rows and guesses from a system; the
nominal magnitudes they are scaled by are in :mod:`.nominal_scales`.
"""

from __future__ import annotations

from typing import Any, Iterable

import jax
import jax.numpy as jnp
import numpy as np

from ..system import System
from .nominal_scales import nominal_scale, path_scale

__all__ = [
    "guess_controls",
    "guess_states",
    "sparsity",
    "final_value_rows",
    "bounded_free_states",
    "node_state_bounds",
    "path_rows",
    "path_bounds",
    "final_time_variable",
]


def guess_controls(system: System, k: int) -> np.ndarray:
    """Controls at the middle of their bounds where both are finite, else 0 clipped into the bounds: (k, m)."""
    a = system.arrays()
    lo, hi = a["u_lower"], a["u_upper"]
    both = np.isfinite(lo) & np.isfinite(hi)
    mid = np.where(both, 0.5 * (np.where(both, lo, 0.0) + np.where(both, hi, 0.0)), np.clip(0.0, lo, hi))
    return np.tile(mid, (k, 1))


def guess_states(system: System, x0: Any, times: np.ndarray) -> Any:
    """States (K, n) at the times (K,) in [0, T], moving linearly from x0 (possibly traced) to the required final
    values, free ones held at x0, clipped to the bounds."""
    a = system.arrays()
    x0 = jnp.asarray(x0)
    s = jnp.asarray(np.asarray(times, dtype=np.float64) / system.horizon)[:, None]
    mask = jnp.asarray(system.final_mask)
    target = jnp.where(mask, jnp.asarray(np.nan_to_num(system.final_values)), x0)
    xs = x0[None, :] + s * (target - x0)[None, :]
    return jnp.clip(xs, jnp.asarray(a["x_lower"]), jnp.asarray(a["x_upper"]))


def sparsity(blocks: Iterable[tuple[np.ndarray, np.ndarray, bool]]) -> tuple[np.ndarray, np.ndarray]:
    """A Jacobian pattern ``(rows, cols)`` (int64, without duplicates, sorted by row then column) from blocks of
    structurally non-zero entries, ``(rows, cols, diagonal)`` triples: ``diagonal=False`` marks every (row, col) pair
    of the two index arrays, ``diagonal=True`` only the pairs (rows[i], cols[i])."""
    rs, cs = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for r, c, diagonal in blocks:
        r = np.asarray(r, dtype=np.int64)
        c = np.asarray(c, dtype=np.int64)
        if diagonal:
            rs.append(r)
            cs.append(c)
        else:
            rr, cc = np.meshgrid(r, c, indexing="ij")
            rs.append(rr.ravel())
            cs.append(cc.ravel())
    pairs = np.unique(np.stack([np.concatenate(rs), np.concatenate(cs)], axis=1), axis=0)
    return pairs[:, 0].copy(), pairs[:, 1].copy()


def collocation_blocks(N: int, n: int, m: int, fixed: np.ndarray, n_path: int, n_T: int,
                       midpoints: bool = False) -> list:
    """A collocation Jacobian's structurally non-zero blocks for ``sparsity``: the defect of interval ``k`` couples
    ``x_k`` (a variable from ``k = 1``: ``x_0`` is given), ``x_{k+1}``, ``u_k``, ``u_{k+1}`` and, with ``midpoints``,
    ``u_{k+1/2}`` (stored after the node controls); then one row per required final value; then ``n_path`` path rows
    per node (and midpoint), a node's on its own state and control, a midpoint's on its interval's. Variables: the
    states ``x_1 .. x_N``, the node controls, the midpoint controls, then ``n_T`` (1 for a free final time, whose
    column every row has, else 0)."""
    nX, nU = N * n, (N + 1) * m
    T_col = np.arange(nX + nU + N * m * midpoints, nX + nU + N * m * midpoints + n_T)
    blocks = []
    for k in range(N):
        cols = [np.arange(k * n, (k + 1) * n)]  # x_{k+1}
        if k > 0:
            cols.append(np.arange((k - 1) * n, k * n))  # x_k
        cols.append(nX + np.arange(k * m, (k + 2) * m))  # u_k, u_{k+1}
        if midpoints:
            cols.append(nX + nU + np.arange(k * m, (k + 1) * m))  # u_{k+1/2}
        blocks.append((k * n + np.arange(n), np.concatenate(cols + [T_col]), False))
    for r, i in enumerate(fixed):
        blocks.append((np.array([N * n + r]), np.array([(N - 1) * n + i]), True))
    for p in range(2 * N + 1 if midpoints else N + 1):  # with midpoints the half-step grid: node p / 2 or interval's
        k, mid = (p // 2, p % 2) if midpoints else (p, 0)
        cols = [np.arange((k - 1) * n, k * n)] if k > 0 else []
        if mid:
            cols += [np.arange(k * n, (k + 1) * n), nX + np.arange(k * m, (k + 2) * m),
                     nX + nU + np.arange(k * m, (k + 1) * m)]
        else:
            cols.append(nX + np.arange(k * m, (k + 1) * m))
        blocks.append((N * n + fixed.size + p * n_path + np.arange(n_path), np.concatenate(cols + [T_col]), False))
    return blocks


def final_value_rows(system: System) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the states with a required final value, and those values."""
    fixed = np.flatnonzero(system.final_mask)
    return fixed, system.final_values[fixed]


def bounded_free_states(system: System) -> np.ndarray:
    """States with at least one finite bound and no required final value (why: :func:`node_state_bounds`)."""
    a = system.arrays()
    finite = np.isfinite(a["x_lower"]) | np.isfinite(a["x_upper"])
    return np.flatnonzero(finite & ~system.final_mask)


def node_state_bounds(system: System, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """State bounds tiled over ``nodes`` node-state blocks (the last block is x(T)), flattened to (nodes * n,),
    without the last node's for the states with a required final value: the equality row pins them, and an active
    bound duplicating it (Predator Prey's z(T) = B with z <= B) would make the constraint gradients linearly
    dependent."""
    a = system.arrays()
    lo = np.tile(a["x_lower"], (nodes, 1))
    hi = np.tile(a["x_upper"], (nodes, 1))
    lo[-1, system.final_mask] = -np.inf
    hi[-1, system.final_mask] = np.inf
    return lo.ravel(), hi.ravel()


# ---- schema 2: path constraints and a free final time ---------------------------------------------------------------


def path_rows(system: System, params: Any, xs: Any, us: Any, ts: Any) -> Any:
    """The path-constraint rows at K points, g(x_k, u_k, t_k) / scale, point-major: (K * n_path,); empty (and free
    of any evaluation) for a system without path constraints, so that a schema 1 NLP stays the NLP it always was."""
    if not system.n_path:
        return jnp.zeros((0,), dtype=jnp.result_type(xs))
    g = jax.vmap(lambda x, u, t: system.path_constraints(x, u, t, params))(xs, us, jnp.asarray(ts))
    return (g / jnp.asarray(path_scale(system))).ravel()


def path_bounds(system: System, points: int) -> tuple[np.ndarray, np.ndarray]:
    """The bounds of :func:`path_rows` at ``points`` points: path_lower / scale, path_upper / scale, tiled."""
    scale = path_scale(system)
    lo = np.asarray(system.path_lower, dtype=np.float64) / scale
    hi = np.asarray(system.path_upper, dtype=np.float64) / scale
    return np.tile(lo, points), np.tile(hi, points)


def final_time_variable(system: System) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The free final time as the last decision variable: ``(lower, upper, scale, guess)``, each of shape (1,), or
    (0,) when the horizon is fixed. Its nominal scale is the guess: the bounds of a minimum-time problem are often
    wide ([0.1, 10] around T* = 2), and the largest would make the variable look ten times smaller than it is."""
    if not system.free_horizon:
        empty = np.zeros(0)
        return empty, empty, empty, empty
    lo, hi = (float(b) for b in system.horizon_bounds)
    guess = float(system.horizon_guess if system.horizon_guess is not None else system.horizon)
    scale = abs(guess) if guess != 0.0 else nominal_scale(np.array([lo]), np.array([hi]))[0]
    return np.array([lo]), np.array([hi]), np.array([scale]), np.array([guess])
