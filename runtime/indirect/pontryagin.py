r"""Pontryagin's maps on the sweep's grid: the forward state rollout, the backward costate rollout, the sweep map
G(u; theta) and the sweep's convergence measure.

Minimisation form, H = L + lambda . f (see :class:`~myriad.runtime.indirect.ForwardBackwardSweep` for the method):

    x' = f(x, u, t),                      x(0) = x0
    lambda' = -dH/dx(x, u, lambda, t),     lambda_i(T) = dphi/dx_i(x(T)) for free x_i(T),  theta_i for fixed ones
    u*(x, lambda, t) = argmin_{u in U} H(x, u, lambda, t)              (``system.optimal_control``)

Every function takes a :class:`Problem`, the arrays of one problem (system, params, x0, grid, scales) that the
sweep's phases share; they are pure and traceable, so they run inside ``jit`` and ``vmap``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..integrators import RK4, rollout, rollout_with_cost
from ..system import System
from ..transcriptions.nlp_parts import final_value_rows
from ..transcriptions.nominal_scales import control_scale, state_scale

__all__ = ["Problem", "problem", "forward", "backward", "sweep_map", "relative_change", "cost_and_trajectories"]

_RK4 = RK4()


class Problem(NamedTuple):
    """One problem on a uniform grid of N intervals: what every phase of the sweep reads (built inside the trace).

    Attributes:
        system: the system (static: its compiled functions).
        params: the parameter pytree; x0: the initial state (n,).
        T, h: the horizon and the step T / N (Python floats); times: the N + 1 nodes.
        fixed, final: indices of the states with a required final value (NumPy) and those values (k,).
        su, sx: nominal control (m,) and state (n,) scales; u_lo, u_hi: the control bounds (m,).
    """

    system: System
    params: Any
    x0: Any
    T: float
    h: float
    times: Any
    fixed: np.ndarray
    final: np.ndarray
    su: Any
    sx: Any
    u_lo: Any
    u_hi: Any

    @property
    def k(self) -> int:
        """The number of fixed final states (unknown terminal costates theta)."""
        return self.fixed.size


def problem(system: System, data: Any, intervals: int) -> Problem:
    """The :class:`Problem` of ``data = ProblemData(params, x0)`` on ``intervals`` uniform intervals."""
    T = float(system.horizon)
    fixed, final = final_value_rows(system)
    arrays = system.arrays()
    return Problem(
        system=system,
        params=data.params,
        x0=jnp.asarray(data.x0),
        T=T,
        h=T / intervals,
        times=jnp.asarray(np.linspace(0.0, T, intervals + 1)),
        fixed=fixed,
        final=final,
        su=jnp.asarray(control_scale(system)),
        sx=jnp.asarray(state_scale(system)),
        u_lo=jnp.asarray(arrays["u_lower"]),
        u_hi=jnp.asarray(arrays["u_upper"]),
    )


def _f(p: Problem):
    return lambda x, u, t: p.system.dynamics(x, u, t, p.params)


def forward(p: Problem, u: Any) -> Any:
    """x(u): RK4 from x0 with the controls u (N + 1, m), linearly interpolated; (N + 1, n)."""
    return rollout(_RK4, _f(p), p.x0, 0.0, p.h, u)


def backward(p: Problem, xs: Any, u: Any, theta: Any) -> Any:
    r"""lambda(x, u; theta): RK4 backward from lambda(T), with lambda_fixed(T) = theta; (N + 1, n).

    (x, u) enter the costate equation as one linearly interpolated "control" of the backward rollout (Lenhart's
    averages of the neighbouring nodes)."""
    n = p.system.n_states
    g = lambda lam, xu, t: p.system.costate_dynamics(xu[:n], xu[n:], lam, t, p.params)  # noqa: E731
    lam_T = jnp.asarray(p.system.terminal_costate(xs[-1], p.T, p.params)).at[p.fixed].set(theta)
    xu = jnp.concatenate([xs, u], axis=1)[::-1]
    return rollout(_RK4, g, lam_T, p.T, -p.h, xu)[::-1]


def optimal_controls(p: Problem, xs: Any, lams: Any) -> Any:
    """u*(x, lambda, t) at the N + 1 nodes; (N + 1, m)."""
    return jax.vmap(lambda x, lam, t: p.system.optimal_control(x, lam, t, p.params))(xs, lams, p.times)


def sweep_map(p: Problem, u: Any, theta: Any) -> tuple[Any, Any]:
    r"""G(u; theta) = u*(x(u), lambda(x(u), u; theta)) (steps 1-3 of a sweep), and the states x(u) it went through."""
    xs = forward(p, u)
    return optimal_controls(p, xs, backward(p, xs, u, theta)), xs


def relative_change(p: Problem, new: Any, u: Any) -> Any:
    r"""The sweep's convergence measure: max over the control components j of

        max_k |new_kj - u_kj| / max(max_k |new_kj|, s_u,j),

    the fixed-point residual of the whole iteration (x and lambda are functions of u)."""
    return jnp.max(jnp.max(jnp.abs(new - u), axis=0) / jnp.maximum(jnp.max(jnp.abs(new), axis=0), p.su))


def cost_and_trajectories(p: Problem, u: Any, theta: Any) -> tuple[Any, Any, Any]:
    r"""(x, lambda, J) of the controls u: J = phi(x(T)) + int L dt, the running cost an extra RK4 state."""
    f = _f(p)
    xs, cost = rollout_with_cost(_RK4, f, lambda x, u, t: p.system.running_cost(x, u, t, p.params), p.x0, 0.0, p.h, u)
    lams = backward(p, xs, u, theta)
    return xs, lams, cost[-1] + p.system.terminal_cost(xs[-1], p.T, p.params)
