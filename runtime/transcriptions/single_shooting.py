"""Single shooting: the controls are the only decisions; the states come from one rollout."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ..integrators import AbstractIntegrator, Heun, with_running_cost
from ..nlp import NLP
from ..smallops import take
from ..system import System
from .base import AbstractTranscription, Transcribed
from .grid import Grid, node_times
from .nlp_parts import bounded_free_states, guess_controls, path_bounds, path_rows
from .nominal_scales import control_scale
from .staged import stage_derivatives as staged_stage_derivatives
from .staged import staged_derivatives

__all__ = ["SingleShooting"]


@dataclasses.dataclass(frozen=True)
class SingleShooting(AbstractTranscription):
    """Direct single shooting on a grid of N control intervals (the published setting by default: uniform, N = 100).

    Decision: the controls u_0..u_N at the N + 1 nodes t_k (k T / N, or T grid[k]), linearly interpolated in
    between. The states are the rollout x_{k+1} = Phi_{h_k}(x_k, u_k, u_{k+1}) of ``integrator`` from
    x_0 = data.x0, one step per control interval (h_k = t_{k+1} - t_k), and

        minimise    phi(x_N, T) + C_N,     C = int L dt integrated as an extra state by the same integrator
        subject to  x_N,i = x_final,i              for every state with a required final value,
                    lo_i <= x_N,i <= hi_i           for every other state with a finite bound (if enforced),
                    g_lo <= g(x_k, u_k, t_k) <= g_hi   k = 0..N  (path constraints, states from the rollout),
                    u_lower <= u_k <= u_upper,      T_lower <= T <= T_upper   (a free final time).

    State bounds are enforced at the shooting nodes, which for single shooting is the final node only, exactly as
    in the published setting (Bacteria's x(T) <= 10 and Tumour's budget y(T) <= A rely on it). Path constraints
    (schema 2) hold at every control node, with the states the rollout reaches there. Bound and path rows are
    divided by their nominal scale; required final values are not. The constraint Jacobian is dense (every
    x_N depends on every control), so ``jacobian_sparsity`` is None.

    Layout of z: ``[u_0..u_N ((N + 1) m), p, n (soft state bounds only), T (free final time only)]``.

    Soft state bounds (``soft_state_bounds=rho``): each final-state bound row becomes elastic,
    ``lo_i <= x_N,i / s_i + p_i - n_i <= hi_i`` with slacks ``p, n >= 0`` and ``rho * sum(p + n)`` added to the cost
    (the L1 exact penalty: the same optimum where the hard problem is feasible and ``rho`` exceeds the rows'
    multipliers, else the least violation; README.md in this folder). Required final values stay hard.

    Attributes:
        intervals: N, the number of control intervals (N + 1 control nodes).
        integrator: the one-step method of the rollout (Heun, as published).
        enforce_final_state_bounds: add the final-node state-bound rows.
        checkpoint: rematerialise the rollout's steps when differentiating (see ``rollout``): fewer XLA kernels per
            step, which pays unless the step is expensive; values are identical either way
            (docs/notes/single-shooting-checkpoint.md).
        grid: None (uniform), or the N + 1 normalised control nodes 0 = s_0 < ... < s_N = 1 (see ``grid.py``);
            the integrator steps follow it. ``SingleShooting.on_grid(grid)`` sets ``intervals`` from it.
        soft_state_bounds: None (hard final-state bounds), or the penalty rho > 0 per unit of violation of a
            bound row (in the row's scale: state / nominal scale) that makes them elastic (above).
    """

    label: ClassVar[str] = "single_shooting"

    intervals: int = 100
    integrator: AbstractIntegrator = Heun()
    enforce_final_state_bounds: bool = True
    checkpoint: bool = True
    grid: Grid | None = None
    soft_state_bounds: float | None = None

    def __post_init__(self):
        super().__post_init__()  # intervals and grid (see AbstractTranscription)
        rho = self.soft_state_bounds
        if rho is not None:
            if isinstance(rho, bool) or not isinstance(rho, (int, float)) or not (np.isfinite(rho) and rho > 0):
                raise ValueError(f"SingleShooting: soft_state_bounds must be None or a finite penalty > 0, got {rho!r}")
            object.__setattr__(self, "soft_state_bounds", float(rho))

    def transcribe(self, system: System) -> NLP:
        return _Transcribed(self, system, self.intervals).nlp()

    def sample_parts(self, system, states, controls, T):
        times, _ = node_times(self.grid, self.intervals, T)
        soft = self.soft_state_bounds is not None and self.enforce_final_state_bounds
        # The slacks: no violation.
        return [controls(times), np.zeros(2 * bounded_free_states(system).size if soft else 0)]


class _Transcribed(Transcribed):
    """Single shooting's NLP for one system."""

    def __init__(self, method: SingleShooting, system: System, N: int):
        super().__init__(method, system, N)
        self.bounded = (bounded_free_states(system) if method.enforce_final_state_bounds
                        else np.zeros(0, dtype=np.int64))
        self.nU = (self.N + 1) * self.m
        self.rho = method.soft_state_bounds
        # Elastic rows: slacks p (nS) and n (nS) after the controls.
        self.nS = self.bounded.size if self.rho is not None else 0
        # Step k reads u_k and u_{k+1}; staged only where nothing else reaches the rows (no path rows, slacks or T).
        self.stage_index = np.arange(self.N)[:, None] * self.m + np.arange(2 * self.m)[None, :]
        self.staged = not self.free and self.nS == 0 and not system.n_path

    def start(self, ts):
        """The rollout's ``start``: t_0 = 0 on the uniform fixed grid (t_k = k h, as always), else the node times."""
        return 0.0 if self.uniform else ts

    def controls_of(self, z):
        return jnp.reshape(z[:self.nU], (self.N + 1, self.m))

    def slack(self, z):
        return z[self.nU:self.nU + self.nS] - z[self.nU + self.nS:self.nU + 2 * self.nS]  # p - n

    def rows(self, z, xs, us, ts, params):
        xT, bounded = xs[-1], self.bounded
        bound = xT[bounded] / self.sx[bounded] + (self.slack(z) if self.nS else 0.0)
        return jnp.concatenate([xT[self.fixed] - self.final, bound, path_rows(self.system, params, xs, us, ts)])

    def objective_and_constraints(self, z, data):
        params = data.params
        f, L = self.fields(params)
        T, ts, _ = self.clock(z)
        us = self.controls_of(z)
        xs, cost = self.run(f, data.x0, self.start(ts), us, self.method.checkpoint, L)
        penalty = self.rho * jnp.sum(z[self.nU:self.nU + 2 * self.nS]) if self.nS else 0.0
        return cost[-1] + self.system.terminal_cost(xs[-1], T, params) + penalty, self.rows(z, xs, us, ts, params)

    def constraints(self, z, data):
        # Without the cost state: the cheaper rollout when only the rows are wanted.
        f, _ = self.fields(data.params)
        _, ts, _ = self.clock(z)
        us = self.controls_of(z)
        return self.rows(z, self.run(f, data.x0, self.start(ts), us, self.method.checkpoint), us, ts, data.params)

    def unravel(self, z, data):
        f, _ = self.fields(data.params)
        _, ts, _ = self.clock(z)
        us = self.controls_of(z)
        return jnp.asarray(ts), self.run(f, data.x0, self.start(ts), us), us

    def lagrangian_derivatives(self, z, lam, data, objective_weight=1.0, hessian=True):
        # Stage by stage (staged.py): the published setting's Hessian without a reverse pass over the rollout.
        return staged_derivatives(*self.stage_problem(z, data), z, self.stage_index, lam, objective_weight, hessian)

    def stage_derivatives(self, z, lam, data, objective_weight=1.0):
        # The same, the Hessian left as its stages (a Riccati Newton step factorises it in O(N)). The running
        # cost's state is read by nothing but F, linearly: its rows and columns of every stage's curvature, of
        # G_yy and of dc/dy_N are zero, so the stages leave it out (exactly) and the recursion works on n states.
        f, c, grad, jac, st = staged_stage_derivatives(*self.stage_problem(z, data), z, self.stage_index, lam,
                                                       objective_weight)
        n, m = self.system.n_states, self.m
        keep = np.r_[np.arange(n), n + 1 + np.arange(2 * m)]
        w = take(take(st.w, keep, axis=1), keep, axis=2)
        return f, c, grad, jac, st._replace(a=st.a[:, :n, :n], b=st.b[:, :n], w=w, g_yy=st.g_yy[:n, :n],
                                            g_c=st.g_c[:, :n])

    def stage_problem(self, z, data):
        system, m, h, times = self.system, self.m, self.h, self.times
        n = system.n_states
        f_aug = with_running_cost(*self.fields(data.params), n)  # the field objective_and_constraints integrates

        def step(k, y, v):
            t_k, h_k = (k.astype(y.dtype) * h, h) if self.method.grid is None else (jnp.asarray(times)[k],
                                                                                     jnp.asarray(h)[k])
            return self.method.integrator.step(f_aug, y, t_k, h_k, v[:m], v[m:])

        def terminal(y):  # no path rows or slacks here: rows() reads the final state alone
            return y[n] + system.terminal_cost(y[:n], self.T_fixed, data.params), self.rows(z, y[None, :n], None,
                                                                                           None, data.params)

        y0 = jnp.concatenate([jnp.asarray(data.x0, z.dtype), jnp.zeros((1,), z.dtype)])
        return step, terminal, y0

    def nlp(self) -> NLP:
        system, N, nS, bounded, sx = self.system, self.N, self.nS, self.bounded, self.sx
        arrays = system.arrays()
        T_lo, T_hi, T_scale = self.T_lo, self.T_hi, self.T_scale
        guess = np.concatenate([guess_controls(system, N + 1).ravel(), np.zeros(2 * nS), self.T_guess])

        def initial_guess(data):
            del data
            return guess.copy()  # a host constant: no device round trip on every solve

        p_lo, p_hi = path_bounds(system, N + 1)
        n_rows = self.fixed.size + bounded.size + p_lo.size
        staged = self.staged
        return NLP(
            objective=self.objective,
            constraints=self.constraints if n_rows else None,
            c_lower=np.concatenate([np.zeros(self.fixed.size), arrays["x_lower"][bounded] / sx[bounded], p_lo]),
            c_upper=np.concatenate([np.zeros(self.fixed.size), arrays["x_upper"][bounded] / sx[bounded], p_hi]),
            z_lower=np.concatenate([np.tile(arrays["u_lower"], N + 1), np.zeros(2 * nS), T_lo]),
            z_upper=np.concatenate([np.tile(arrays["u_upper"], N + 1), np.full(2 * nS, np.inf), T_hi]),
            initial_guess=initial_guess,
            unravel=self.unravel,
            jacobian_sparsity=None,
            z_scale=np.concatenate([np.tile(control_scale(system), N + 1), np.ones(2 * nS), T_scale]),
            name=self.name(f"N={N}, {type(self.method.integrator).__name__}",
                           f", soft bounds {self.rho:g}" if nS else ""),
            objective_and_constraints=self.objective_and_constraints if n_rows else None,
            lagrangian_derivatives=self.lagrangian_derivatives if staged else None,
            stage_derivatives=self.stage_derivatives if staged else None,
            stage_index=self.stage_index if staged else None,
        )
