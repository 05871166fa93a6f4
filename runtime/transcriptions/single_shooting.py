"""Single shooting: the controls are the only decisions; the states come from one rollout."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ..integrators import AbstractIntegrator, Heun, rollout, rollout_with_cost
from ..nlp import NLP
from ..system import System
from ._common import bounded_free_states, control_scale, final_value_rows, guess_controls, state_scale
from .base import AbstractTranscription
from .grid import Grid, check_grid, grid_argument, node_times, rollout_on, rollout_with_cost_on

__all__ = ["SingleShooting"]


@dataclasses.dataclass(frozen=True)
class SingleShooting(AbstractTranscription):
    """Direct single shooting on a grid of N control intervals (the published setting by default: uniform, N = 100).

    Decision: the controls u_0..u_N at the N + 1 nodes t_k (k T / N, or T grid[k]), linearly interpolated in
    between. The states are the rollout x_{k+1} = Phi_{h_k}(x_k, u_k, u_{k+1}) of ``integrator`` from
    x_0 = data.x0, one step per control interval (h_k = t_{k+1} - t_k), and

        minimise    phi(x_N) + C_N,        C = int L dt integrated as an extra state by the same integrator
        subject to  x_N,i = x_final,i              for every state with a required final value,
                    lo_i <= x_N,i <= hi_i           for every other state with a finite bound (if enforced),
                    u_lower <= u_k <= u_upper.

    State bounds are enforced at the shooting nodes, which for single shooting is the final node only, exactly as
    in the published setting (Bacteria's x(T) <= 10 and Tumour's budget y(T) <= A rely on it). Bound rows are
    divided by the state's nominal scale; required final values are not. The constraint Jacobian is dense (every
    x_N depends on every control), so ``jacobian_sparsity`` is None.

    Attributes:
        controls: N, the number of control intervals (N + 1 control nodes).
        integrator: the one-step method of the rollout (Heun, as published).
        enforce_final_state_bounds: add the final-node state-bound rows.
        checkpoint: rematerialise the rollout's steps when differentiating (see ``rollout``). The derivative
            programs of a small system are bound by the number of XLA kernels per step, not by arithmetic: saving
            only the state at each node and recomputing the step on the way back removes most of them, which pays on
            16 of the 18 systems; a system whose step is expensive (Rocket Landing) loses. Values are identical
            either way. Measurements: docs/notes/single-shooting-checkpoint.md.
        grid: None (uniform), or the N + 1 normalised control nodes 0 = s_0 < ... < s_N = 1 (see ``grid.py``);
            the integrator steps follow it. ``SingleShooting.on_grid(grid)`` sets ``controls`` from it.
    """

    label: ClassVar[str] = "single_shooting"

    controls: int = 100
    integrator: AbstractIntegrator = Heun()
    enforce_final_state_bounds: bool = True
    checkpoint: bool = True
    grid: Grid | None = None

    @classmethod
    def on_grid(cls, intervals, **options) -> "SingleShooting":
        intervals, grid = grid_argument(intervals)
        return cls(controls=intervals, grid=grid, **options)

    @property
    def grid_intervals(self) -> int:
        return self.controls

    @property
    def order(self) -> int:
        return self.integrator.order

    def with_grid(self, grid) -> "SingleShooting":
        return dataclasses.replace(self, controls=len(grid) - 1, grid=tuple(grid))

    @property
    def quadrature(self) -> str:
        return self.integrator.label

    def __post_init__(self):
        if self.controls < 1:
            raise ValueError(f"SingleShooting: controls must be at least 1, got {self.controls}")
        object.__setattr__(self, "grid", check_grid("SingleShooting", self.grid, self.controls, "controls"))

    def transcribe(self, system: System) -> NLP:
        N, m = self.controls, system.n_controls
        T = float(system.horizon)
        times, h = node_times(self.grid, N, T)
        arrays = system.arrays()
        fixed, final = final_value_rows(system)
        bounded = bounded_free_states(system) if self.enforce_final_state_bounds else np.zeros(0, dtype=np.int64)
        sx = state_scale(system)
        integrator = self.integrator

        # The uniform grid keeps the rollouts it always had (t_k = k h); a grid steps through its own nodes.
        def run(f, x0, us, checkpoint=False):
            if self.grid is None:
                return rollout(integrator, f, x0, 0.0, h, us, checkpoint)
            return rollout_on(integrator, f, x0, times, us, checkpoint)

        def run_with_cost(f, L, x0, us, checkpoint=False):
            if self.grid is None:
                return rollout_with_cost(integrator, f, L, x0, 0.0, h, us, checkpoint)
            return rollout_with_cost_on(integrator, f, L, x0, times, us, checkpoint)

        def controls_of(z):
            return jnp.reshape(z, (N + 1, m))

        def fields(params):
            f = lambda x, u, t: system.dynamics(x, u, t, params)  # noqa: E731
            L = lambda x, u, t: system.running_cost(x, u, t, params)  # noqa: E731
            return f, L

        def final_rows(xT):
            return jnp.concatenate([xT[fixed] - final, xT[bounded] / sx[bounded]])

        def objective_and_constraints(z, data):
            params = data.params
            f, L = fields(params)
            xs, cost = run_with_cost(f, L, data.x0, controls_of(z), self.checkpoint)
            return cost[-1] + system.terminal_cost(xs[-1], T, params), final_rows(xs[-1])

        def objective(z, data):
            return objective_and_constraints(z, data)[0]

        def constraints(z, data):
            # Without the cost state: the cheaper rollout when only the rows are wanted.
            f, _ = fields(data.params)
            return final_rows(run(f, data.x0, controls_of(z), self.checkpoint)[-1])

        def unravel(z, data):
            f, _ = fields(data.params)
            us = controls_of(z)
            return jnp.asarray(times), run(f, data.x0, us), us

        def initial_guess(data):
            del data
            return jnp.asarray(guess_controls(system, N + 1).ravel())

        n_rows = fixed.size + bounded.size
        return NLP(
            objective=objective,
            constraints=constraints if n_rows else None,
            c_lower=np.concatenate([np.zeros(fixed.size), arrays["x_lower"][bounded] / sx[bounded]]),
            c_upper=np.concatenate([np.zeros(fixed.size), arrays["x_upper"][bounded] / sx[bounded]]),
            z_lower=np.tile(arrays["u_lower"], N + 1),
            z_upper=np.tile(arrays["u_upper"], N + 1),
            initial_guess=initial_guess,
            unravel=unravel,
            jacobian_sparsity=None,
            z_scale=np.tile(control_scale(system), N + 1),
            name=f"{system.name}/single_shooting(N={N}, {type(integrator).__name__}"
                 f"{'' if self.grid is None else ', graded'})",
            objective_and_constraints=objective_and_constraints if n_rows else None,
        )

    def sample(self, system, states, controls):
        del states
        times, _ = node_times(self.grid, self.controls, system.horizon)
        return np.asarray(controls(times), dtype=np.float64).reshape(-1)
