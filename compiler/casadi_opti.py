"""A whole optimal-control problem of an exported spec posed with ``casadi.Opti``: trapezoidal collocation, path
constraints at every node, and a free final time as a decision variable.

    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import trapezoidal

    problem = trapezoidal(export_file("tests/compiler/schema2/min_time_double_integrator.yaml"), intervals=40)
    sol = problem.opti.solve()
    sol.value(problem.T), sol.value(problem.J)

The NLP, on the grid tau_k = k / N of [0, 1] with physical times t_k = T tau_k (T fixed, or free in its bounds):

    variables    X (n, N+1) states and U (m, N+1) controls at the nodes; T when the final time is free
    dynamics     x_{k+1} = x_k + (h/2) (f(x_k, u_k, t_k) + f(x_{k+1}, u_{k+1}, t_{k+1})),  h = T / N
    objective    J = phi(x_N, T) + sum_k (h/2) (L_k + L_{k+1})
    constraints  x_0 = x0; x_N,i = x_final,i where required; the state and control bounds at every node;
                 path_lower <= g(x_k, u_k, t_k) <= path_upper at every node (one side where the other is infinite,
                 an equality where they are equal); T_lower <= T <= T_upper

It is an independent reading of the spec's semantics (time scaling, where path constraints hold, what ``t`` means in
phi) for the tests and the bench, not a method of the runtime: myriad's transcriptions are in ``runtime/``. casadi is
imported by :mod:`.casadi_export`'s ``_casadi``, only when called.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from .casadi_export import CasadiSystem, _casadi

__all__ = ["OptiProblem", "trapezoidal"]


@dataclasses.dataclass(frozen=True)
class OptiProblem:
    """The Opti instance and the handles to read a solution with (``sol.value(handle)``)."""

    opti: Any
    X: Any  # (n_states, N + 1)
    U: Any  # (n_controls, N + 1)
    T: Any  # the final time: a variable when free, else a constant
    J: Any  # the objective
    G: Any  # (n_path, N + 1) the path constraint values at the nodes


def trapezoidal(cs: CasadiSystem, intervals: int, *, params=None, ipopt_options: dict | None = None) -> OptiProblem:
    """Pose ``cs`` on ``intervals`` trapezoidal intervals (see the module docstring) with IPOPT as the solver.

    Args:
        cs: from :func:`myriad.compiler.casadi_export.to_casadi` or ``export_file``.
        intervals: N >= 1.
        params: ``{name: value}`` overriding the spec's parameter values.
        ipopt_options: passed to IPOPT (default: quiet, tol 1e-10).
    """
    if intervals < 1:
        raise ValueError(f"intervals must be at least 1, got {intervals}")
    ca = _casadi()
    N, n, m = intervals, cs.n_states, cs.n_controls
    p = ca.DM(cs.params_vector(params)) if cs.n_params else ca.DM(0, 1)
    opti = ca.Opti()
    X, U = opti.variable(n, N + 1), opti.variable(m, N + 1)
    if cs.free_horizon:
        T = opti.variable()
        opti.subject_to(opti.bounded(cs.horizon_bounds[0], T, cs.horizon_bounds[1]))
        opti.set_initial(T, cs.horizon)
    else:
        T = ca.MX(cs.horizon)
    h = T / N
    t = [T * k / N for k in range(N + 1)]
    f = [cs.f(X[:, k], U[:, k], t[k], p) for k in range(N + 1)]
    L = [cs.L(X[:, k], U[:, k], t[k], p) for k in range(N + 1)]
    for k in range(N):
        opti.subject_to(X[:, k + 1] == X[:, k] + h / 2 * (f[k] + f[k + 1]))
    J = cs.phi(X[:, N], T, p) + sum(h / 2 * (L[k] + L[k + 1]) for k in range(N))
    opti.minimize(J)

    opti.subject_to(X[:, 0] == ca.DM(cs.x0))
    for i, xf in enumerate(cs.x_final):
        if xf is not None:
            opti.subject_to(X[i, N] == xf)
    for rows, lower, upper in ((X, cs.x_lower, cs.x_upper), (U, cs.u_lower, cs.u_upper)):
        for i, (lo, hi) in enumerate(zip(lower, upper)):
            _bound(opti, rows[i, :], lo, hi)
    G = ca.horzcat(*(cs.g(X[:, k], U[:, k], t[k], p) for k in range(N + 1))) if cs.n_path else ca.MX(0, N + 1)
    for i, (lo, hi) in enumerate(zip(cs.path_lower, cs.path_upper)):
        _bound(opti, G[i, :], lo, hi)

    # A start that satisfies the boundary conditions: a straight line from x0 to the required final values.
    for i, (x0, xf) in enumerate(zip(cs.x0, cs.x_final)):
        end = x0 if xf is None else xf
        opti.set_initial(X[i, :], [x0 + (end - x0) * k / N for k in range(N + 1)])
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "tol": 1e-10, **(ipopt_options or {})})
    return OptiProblem(opti, X, U, T, J, G)


def _bound(opti, row, lo: float, hi: float) -> None:
    if lo == hi:
        opti.subject_to(row == lo)
        return
    if not math.isinf(lo):
        opti.subject_to(row >= lo)
    if not math.isinf(hi):
        opti.subject_to(row <= hi)
