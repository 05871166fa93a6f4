"""Multiple shooting: node states and controls are decisions; continuity between intervals is a constraint."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..integrators import RK4, AbstractIntegrator, rollout, rollout_with_cost
from ..nlp import NLP
from ..system import System
from ._common import (
    control_scale,
    final_value_rows,
    guess_controls,
    guess_states,
    node_state_bounds,
    sparsity,
    state_scale,
)
from .base import AbstractTranscription
from .grid import Grid, check_grid, grid_argument, node_times, rollout_on, rollout_with_cost_on

__all__ = ["MultipleShooting"]


@dataclasses.dataclass(frozen=True)
class MultipleShooting(AbstractTranscription):
    """Direct multiple shooting with M intervals of S integrator steps each (N = M S steps in all).

    Decision: the states X_1..X_M at the shooting nodes t_{jS} (X_0 = data.x0 is not a decision) and the
    controls u_0..u_N at *every* step node t_k (k T / N, or T grid[k] for a ``grid`` of N = M S intervals: the
    integrator steps follow it), linearly interpolated in between, so the control
    parametrisation is the same as single shooting with N intervals and the two have the same optimum when they
    share an integrator. On interval j the integrator runs S steps from X_j, giving x_end,j, and

        minimise    phi(X_M) + sum_j C_j,          C_j = int over interval j of L dt (extra state, same integrator)
        subject to  (x_end,j - X_{j+1}) / s = 0    j = 0..M-1   (continuity defects, divided by the state scale s)
                    X_M,i = x_final,i               for every state with a required final value
                    x_lower <= X_j <= x_upper,  u_lower <= u_k <= u_upper   (bounds on every node)

    Layout of z: ``[X_1..X_M (M n), u_0..u_N ((N + 1) m)]``. The constraint Jacobian is block-banded: defect j
    depends densely on X_j and on the S + 1 controls of interval j, and only diagonally on X_{j+1}.

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
        ``steps_per_interval`` steps each.

        Without ``steps_per_interval``, the default 5 steps per shooting interval (the largest of 5, 4, 3, 2, 1 that
        divides N), so ``on_grid(100)`` is 20 shooting intervals of 5 steps: the same control grid as
        ``SingleShooting(controls=100)``.
        """
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

    @property
    def quadrature(self) -> str:
        return self.integrator.label

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
    def grid_intervals(self) -> int:
        return self.intervals * self.steps_per_interval

    @property
    def order(self) -> int:
        return self.integrator.order

    @property
    def steps_per_mesh_interval(self) -> int:
        # Refinement splits shooting intervals, each keeping its S steps (see refine.py).
        return self.steps_per_interval

    def with_grid(self, grid) -> "MultipleShooting":
        steps = len(grid) - 1
        if steps % self.steps_per_interval:
            raise ValueError(f"MultipleShooting: a grid of {steps} steps cannot be cut into shooting intervals of "
                             f"{self.steps_per_interval} steps")
        return dataclasses.replace(self, intervals=steps // self.steps_per_interval, grid=tuple(grid))

    def transcribe(self, system: System) -> NLP:
        M, S = self.intervals, self.steps_per_interval
        N = M * S
        n, m = system.n_states, system.n_controls
        T = float(system.horizon)
        times, h = node_times(self.grid, N, T)
        shooting_times = times[::S]  # shooting nodes t_0..t_M
        window = np.arange(M)[:, None] * S + np.arange(S + 1)[None, :]  # control nodes of each interval, (M, S+1)
        # Each interval's rollout starts from its time (uniform grid: t_j and the step h, as always) or steps through
        # its own S + 1 nodes (a grid).
        when = shooting_times[:-1] if self.grid is None else times[window]
        arrays = system.arrays()
        fixed, final = final_value_rows(system)
        sx, su = state_scale(system), control_scale(system)
        integrator = self.integrator
        nX = M * n

        def split(z):
            return jnp.reshape(z[:nX], (M, n)), jnp.reshape(z[nX:], (N + 1, m))

        def run(f, x, ts, u):
            if self.grid is None:
                return rollout(integrator, f, x, ts, h, u)
            return rollout_on(integrator, f, x, ts, u)

        def run_with_cost(f, L, x, ts, u):
            if self.grid is None:
                return rollout_with_cost(integrator, f, L, x, ts, h, u)
            return rollout_with_cost_on(integrator, f, L, x, ts, u)

        def fields(params):
            f = lambda x, u, t: system.dynamics(x, u, t, params)  # noqa: E731
            L = lambda x, u, t: system.running_cost(x, u, t, params)  # noqa: E731
            return f, L

        def starts_and_windows(z, data):
            X, U = split(z)
            starts = jnp.concatenate([jnp.asarray(data.x0)[None], X[:-1]], axis=0)
            return X, U, starts, U[window]

        def constraint_rows(X, ends):
            return jnp.concatenate([((ends - X) / sx).ravel(), X[-1, fixed] - final])

        def objective_and_constraints(z, data):
            params = data.params
            f, L = fields(params)
            X, _, starts, Uw = starts_and_windows(z, data)
            shoot = lambda x, t, u: run_with_cost(f, L, x, t, u)  # noqa: E731
            xs, costs = jax.vmap(shoot)(starts, jnp.asarray(when), Uw)
            return jnp.sum(costs[:, -1]) + system.terminal_cost(X[-1], T, params), constraint_rows(X, xs[:, -1])

        def objective(z, data):
            return objective_and_constraints(z, data)[0]

        def constraints(z, data):
            # Without the cost state: the cheaper rollout when only the rows are wanted.
            f, _ = fields(data.params)
            X, _, starts, Uw = starts_and_windows(z, data)
            shoot = lambda x, t, u: run(f, x, t, u)[-1]  # noqa: E731
            return constraint_rows(X, jax.vmap(shoot)(starts, jnp.asarray(when), Uw))

        def unravel(z, data):
            f, _ = fields(data.params)
            X, U, starts, Uw = starts_and_windows(z, data)
            shoot = lambda x, t, u: run(f, x, t, u)  # noqa: E731
            xs = jax.vmap(shoot)(starts, jnp.asarray(when), Uw)  # (M, S+1, n)
            # Each interval's own start is the node variable; its end is dropped for the next node (any defect shows
            # as a jump there, not hidden by overwriting the node).
            states = jnp.concatenate([jnp.reshape(xs[:, :S], (N, n)), X[-1:]], axis=0)
            return jnp.asarray(times), states, U

        def initial_guess(data):
            X = guess_states(system, data.x0, shooting_times[1:])
            return jnp.concatenate([X.ravel(), jnp.asarray(guess_controls(system, N + 1).ravel())])

        blocks = []
        for j in range(M):
            rows = j * n + np.arange(n)
            if j > 0:
                blocks.append((rows, (j - 1) * n + np.arange(n), False))
            blocks.append((rows, j * n + np.arange(n), True))
            blocks.append((rows, nX + (window[j][:, None] * m + np.arange(m)).ravel(), False))
        for r, i in enumerate(fixed):
            blocks.append((np.array([M * n + r]), np.array([(M - 1) * n + i]), True))

        x_lo, x_hi = node_state_bounds(system, M)
        return NLP(
            objective=objective,
            constraints=constraints,
            c_lower=np.zeros(M * n + fixed.size),
            c_upper=np.zeros(M * n + fixed.size),
            z_lower=np.concatenate([x_lo, np.tile(arrays["u_lower"], N + 1)]),
            z_upper=np.concatenate([x_hi, np.tile(arrays["u_upper"], N + 1)]),
            initial_guess=initial_guess,
            unravel=unravel,
            jacobian_sparsity=sparsity(blocks),
            z_scale=np.concatenate([np.tile(sx, M), np.tile(su, N + 1)]),
            name=f"{system.name}/multiple_shooting(M={M}, S={S}, {type(integrator).__name__}"
                 f"{'' if self.grid is None else ', graded'})",
            objective_and_constraints=objective_and_constraints,
        )

    def sample(self, system, states, controls):
        S = self.steps_per_interval
        times, _ = node_times(self.grid, self.intervals * S, system.horizon)
        X = np.asarray(states(times[S::S]), dtype=np.float64)
        U = np.asarray(controls(times), dtype=np.float64)
        return np.concatenate([X.ravel(), U.ravel()])
