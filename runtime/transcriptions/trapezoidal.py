"""Trapezoidal direct collocation."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from ..nlp import NLP
from ..system import System
from .base import AbstractTranscription, Transcribed
from .grid import Grid, column, node_times, weighted_sum
from .nlp_parts import path_rows

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
        return _Transcribed(self, system, self.intervals).nlp()

    def sample_parts(self, system, states, controls, T):
        times, _ = node_times(self.grid, self.intervals, T)
        return [states(times[1:]), controls(times)]


class _Transcribed(Transcribed):
    """Trapezoidal collocation's NLP for one system."""

    def objective(self, z, data):
        params = data.params
        xs, us, _ = self.collocation_nodes(z, data)
        T, ts, hs = self.clock(z)
        Ls = jax.vmap(self.fields(params)[1])(xs, us, ts)
        quad = weighted_sum(hs, Ls[:-1] + Ls[1:], lambda h: 0.5 * h)
        return quad + self.system.terminal_cost(xs[-1], T, params)

    def constraints(self, z, data):
        params = data.params
        xs, us, _ = self.collocation_nodes(z, data)
        _, ts, hs = self.clock(z)
        fs = jax.vmap(self.fields(params)[0])(xs, us, ts)
        defects = (xs[1:] - xs[:-1] - 0.5 * column(hs) * (fs[:-1] + fs[1:])) / self.sx
        return jnp.concatenate([defects.ravel(), xs[-1, self.fixed] - self.final,
                                path_rows(self.system, params, xs, us, ts)])

    def unravel(self, z, data):
        xs, us, _ = self.collocation_nodes(z, data)
        return self.clock(z)[1], xs, us

    def nlp(self) -> NLP:
        return self.collocation_nlp()

