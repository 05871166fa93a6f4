"""Non-uniform grids: the ``grid`` option of every direct transcription and its node times.

A grid is a tuple of normalised node positions 0 = s_0 < s_1 < ... < s_N = 1 (a tuple: transcriptions are hashable,
static ``jax.jit`` arguments and keys of the NLP cache); on a horizon T the nodes are t_k = T s_k. ``grid=None`` is
the uniform grid t_k = k T / N, computed exactly as before grids existed (``np.linspace`` and the scalar step T / N),
so a transcription without a grid builds bit for bit the NLP it always did.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import jax.numpy as jnp
import numpy as np

__all__ = ["Grid", "check_grid", "column", "free_node_times", "grid_argument", "node_times", "weighted_sum"]

Grid = tuple[float, ...]


def check_grid(owner: str, grid: Sequence[float] | None, intervals: int, count: str = "intervals") -> Grid | None:
    """``grid`` (any sequence of numbers, or None) as a tuple of floats, after checking it is a grid of ``intervals``
    intervals on [0, 1], the size the field ``count`` of the class ``owner`` says (ValueError: what is wrong and how
    to fix it)."""
    if grid is None:
        return None
    try:
        s = np.asarray(grid, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: grid must be a sequence of numbers in [0, 1], got {grid!r}") from None
    if s.ndim != 1 or s.size < 2:
        raise ValueError(f"{owner}: grid must be a flat sequence of at least 2 node positions (0, ..., 1), "
                         f"got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError(f"{owner}: grid has non-finite node positions")
    if s[0] != 0.0 or s[-1] != 1.0:
        raise ValueError(f"{owner}: grid must start at 0 and end at 1 (positions normalised by the horizon), "
                         f"got {s[0]:g} ... {s[-1]:g}")
    bad = np.flatnonzero(np.diff(s) <= 0.0)
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"{owner}: grid must be strictly increasing; positions {k} and {k + 1} are "
                         f"{s[k]:g} and {s[k + 1]:g}")
    if s.size - 1 != intervals:
        raise ValueError(f"{owner}: the grid has {s.size - 1} intervals but {count} = {intervals}; build it with "
                         f"{owner}.on_grid(grid), which takes the size from the grid")
    return tuple(float(v) for v in s)


def node_times(grid: Grid | None, intervals: int, horizon: float) -> tuple[np.ndarray, Any]:
    """The node times t_0..t_N and the step: the float T / N on the uniform grid, else the (N,) steps.

    The uniform case returns exactly what the transcriptions always computed, so their NLPs stay bit for bit the
    same; callers branch on ``isinstance(h, float)`` where a formula differs (a sum of h-weighted terms).
    """
    T = float(horizon)
    if grid is None:
        return np.linspace(0.0, T, intervals + 1), T / intervals
    times = T * np.asarray(grid, dtype=np.float64)
    return times, np.diff(times)


def free_node_times(positions: np.ndarray, T: Any) -> tuple[Any, Any]:
    """Node times and steps when the final time T is a decision variable (traced): t_k = T s_k and the (N,) steps
    h_k = T (s_{k+1} - s_k).

    This is the time scaling t = T tau of a free final time: one step h_k of x' = f(x, u, t) is the step
    s_{k+1} - s_k in tau of dx/dtau = T f(x, u, T tau), and h_k L_k is (s_{k+1} - s_k) T L_k, so every formula of a
    transcription stays as written, with T inside its times and steps. The steps are an array even on the uniform
    grid, so callers take their grid branch (``weighted_sum``, ``column``, a rollout through the node times).
    """
    s = np.asarray(positions, dtype=np.float64)
    return T * jnp.asarray(s), T * jnp.asarray(np.diff(s))


def grid_argument(nodes: int | Sequence[float]) -> tuple[int, Grid | None]:
    """``on_grid``'s argument as (intervals, grid): an int N is the uniform grid of N intervals, a sequence of node
    positions is that grid (checked by the transcription's ``__post_init__``)."""
    if isinstance(nodes, (int, np.integer)) and not isinstance(nodes, bool):
        return int(nodes), None
    grid = tuple(float(v) for v in np.asarray(nodes, dtype=np.float64).ravel())
    return len(grid) - 1, grid


def weighted_sum(h: Any, terms: Any, weight: Callable[[Any], Any]) -> Any:
    """sum_k weight(h_k) terms_k: ``weight(h) * sum(terms)`` for the uniform float step (the formula the NLPs always
    used, so they stay bit for bit the same), ``sum(weight(h) * terms)`` for the (N,) steps of a grid."""
    if isinstance(h, float):
        return weight(h) * jnp.sum(terms)
    return jnp.sum(weight(jnp.asarray(h)) * terms)


def column(h: Any) -> Any:
    """The step as a factor of (N, n) per-interval arrays: the float itself, or the steps as an (N, 1) column."""
    return h if isinstance(h, float) else jnp.asarray(h)[:, None]
