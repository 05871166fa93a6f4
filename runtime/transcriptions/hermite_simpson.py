"""Hermite-Simpson direct collocation, compressed form."""

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

__all__ = ["HermiteSimpson"]


@dataclasses.dataclass(frozen=True)
class HermiteSimpson(AbstractTranscription):
    """Hermite-Simpson collocation on a grid of N intervals (order 4), uniform unless ``grid`` is given, in
    compressed form.

    Decision: states x_1..x_N and controls u_0..u_N at the nodes t_k (x_0 = data.x0; t_k = k T / N, or
    T grid[k]; h_k = t_{k+1} - t_k), and a control u_{k+1/2} at each interval midpoint. The midpoint state is *not*
    a decision: it is the cubic Hermite interpolant of the two nodes,

        x_{k+1/2} = (x_k + x_{k+1}) / 2 + (h_k / 8)(f_k - f_{k+1}),   f_{k+1/2} = f(x_{k+1/2}, u_{k+1/2}, t_k + h_k/2),

    and with the Simpson rule for both the dynamics and the cost,

        minimise    phi(x_N, T) + sum_k (h_k / 6)(L_k + 4 L_{k+1/2} + L_{k+1})
        subject to  (x_{k+1} - x_k - (h_k / 6)(f_k + 4 f_{k+1/2} + f_{k+1})) / s = 0     k = 0..N-1
                    x_N,i = x_final,i  (required final values)
                    g_lo <= g(x_p, u_p, t_p) <= g_hi   at the 2N + 1 nodes and midpoints p  (path constraints)
                    x_lower <= x_k <= x_upper,  u_lower <= u_k, u_{k+1/2} <= u_upper   (bounds on every node)
                    T_lower <= T <= T_upper   (a free final time).

    Path constraints hold at the nodes and at the midpoints (with the Hermite midpoint state), in the order of the
    half-step grid; a midpoint row depends on both nodes of its interval and its three controls.

    A free final time (``system.free_horizon``) is the last entry of z; t_k = T s_k and h_k = T (s_{k+1} - s_k)
    (``grid.free_node_times``: the time scaling to tau in [0, 1]), and phi is evaluated at T.

    NOTE: the compressed form (Kelly 2017, sec. 4) has n fewer variables and n fewer constraints per interval than
    the separated form, which matters for the dense solvers; the price is that state bounds hold at the nodes only,
    not at the interpolated midpoints, and each defect block is dense in (x_k, x_{k+1}).

    Layout of z: ``[x_1..x_N (N n), u_0..u_N ((N + 1) m), u_{1/2}..u_{N-1/2} (N m), T (free final time
    only)]``. ``unravel`` returns the 2N + 1 points of the half-step grid (nodes and midpoints interleaved), so a
    solution can be re-simulated with :func:`~myriad.runtime.simulate.simulate` on that grid.

    Attributes:
        intervals: N.
        grid: None (uniform), or the N + 1 normalised node positions 0 = s_0 < ... < s_N = 1 (see ``grid.py``);
            ``HermiteSimpson.on_grid(grid)`` sets ``intervals`` from it.

    References:
        M. Kelly, "An introduction to trajectory optimization: how to do your own direct collocation",
        SIAM Review 59(4), 2017.
    """

    label: ClassVar[str] = "hermite_simpson"
    quadrature: ClassVar[str] = "simpson"
    order: ClassVar[int] = 4

    intervals: int = 50
    grid: Grid | None = None

    def _times(self, horizon: float):
        """Node times, midpoint times, the 2N + 1 points of the half-step grid, and the step (see grid.py)."""
        N = self.intervals
        times, h = node_times(self.grid, N, horizon)
        if self.grid is None:  # as always: the uniform half-step grid
            return times, times[:-1] + 0.5 * h, np.linspace(0.0, float(horizon), 2 * N + 1), h
        mids = times[:-1] + 0.5 * h
        half = np.empty(2 * N + 1)
        half[0::2], half[1::2] = times, mids
        return times, mids, half, h

    def transcribe(self, system: System) -> NLP:
        N = self.intervals
        n, m = system.n_states, system.n_controls
        T_fixed = float(system.horizon)
        times, mid_times, half_times, h = self._times(T_fixed)
        positions = self.positions()
        free = system.free_horizon
        arrays = system.arrays()
        fixed, final = final_value_rows(system)
        sx, su = state_scale(system), control_scale(system)
        T_lo, T_hi, T_scale, T_guess = final_time_variable(system)
        nX, nU = N * n, (N + 1) * m

        def clock(z):
            """(T, node times, midpoint times, steps): constants, or from the decision T (grid.free_node_times)."""
            if free:
                ts, hs = free_node_times(positions, z[-1])
                return z[-1], ts, ts[:-1] + 0.5 * hs, hs
            return T_fixed, jnp.asarray(times), jnp.asarray(mid_times), h

        def split(z, data):
            X = jnp.reshape(z[:nX], (N, n))
            xs = jnp.concatenate([jnp.asarray(data.x0)[None], X], axis=0)
            return xs, jnp.reshape(z[nX : nX + nU], (N + 1, m)), jnp.reshape(z[nX + nU : nX + nU + N * m], (N, m))

        def collocate(z, data):
            params = data.params
            f = jax.vmap(lambda x, u, t: system.dynamics(x, u, t, params))
            _, ts, tms, hs = clock(z)
            xs, us, ums = split(z, data)
            fs = f(xs, us, ts)
            xms = 0.5 * (xs[:-1] + xs[1:]) + (column(hs) / 8.0) * (fs[:-1] - fs[1:])
            return xs, us, ums, xms, fs, f(xms, ums, tms)

        def objective(z, data):
            params = data.params
            L = jax.vmap(lambda x, u, t: system.running_cost(x, u, t, params))
            T, ts, tms, hs = clock(z)
            xs, us, ums, xms, _, _ = collocate(z, data)
            Ls = L(xs, us, ts)
            Lms = L(xms, ums, tms)
            quad = weighted_sum(hs, Ls[:-1] + 4.0 * Lms + Ls[1:], lambda h: h / 6.0)
            return quad + system.terminal_cost(xs[-1], T, params)

        def constraints(z, data):
            _, ts, tms, hs = clock(z)
            xs, us, ums, xms, fs, fms = collocate(z, data)
            defects = (xs[1:] - xs[:-1] - (column(hs) / 6.0) * (fs[:-1] + 4.0 * fms + fs[1:])) / sx
            half = _interleave(ts[:, None], tms[:, None])[:, 0]
            path = path_rows(system, data.params, _interleave(xs, xms), _interleave(us, ums), half)
            return jnp.concatenate([defects.ravel(), xs[-1, fixed] - final, path])

        def unravel(z, data):
            _, ts, tms, _ = clock(z)
            xs, us, ums, xms, _, _ = collocate(z, data)
            half = _interleave(ts[:, None], tms[:, None])[:, 0] if free else jnp.asarray(half_times)
            return half, _interleave(xs, xms), _interleave(us, ums)

        def initial_guess(data):
            X = guess_states(system, data.x0, times[1:])
            U = guess_controls(system, 2 * N + 1)
            return jnp.concatenate([X.ravel(), jnp.asarray(U[: N + 1].ravel()), jnp.asarray(U[N + 1 :].ravel()),
                                    jnp.asarray(T_guess)])

        x_lo, x_hi = node_state_bounds(system, N)
        p_lo, p_hi = path_bounds(system, 2 * N + 1)
        return NLP(
            objective=objective,
            constraints=constraints,
            c_lower=np.concatenate([np.zeros(N * n + fixed.size), p_lo]),
            c_upper=np.concatenate([np.zeros(N * n + fixed.size), p_hi]),
            z_lower=np.concatenate([x_lo, np.tile(arrays["u_lower"], 2 * N + 1), T_lo]),
            z_upper=np.concatenate([x_hi, np.tile(arrays["u_upper"], 2 * N + 1), T_hi]),
            initial_guess=initial_guess,
            unravel=unravel,
            jacobian_sparsity=sparsity(_blocks(N, n, m, fixed, system.n_path, T_lo.size)),
            z_scale=np.concatenate([np.tile(sx, N), np.tile(su, 2 * N + 1), T_scale]),
            name=f"{system.name}/hermite_simpson(N={N}{'' if self.grid is None else ', graded'}"
                 f"{', free T' if free else ''})",
        )

    def sample(self, system, states, controls, final_time=None):
        T = sample_final_time(system, final_time)
        times, mids, _, _ = self._times(T)
        X = np.asarray(states(times[1:]), dtype=np.float64)
        U = np.asarray(controls(times), dtype=np.float64)
        Um = np.asarray(controls(mids), dtype=np.float64)
        return np.concatenate([X.ravel(), U.ravel(), Um.ravel()] + ([np.array([T])] if system.free_horizon else []))


def _interleave(nodes, mids):
    """Nodes (N + 1, d) and midpoints (N, d) as the 2N + 1 points of the half-step grid."""
    N = mids.shape[0]
    both = jnp.concatenate([nodes[:-1, None], mids[:, None]], axis=1)  # (N, 2, d)
    return jnp.concatenate([jnp.reshape(both, (2 * N, -1)), nodes[-1:]], axis=0)


def _blocks(N: int, n: int, m: int, fixed: np.ndarray, n_path: int, n_T: int) -> list:
    """The Jacobian's structurally non-zero blocks: defects, final values, path rows on the half-step grid
    (``n_T``: 1 with a free final time, whose column every row has, else 0)."""
    nX, nU = N * n, (N + 1) * m
    T_col = np.arange(nX + nU + N * m, nX + nU + N * m + n_T)
    blocks = collocation_blocks(N, n, m, fixed, T_col, midpoints=True)
    for p in range(2 * N + 1):  # the half-step grid: node p / 2, or the midpoint of interval (p - 1) / 2
        rows = N * n + fixed.size + p * n_path + np.arange(n_path)
        k = p // 2
        if p % 2 == 0:
            cols = ([np.arange((k - 1) * n, k * n)] if k > 0 else []) + [nX + np.arange(k * m, (k + 1) * m)]
        else:
            cols = ([np.arange((k - 1) * n, k * n)] if k > 0 else []) + [
                np.arange(k * n, (k + 1) * n), nX + np.arange(k * m, (k + 2) * m),
                nX + nU + np.arange(k * m, (k + 1) * m)]
        blocks.append((rows, np.concatenate(cols + [T_col]), False))
    return blocks
