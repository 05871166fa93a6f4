"""Hermite-Simpson direct collocation, compressed form."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..nlp import NLP
from ..system import System
from .base import AbstractTranscription, Transcribed
from .grid import Grid, column, node_times, weighted_sum
from .nlp_parts import path_rows

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
        return _Transcribed(self, system, self.intervals).nlp()

    def sample_parts(self, system, states, controls, T):
        times, mids, _, _ = self._times(T)
        return [states(times[1:]), controls(times), controls(mids)]


class _Transcribed(Transcribed):
    """Hermite-Simpson collocation's NLP for one system."""

    def __init__(self, method: HermiteSimpson, system: System, N: int):
        super().__init__(method, system, N)
        _, self.mid_times, self.half_times, _ = method._times(self.T_fixed)

    def clock(self, z):
        """(T, node times, midpoint times, steps): constants, or from the decision T (grid.free_node_times)."""
        T, ts, hs = super().clock(z)
        return T, ts, ts[:-1] + 0.5 * hs if self.free else jnp.asarray(self.mid_times), hs

    def collocate(self, z, data):
        f = jax.vmap(self.fields(data.params)[0])
        _, ts, tms, hs = self.clock(z)
        xs, us, rest = self.collocation_nodes(z, data)
        ums = jnp.reshape(rest[: self.N * self.m], (self.N, self.m))
        fs = f(xs, us, ts)
        xms = 0.5 * (xs[:-1] + xs[1:]) + (column(hs) / 8.0) * (fs[:-1] - fs[1:])
        return xs, us, ums, xms, fs, f(xms, ums, tms)

    def objective(self, z, data):
        params = data.params
        L = jax.vmap(self.fields(params)[1])
        T, ts, tms, hs = self.clock(z)
        xs, us, ums, xms, _, _ = self.collocate(z, data)
        Ls = L(xs, us, ts)
        Lms = L(xms, ums, tms)
        quad = weighted_sum(hs, Ls[:-1] + 4.0 * Lms + Ls[1:], lambda h: h / 6.0)
        return quad + self.system.terminal_cost(xs[-1], T, params)

    def constraints(self, z, data):
        _, ts, tms, hs = self.clock(z)
        xs, us, ums, xms, fs, fms = self.collocate(z, data)
        defects = (xs[1:] - xs[:-1] - (column(hs) / 6.0) * (fs[:-1] + 4.0 * fms + fs[1:])) / self.sx
        half = _interleave(ts[:, None], tms[:, None])[:, 0]
        path = path_rows(self.system, data.params, _interleave(xs, xms), _interleave(us, ums), half)
        return jnp.concatenate([defects.ravel(), xs[-1, self.fixed] - self.final, path])

    def unravel(self, z, data):
        _, ts, tms, _ = self.clock(z)
        xs, us, ums, xms, _, _ = self.collocate(z, data)
        half = _interleave(ts[:, None], tms[:, None])[:, 0] if self.free else jnp.asarray(self.half_times)
        return half, _interleave(xs, xms), _interleave(us, ums)

    def nlp(self) -> NLP:
        return self.collocation_nlp(midpoints=True)


def _interleave(nodes, mids):
    """Nodes (N + 1, d) and midpoints (N, d) as the 2N + 1 points of the half-step grid."""
    N = mids.shape[0]
    both = jnp.concatenate([nodes[:-1, None], mids[:, None]], axis=1)  # (N, 2, d)
    return jnp.concatenate([jnp.reshape(both, (2 * N, -1)), nodes[-1:]], axis=0)

