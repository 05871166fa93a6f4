"""Trapezoidal direct collocation."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..nlp import NLP
from ..system import System
from .base import AbstractTranscription, sample_final_time
from .grid import Grid, column, free_node_times, node_times, weighted_sum
from .nlp_parts import (
    collocation_blocks,
    final_time_variable,
    final_value_rows,
    guess_controls,
    guess_states,
    node_state_bounds,
    path_bounds,
    path_rows,
    sparsity,
)
from .nominal_scales import control_scale, state_scale

__all__ = ["Trapezoidal"]


@dataclasses.dataclass(frozen=True)
class Trapezoidal(AbstractTranscription):
    """Trapezoidal collocation on a grid of N intervals (order 2), uniform unless ``grid`` is given.

    Decision: states x_1..x_N and controls u_0..u_N at the nodes t_k (x_0 = data.x0): t_k = k T / N, or
    t_k = T grid[k]; h_k = t_{k+1} - t_k. With f_k = f(x_k, u_k, t_k) and L_k = L(x_k, u_k, t_k):

        minimise    phi(x_N, T) + sum_k (h_k / 2)(L_k + L_{k+1})
        subject to  (x_{k+1} - x_k - (h_k / 2)(f_k + f_{k+1})) / s = 0     k = 0..N-1
                    x_N,i = x_final,i  (required final values)
                    g_lo <= g(x_k, u_k, t_k) <= g_hi    k = 0..N  (path constraints, divided by their scale)
                    x_lower <= x_k <= x_upper,  u_lower <= u_k <= u_upper   (bounds on every node)
                    T_lower <= T <= T_upper   (a free final time)

    A free final time (``system.free_horizon``) is the last entry of z; t_k = T s_k and h_k = T (s_{k+1} - s_k)
    (``grid.free_node_times``: the time scaling to tau in [0, 1]), and phi is evaluated at T.

    Layout of z: ``[x_1..x_N (N n), u_0..u_N ((N + 1) m), T (free final time only)]``; defect k depends on x_k,
    x_{k+1}, u_k, u_{k+1} (and T), path row k on x_k, u_k (and T).

    Attributes:
        intervals: N.
        grid: None (uniform), or the N + 1 normalised node positions 0 = s_0 < ... < s_N = 1 (see ``grid.py``);
            ``Trapezoidal.on_grid(grid)`` sets ``intervals`` from it.
    """

    label: ClassVar[str] = "trapezoidal"
    quadrature: ClassVar[str] = "trapezoidal"
    order: ClassVar[int] = 2

    intervals: int = 100
    grid: Grid | None = None

    def transcribe(self, system: System) -> NLP:
        N = self.intervals
        n, m = system.n_states, system.n_controls
        T_fixed = float(system.horizon)
        times, h = node_times(self.grid, N, T_fixed)
        positions = self.positions()
        free = system.free_horizon
        arrays = system.arrays()
        fixed, final = final_value_rows(system)
        sx, su = state_scale(system), control_scale(system)
        T_lo, T_hi, T_scale, T_guess = final_time_variable(system)
        nX, nU = N * n, (N + 1) * m

        def clock(z):
            """(T, node times, steps): constants, or from the decision T (see grid.free_node_times)."""
            if free:
                return (z[-1], *free_node_times(positions, z[-1]))
            return T_fixed, jnp.asarray(times), h

        def nodes(z, data):
            X = jnp.reshape(z[:nX], (N, n))
            xs = jnp.concatenate([jnp.asarray(data.x0)[None], X], axis=0)
            return xs, jnp.reshape(z[nX : nX + nU], (N + 1, m))

        def objective(z, data):
            params = data.params
            xs, us = nodes(z, data)
            T, ts, hs = clock(z)
            Ls = jax.vmap(lambda x, u, t: system.running_cost(x, u, t, params))(xs, us, ts)
            quad = weighted_sum(hs, Ls[:-1] + Ls[1:], lambda h: 0.5 * h)
            return quad + system.terminal_cost(xs[-1], T, params)

        def constraints(z, data):
            params = data.params
            xs, us = nodes(z, data)
            _, ts, hs = clock(z)
            fs = jax.vmap(lambda x, u, t: system.dynamics(x, u, t, params))(xs, us, ts)
            defects = (xs[1:] - xs[:-1] - 0.5 * column(hs) * (fs[:-1] + fs[1:])) / sx
            return jnp.concatenate([defects.ravel(), xs[-1, fixed] - final, path_rows(system, params, xs, us, ts)])

        def unravel(z, data):
            xs, us = nodes(z, data)
            return clock(z)[1], xs, us

        def initial_guess(data):
            X = guess_states(system, data.x0, times[1:])
            return jnp.concatenate([X.ravel(), jnp.asarray(guess_controls(system, N + 1).ravel()),
                                    jnp.asarray(T_guess)])

        x_lo, x_hi = node_state_bounds(system, N)
        p_lo, p_hi = path_bounds(system, N + 1)
        return NLP(
            objective=objective,
            constraints=constraints,
            c_lower=np.concatenate([np.zeros(N * n + fixed.size), p_lo]),
            c_upper=np.concatenate([np.zeros(N * n + fixed.size), p_hi]),
            z_lower=np.concatenate([x_lo, np.tile(arrays["u_lower"], N + 1), T_lo]),
            z_upper=np.concatenate([x_hi, np.tile(arrays["u_upper"], N + 1), T_hi]),
            initial_guess=initial_guess,
            unravel=unravel,
            jacobian_sparsity=sparsity(_blocks(N, n, m, fixed, system.n_path, T_lo.size)),
            z_scale=np.concatenate([np.tile(sx, N), np.tile(su, N + 1), T_scale]),
            name=f"{system.name}/trapezoidal(N={N}{'' if self.grid is None else ', graded'}"
                 f"{', free T' if free else ''})",
        )

    def sample(self, system, states, controls, final_time=None):
        T = sample_final_time(system, final_time)
        times, _ = node_times(self.grid, self.intervals, T)
        X = np.asarray(states(times[1:]), dtype=np.float64)
        U = np.asarray(controls(times), dtype=np.float64)
        return np.concatenate([X.ravel(), U.ravel()] + ([np.array([T])] if system.free_horizon else []))


def _blocks(N: int, n: int, m: int, fixed: np.ndarray, n_path: int, n_T: int) -> list:
    """The Jacobian's structurally non-zero blocks: defects, final values, path rows (``n_T``: 1 with a free final
    time, whose column every row has, else 0)."""
    nX, nU = N * n, (N + 1) * m
    T_col = np.arange(nX + nU, nX + nU + n_T)  # empty for a fixed T
    blocks = collocation_blocks(N, n, m, fixed, T_col)
    for k in range(N + 1):
        rows = N * n + fixed.size + k * n_path + np.arange(n_path)
        x_k = [np.arange((k - 1) * n, k * n)] if k > 0 else []
        blocks.append((rows, np.concatenate(x_k + [nX + np.arange(k * m, (k + 1) * m), T_col]), False))
    return blocks
