"""A whole optimal-control problem of an exported spec posed with ``casadi.Opti``: trapezoidal collocation, path
constraints at every node, and a free final time as a decision variable; and a schema 3 spec's scenario problem
(:func:`scenario_trapezoidal`: one control for every scenario, the mean, worst case or CVaR of their costs).

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

__all__ = ["OptiProblem", "ScenarioProblem", "node_conditions", "posed_at", "scenario_trapezoidal",
           "straight_line_start", "trapezoidal"]


@dataclasses.dataclass(frozen=True)
class OptiProblem:
    """The Opti instance and the handles to read a solution with (``sol.value(handle)``)."""

    opti: Any
    X: Any  # (n_states, N + 1)
    U: Any  # (n_controls, N + 1)
    T: Any  # the final time: a variable when free, else a constant
    J: Any  # the objective
    G: Any  # (n_path, N + 1) the path constraint values at the nodes
    P: Any = None  # parametric: the parameter vector's Opti parameter (None when there are no parameters)
    X0: Any = None  # parametric: x(0)'s Opti parameter


def trapezoidal(cs: CasadiSystem, intervals: int, *, params=None, ipopt_options: dict | None = None,
                parametric: bool = False) -> OptiProblem:
    """Pose ``cs`` on ``intervals`` trapezoidal intervals (see the module docstring) with IPOPT as the solver.

    Args:
        cs: from :func:`myriad.compiler.casadi_export.to_casadi` or ``export_file``.
        intervals: N >= 1.
        params: ``{name: value}`` overriding the spec's parameter values.
        ipopt_options: passed to IPOPT (default: quiet, tol 1e-10).
        parametric: the parameters and x(0) as Opti parameters (``P``, ``X0``; see :func:`posed_at`).
    """
    ca, opti, U, T = _start(cs, intervals)
    p, x0 = posed_at(opti, cs, params, parametric)
    X = opti.variable(cs.n_states, intervals + 1)
    J = _states(opti, cs, X, U, T, p, intervals, x0)
    opti.minimize(J)
    _bound_controls(opti, cs, U)
    G = _path(opti, cs, X, U, T, p, intervals)
    _solver(opti, ipopt_options)
    return OptiProblem(opti, X, U, T, J, G, p if parametric and cs.n_params else None, x0)


@dataclasses.dataclass(frozen=True)
class ScenarioProblem:
    """The scenario problem's Opti instance and handles: one control trajectory ``U`` (and final time ``T``) for
    every scenario, each scenario ``s`` with its own states ``X[s]``, cost ``costs[s]`` and path values ``G[s]``;
    ``J`` is the robust objective."""

    opti: Any
    X: tuple[Any, ...]
    U: Any
    T: Any
    J: Any
    costs: tuple[Any, ...]
    G: tuple[Any, ...]


def scenario_trapezoidal(cs: CasadiSystem, intervals: int, *, rows=None, objective: str | None = None,
                         alpha: float | None = None, ipopt_options: dict | None = None) -> ScenarioProblem:
    """The scenario problem of a schema 3 spec, trapezoidal like :func:`trapezoidal`, with IPOPT as the solver.

    One control trajectory (and one final time, when free) for all scenarios; each scenario has its own states,
    initial and final conditions, state bounds and path constraints, at its own parameter values. The objective of
    the scenario costs J_1..J_S (equally weighted):

        mean    (1/S) sum_s J_s
        worst   max_s J_s, as the epigraph: min z subject to J_s <= z
        cvar    Rockafellar-Uryasev: min_tau tau + sum_s max(J_s - tau, 0) / (S (1 - alpha)), with max(., 0) as
                slack variables; the mean of the worst (1 - alpha) fraction of the costs (alpha -> 0: the mean,
                alpha -> 1: the worst case)

    Args:
        cs: from :func:`myriad.compiler.casadi_export.export_file` of a schema 3 spec.
        intervals: N >= 1.
        rows: the scenarios, each the values of ``cs.uncertain_params`` in order; default ``cs.scenarios``.
        objective: "mean", "worst" or "cvar"; default the spec's ``robust_objective``, else "mean".
        alpha: cvar's alpha in (0, 1); default the spec's ``robust_alpha``.
        ipopt_options: passed to IPOPT (default: quiet, tol 1e-10).
    """
    params = cs.scenario_params(rows)
    if not params:
        raise ValueError(f"{cs.name}: no scenarios: the spec lists no `scenarios:`, so pass rows (e.g. drawn from "
                         "its distributions)")
    objective = objective or cs.robust_objective or "mean"
    alpha = cs.robust_alpha if alpha is None else alpha
    if objective not in ("mean", "worst", "cvar") or (objective == "cvar" and not (alpha is not None and
                                                                                 0 < alpha < 1)):
        raise ValueError(f"objective must be mean, worst or cvar with 0 < alpha < 1, got {objective!r}, {alpha!r}")
    ca, opti, U, T = _start(cs, intervals)
    X = tuple(opti.variable(cs.n_states, intervals + 1) for _ in params)
    costs = tuple(_states(opti, cs, Xs, U, T, ca.DM(p), intervals) for Xs, p in zip(X, params))
    _bound_controls(opti, cs, U)
    G = tuple(_path(opti, cs, Xs, U, T, ca.DM(p), intervals) for Xs, p in zip(X, params))
    J = _robust(opti, costs, objective, alpha)
    opti.minimize(J)
    _solver(opti, ipopt_options)
    return ScenarioProblem(opti, X, U, T, J, costs, G)


def _robust(opti, costs, objective: str, alpha: float | None):
    """The robust objective of the scenario costs (see :func:`scenario_trapezoidal`)."""
    S = len(costs)
    if objective == "mean":
        return sum(costs) / S
    if objective == "worst":
        z = opti.variable()
        for J in costs:
            opti.subject_to(J <= z)
        return z
    tau, xi = opti.variable(), opti.variable(S)
    opti.subject_to(xi >= 0)
    for s, J in enumerate(costs):
        opti.subject_to(xi[s] >= J - tau)
    return tau + sum(xi[s] for s in range(S)) / (S * (1 - alpha))


def _start(cs: CasadiSystem, intervals: int):
    """casadi, a new Opti, the controls U (m, N + 1) and the final time T (a variable in its bounds when free)."""
    if intervals < 1:
        raise ValueError(f"intervals must be at least 1, got {intervals}")
    ca = _casadi()
    opti = ca.Opti()
    U = opti.variable(cs.n_controls, intervals + 1)
    if cs.free_horizon:
        T = opti.variable()
        opti.subject_to(opti.bounded(cs.horizon_bounds[0], T, cs.horizon_bounds[1]))
        opti.set_initial(T, cs.horizon)
    else:
        T = ca.MX(cs.horizon)
    return ca, opti, U, T


def _states(opti, cs: CasadiSystem, X, U, T, p, N: int, x0=None):
    """One set of states X (n, N + 1) under the controls U at parameters p: the trapezoidal defects, x(0), the
    required final values and the state bounds, and a straight-line start; returns its cost."""
    h = T / N
    t = [T * k / N for k in range(N + 1)]
    f = [cs.f(X[:, k], U[:, k], t[k], p) for k in range(N + 1)]
    L = [cs.L(X[:, k], U[:, k], t[k], p) for k in range(N + 1)]
    for k in range(N):
        opti.subject_to(X[:, k + 1] == X[:, k] + h / 2 * (f[k] + f[k + 1]))
    J = cs.phi(X[:, N], T, p) + sum(h / 2 * (L[k] + L[k + 1]) for k in range(N))
    node_conditions(opti, cs, X, N, x0)
    return J


def posed_at(opti, cs: CasadiSystem, params=None, parametric: bool = False):
    """The parameter vector and x(0) a problem is posed at: constants (the spec's values, ``params`` overriding; x0
    None, meaning the spec's), or with ``parametric`` Opti parameters holding those values, so that one built problem
    re-solves at other values by ``opti.set_value`` (and :func:`straight_line_start` from the new x(0)) without
    building IPOPT's NLP again."""
    ca = _casadi()
    values = cs.params_vector(params) if cs.n_params else []
    if not parametric:
        return (ca.DM(values) if cs.n_params else ca.DM(0, 1)), None
    p = opti.parameter(cs.n_params) if cs.n_params else ca.DM(0, 1)
    if cs.n_params:
        opti.set_value(p, values)
    x0 = opti.parameter(cs.n_states)
    opti.set_value(x0, list(cs.x0))
    return p, x0


def node_conditions(opti, cs: CasadiSystem, X, N: int, x0=None) -> None:
    """x(0) (``x0``: an expression, e.g. an Opti parameter; default the spec's x0), the required final values and the
    state bounds on the node states X (n, N + 1), and a straight-line start from the spec's x0 (shared with the other
    transcriptions of bench/casadi_transcriptions.py)."""
    ca = _casadi()
    opti.subject_to(X[:, 0] == (ca.DM(cs.x0) if x0 is None else x0))
    for i, xf in enumerate(cs.x_final):
        if xf is not None:
            opti.subject_to(X[i, N] == xf)
    for i, (lo, hi) in enumerate(zip(cs.x_lower, cs.x_upper)):
        _bound(opti, X[i, :], lo, hi)
    straight_line_start(opti, cs, X, N, cs.x0)


def straight_line_start(opti, cs: CasadiSystem, X, N: int, x0) -> None:
    """A start that satisfies the boundary conditions: a straight line from ``x0`` to the required final values
    (constant where none is required)."""
    for i, (start, xf) in enumerate(zip(x0, cs.x_final)):
        start = float(start)
        end = start if xf is None else xf
        opti.set_initial(X[i, :], [start + (end - start) * k / N for k in range(N + 1)])


def _bound_controls(opti, cs: CasadiSystem, U) -> None:
    for i, (lo, hi) in enumerate(zip(cs.u_lower, cs.u_upper)):
        _bound(opti, U[i, :], lo, hi)


def _path(opti, cs: CasadiSystem, X, U, T, p, N: int):
    """The path constraints at every node; returns their values G (n_path, N + 1)."""
    ca = _casadi()
    t = [T * k / N for k in range(N + 1)]
    G = ca.horzcat(*(cs.g(X[:, k], U[:, k], t[k], p) for k in range(N + 1))) if cs.n_path else ca.MX(0, N + 1)
    for i, (lo, hi) in enumerate(zip(cs.path_lower, cs.path_upper)):
        _bound(opti, G[i, :], lo, hi)
    return G


def _solver(opti, ipopt_options: dict | None) -> None:
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "tol": 1e-10, **(ipopt_options or {})})


def _bound(opti, row, lo: float, hi: float) -> None:
    if lo == hi:
        opti.subject_to(row == lo)
        return
    if not math.isinf(lo):
        opti.subject_to(row >= lo)
    if not math.isinf(hi):
        opti.subject_to(row <= hi)
