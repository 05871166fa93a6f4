"""Multiple shooting: node states and controls are decisions; continuity between intervals is a constraint."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..integrators import RK4, AbstractIntegrator
from ..nlp import NLP
from ..system import System
from .base import AbstractTranscription, Transcribed
from .grid import Grid, check_grid, grid_argument, node_times
from .nlp_parts import path_rows, sparsity
from .stage_structure import multiple_shooting_structure

__all__ = ["MultipleShooting"]


@dataclasses.dataclass(frozen=True)
class MultipleShooting(AbstractTranscription):
    """Direct multiple shooting with M intervals of S integrator steps each (N = M S steps in all).

    Decision: the states X_1..X_M at the shooting nodes t_{jS} (X_0 = data.x0 is not a decision) and the
    controls u_0..u_N at *every* step node t_k (k T / N, or T grid[k] for a ``grid`` of N = M S intervals: the
    integrator steps follow it), linearly interpolated in between, so the control
    parametrisation is the same as single shooting with N intervals and the two have the same optimum when they
    share an integrator. On interval j the integrator runs S steps from X_j, giving x_end,j, and

        minimise    phi(X_M, T) + sum_j C_j,       C_j = int over interval j of L dt (extra state, same integrator)
        subject to  (x_end,j - X_{j+1}) / s = 0    j = 0..M-1   (continuity defects, divided by the state scale s)
                    X_M,i = x_final,i               for every state with a required final value
                    g_lo <= g(x_k, u_k, t_k) <= g_hi   k = 0..N  (path constraints, scaled; x_k from the rollouts)
                    x_lower <= X_j <= x_upper,  u_lower <= u_k <= u_upper   (bounds on every node)
                    T_lower <= T <= T_upper   (a free final time)

    Path constraints hold at every control node: at a shooting node the node variable X_j, between them the state
    the interval's rollout reaches (so row k depends on its interval's start X_j and the controls up to u_k only).

    Layout of z: ``[X_1..X_M (M n), u_0..u_N ((N + 1) m), T (free final time only)]``. The constraint Jacobian is
    block-banded: defect j depends densely on X_j and on the S + 1 controls of interval j, and only diagonally on
    X_{j+1}; the column of a free T is dense in the defect and path rows.

    Attributes:
        intervals: M, the number of shooting intervals.
        steps_per_interval: S, integrator steps (and control intervals) per shooting interval.
        integrator: the one-step method.
        grid: None (uniform), or the N + 1 normalised control nodes 0 = s_0 < ... < s_N = 1 (see ``grid.py``);
            every S-th is a shooting node. ``MultipleShooting.on_grid(grid)`` sets ``intervals`` from it.
    """

    label: ClassVar[str] = "multiple_shooting"

    intervals: int = 20
    steps_per_interval: int = 5
    integrator: AbstractIntegrator = RK4()
    grid: Grid | None = None

    @classmethod
    def on_grid(cls, intervals, **options) -> "MultipleShooting":
        """``intervals`` = N control intervals (or a grid of N + 1 node positions), cut into shooting intervals of
        ``steps_per_interval`` steps each: by default the largest of 5, 4, 3, 2, 1 that divides N, so ``on_grid(100)``
        is ``SingleShooting(intervals=100)``'s control grid in 20 shooting intervals of 5 steps."""
        intervals, grid = grid_argument(intervals)
        if grid is not None:
            options["grid"] = grid
        if intervals < 1:
            raise ValueError(f"MultipleShooting: the control grid needs at least 1 interval, got {intervals}")
        steps = options.pop("steps_per_interval", None)
        if steps is None:
            steps = next(s for s in (5, 4, 3, 2, 1) if intervals % s == 0)
        if intervals % steps:
            raise ValueError(f"MultipleShooting: {intervals} control intervals cannot be cut into shooting intervals "
                             f"of {steps} steps; choose a multiple of {steps}")
        return cls(intervals=intervals // steps, steps_per_interval=steps, **options)

    def __post_init__(self):
        if self.intervals < 1 or self.steps_per_interval < 1:
            raise ValueError(
                f"MultipleShooting: intervals and steps_per_interval must be at least 1, "
                f"got {self.intervals} and {self.steps_per_interval}"
            )
        grid = check_grid("MultipleShooting", self.grid, self.intervals * self.steps_per_interval,
                          f"intervals * steps_per_interval = {self.intervals} * {self.steps_per_interval}")
        object.__setattr__(self, "grid", grid)

    @property
    def steps_per_mesh_interval(self) -> int:
        # Refinement splits shooting intervals, each keeping its S steps (see refine.py).
        return self.steps_per_interval

    def transcribe(self, system: System) -> NLP:
        return _Transcribed(self, system).nlp()

    def sample_parts(self, system, states, controls, T):
        S = self.steps_per_interval
        times, _ = node_times(self.grid, self.intervals * S, T)
        return [states(times[S::S]), controls(times)]


class _Transcribed(Transcribed):
    """Multiple shooting's NLP for one system."""

    def __init__(self, method: MultipleShooting, system: System):
        self.M, self.S = method.intervals, method.steps_per_interval
        super().__init__(method, system, self.M * self.S)
        self.shooting_times = self.times[::self.S]  # shooting nodes t_0..t_M
        # The control nodes of each interval, (M, S+1).
        self.window = np.arange(self.M)[:, None] * self.S + np.arange(self.S + 1)[None, :]
        self.nX, self.nU = self.M * self.n, (self.N + 1) * self.m

    def clock(self, z):
        """(T, node times, each interval's start or nodes): constants, or from the decision T."""
        T, ts, _ = super().clock(z)
        if self.free:
            return T, ts, ts[self.window]
        # Each interval's rollout starts from its time (uniform grid: t_j and the step h, as always) or steps
        # through its own S + 1 nodes (a grid).
        return T, ts, jnp.asarray(self.shooting_times[:-1] if self.method.grid is None else self.times[self.window])

    def split(self, z):
        nX, nU = self.nX, self.nU
        return jnp.reshape(z[:nX], (self.M, self.n)), jnp.reshape(z[nX : nX + nU], (self.N + 1, self.m))

    def starts_and_windows(self, z, data):
        X, U = self.split(z)
        starts = jnp.concatenate([jnp.asarray(data.x0)[None], X[:-1]], axis=0)
        return X, U, starts, U[self.window]

    def node_states(self, X, xs):
        # Each interval's own start is the node variable; its end is dropped for the next node (any defect
        # shows as a jump there, not hidden by overwriting the node).
        return jnp.concatenate([jnp.reshape(xs[:, :self.S], (self.N, self.n)), X[-1:]], axis=0)

    def constraint_rows(self, X, U, xs, ts, params):
        return jnp.concatenate([((xs[:, -1] - X) / self.sx).ravel(), X[-1, self.fixed] - self.final,
                                path_rows(self.system, params, self.node_states(X, xs), U, ts)])

    def objective_and_constraints(self, z, data):
        params = data.params
        f, L = self.fields(params)
        T, ts, when = self.clock(z)
        X, U, starts, Uw = self.starts_and_windows(z, data)
        shoot = lambda x, t, u: self.run(f, x, t, u, L=L)  # noqa: E731
        xs, costs = jax.vmap(shoot)(starts, when, Uw)
        return (jnp.sum(costs[:, -1]) + self.system.terminal_cost(X[-1], T, params),
                self.constraint_rows(X, U, xs, ts, params))

    def rollouts(self, z, data):
        """(X, U, node times, each interval's states (M, S+1, n)), without the cost state: the cheaper rollout when
        only the rows are wanted."""
        f, _ = self.fields(data.params)
        _, ts, when = self.clock(z)
        X, U, starts, Uw = self.starts_and_windows(z, data)
        return X, U, ts, jax.vmap(lambda x, t, u: self.run(f, x, t, u))(starts, when, Uw)

    def constraints(self, z, data):
        X, U, ts, xs = self.rollouts(z, data)
        return self.constraint_rows(X, U, xs, ts, data.params)

    def unravel(self, z, data):
        X, U, ts, xs = self.rollouts(z, data)
        return jnp.asarray(ts), self.node_states(X, xs), U

    def sparsity_blocks(self, n_T: int) -> list:
        """The Jacobian's structurally non-zero blocks: defects, final values, path rows (``n_T``: 1 with a free
        final time, whose column every row has, else 0)."""
        M, S, N, n, m, nX, window = self.M, self.S, self.N, self.n, self.m, self.nX, self.window
        n_path = self.system.n_path
        T_col = np.arange(nX + self.nU, nX + self.nU + n_T)  # empty for a fixed horizon
        blocks = []
        for j in range(M):
            rows = j * n + np.arange(n)
            if j > 0:
                blocks.append((rows, (j - 1) * n + np.arange(n), False))
            blocks.append((rows, j * n + np.arange(n), True))
            blocks.append((rows, np.concatenate([nX + (window[j][:, None] * m + np.arange(m)).ravel(), T_col]), False))
        for r, i in enumerate(self.fixed):
            blocks.append((np.array([M * n + r]), np.array([(M - 1) * n + i]), True))
        first_path = M * n + self.fixed.size
        for k in range(N + 1):
            j, i = min(k // S, M - 1), k - min(k // S, M - 1) * S  # node k is step i of interval j (N: j = M-1, S)
            rows = first_path + k * n_path + np.arange(n_path)
            start = [] if j == 0 else [(j - 1) * n + np.arange(n)]  # X_j (x0 is not a decision)
            end = [(M - 1) * n + np.arange(n)] if k == N else []  # the last node is X_M itself
            us = nX + (window[j][: i + 1, None] * m + np.arange(m)).ravel()
            blocks.append((rows, np.concatenate(start + end + [us, T_col]), False))
        return blocks

    def nlp(self) -> NLP:
        return self.node_nlp(
            self.M, self.N + 1, self.N + 1, objective=self.objective, constraints=self.constraints,
            initial_guess=self.initial_guess_of(self.shooting_times[1:], self.N + 1), unravel=self.unravel,
            jacobian_sparsity=sparsity(self.sparsity_blocks(self.T_lo.size)),
            name=self.name(f"M={self.M}, S={self.S}, {type(self.method.integrator).__name__}"),
            objective_and_constraints=self.objective_and_constraints,
            stage_structure=multiple_shooting_structure(self.M, self.S, self.n, self.m, self.fixed.size,
                                                        self.system.n_path, self.T_lo.size),
        )
