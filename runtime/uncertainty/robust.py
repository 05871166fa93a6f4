"""Robust plans (issue 30 item 2): one control trajectory for every scenario of a schema 3 spec, each scenario with
its own states, final conditions and path constraints, and the mean, worst case or CVaR of the scenario costs as the
objective. Built on any direct transcription's NLP, not per transcription:

    nlp = scenario_nlp(system, Trapezoidal(intervals=50), scenarios=3, objective="worst")
    sol = solve_robust(system, Trapezoidal(intervals=50), Ipopt())        # what solve() does for such a spec

The scenario NLP. The transcription's decisions ``z`` split into the shared ones ``u`` (every entry that depends on
the control trajectory, found through the transcription's ``sample``, and a free final time) and the private ones
``x`` (states, single shooting's elastic slacks). With J_s, c_s the transcription's objective and rows at
``z_s = (u, x_s)`` and scenario s's ``ProblemData``:

    decisions   w = [u, x_1, ..., x_S, e]
    mean        min (1/S) sum_s J_s                  s.t. c_s in [c_lower, c_upper] for every s      (e empty)
    worst       min t                                s.t. ... and J_s - t <= 0                       (e = t)
    cvar        min eta + sum_s xi_s / ((1 - alpha) S)  s.t. ... and J_s - eta - xi_s <= 0, xi_s >= 0 (e = eta, xi)

(Rockafellar & Uryasev 2000: at the optimum eta is the alpha-quantile of the costs and the objective their CVaR,
the mean of the worst (1 - alpha) fraction.) Every function evaluates the S scenarios as one ``jax.vmap`` over the
stacked data, so S scenarios are one compiled program whatever S; the Jacobian's pattern is the transcription's,
repeated per scenario with the shared columns in common (dense where the transcription gives none).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation import program_key
from ..compilation.caches import program_cache
from ..data import ProblemData, batch_data, default_data
from ..nlp import NLP, evaluation
from ..solution import AGREEMENT_TOLERANCE, Solution, resimulate, state_magnitudes
from ..solvers import Ipopt
from ..solvers.base import unstack
from ..system import System
from ..transcriptions.base import AbstractTranscription, _trajectories, path_violation, transcribe
from ..transcriptions.error import estimate
from .distributions import uncertain_spec
from .scenarios import scenario_params

__all__ = ["OBJECTIVES", "Layout", "asks_robust", "robust_objective", "robust_value", "scenario_nlp",
           "solve_robust"]

OBJECTIVES = ("mean", "worst", "cvar")


def asks_robust(system: System) -> bool:
    """Whether the spec asks for a robust plan: it declares ``scenarios`` or ``robust`` (schema 3)."""
    return bool(getattr(system, "scenarios", ())) or getattr(system, "robust_objective", None) is not None


def robust_objective(system: System) -> tuple[str, float | None]:
    """The spec's ``(objective, alpha)``: ``robust.objective`` (mean when only ``scenarios`` are given)."""
    objective = getattr(system, "robust_objective", None) or "mean"
    alpha = getattr(system, "robust_alpha", None)
    _check_objective(objective, alpha)
    return objective, None if objective != "cvar" else float(alpha)


def _check_objective(objective: str, alpha: float | None) -> None:
    if objective not in OBJECTIVES:
        raise ValueError(f"robust objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    if objective == "cvar" and not (alpha is not None and 0.0 < float(alpha) < 1.0):
        raise ValueError(f"robust objective cvar needs 0 < alpha < 1, got alpha = {alpha!r}")


def robust_value(costs: Any, objective: str, alpha: float | None = None) -> float:
    """The robust objective of the scenario costs (equal weights): their mean, their maximum, or their CVaR_alpha,
    min over eta of eta + sum_s max(0, J_s - eta) / ((1 - alpha) S), exact at one of the J_s (the function is
    convex and piecewise linear with its kinks there)."""
    J = np.asarray(costs, dtype=np.float64)
    _check_objective(objective, alpha)
    if objective == "mean":
        return float(J.mean())
    if objective == "worst":
        return float(J.max())
    ru = J[:, None] + np.maximum(J[None, :] - J[:, None], 0.0).sum(axis=1, keepdims=True) / ((1 - alpha) * J.size)
    return float(ru.min())


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """Where the transcription's ``z`` (length n) lives in the scenario NLP's ``w``: ``shared`` and ``private`` are
    index arrays into ``z``; ``w = [z[shared], z_1[private], ..., z_S[private], extra]``."""

    n: int
    shared: np.ndarray
    private: np.ndarray
    scenarios: int
    extra: int

    @property
    def n_private(self) -> int:
        return int(self.private.size)

    @property
    def n_variables(self) -> int:
        return int(self.shared.size) + self.scenarios * self.n_private + self.extra

    def split(self, w):
        """``w -> (u, X (S, n_private), extra)``."""
        nu, S, nx = self.shared.size, self.scenarios, self.n_private
        return w[:nu], jnp.reshape(w[nu : nu + S * nx], (S, nx)), w[nu + S * nx :]

    def member(self, u, x):
        """One scenario's ``z`` from the shared ``u`` and its private ``x``."""
        return jnp.concatenate([u, x])[self.inverse]

    @functools.cached_property
    def inverse(self) -> np.ndarray:
        return np.argsort(np.concatenate([self.shared, self.private]))

    def column(self, scenario: int) -> np.ndarray:
        """``w``'s index of each entry of scenario ``scenario``'s ``z``."""
        where = np.empty(self.n, dtype=np.int64)
        where[self.shared] = np.arange(self.shared.size)
        where[self.private] = self.shared.size + scenario * self.n_private + np.arange(self.n_private)
        return where

    def stack(self, per_scenario: np.ndarray, shared_from: np.ndarray | None = None) -> np.ndarray:
        """``[shared part of shared_from (default the first row), every row's private part]`` from (S, n) rows."""
        rows = np.asarray(per_scenario)
        first = rows[0] if shared_from is None else np.asarray(shared_from)
        return np.concatenate([first[self.shared], rows[:, self.private].ravel()])


def shared_entries(system: System, transcription: AbstractTranscription) -> tuple[np.ndarray, np.ndarray]:
    """``(shared, private)`` indices of the transcription's ``z``: an entry is shared when it moves with the control
    trajectory (``sample`` with two different controls and the same states), or is the free final time; everything
    else (states, slacks) is the scenario's own. Through ``sample``, every transcription's layout is read alike."""
    n, m = system.n_states, system.n_controls
    states = lambda t: np.zeros((np.size(t), n))  # noqa: E731
    one, two = (transcription.sample(system, states, lambda t, a=a: np.full((np.size(t), m), a)) for a in (1.0, 2.0))
    moves = one != two
    if system.free_horizon:
        moves[-1] = True  # one final time for the one plan
    return np.flatnonzero(moves), np.flatnonzero(~moves)


@program_cache(maxsize=64)
def _layout(system: System, transcription: AbstractTranscription, scenarios: int, objective: str) -> Layout:
    shared, private = shared_entries(system, transcription)
    return Layout(transcribe(system, transcription).n_variables, shared, private, scenarios,
                  {"mean": 0, "worst": 1, "cvar": 1 + scenarios}[objective])


@program_cache(maxsize=64)
def scenario_nlp(system: System, transcription: AbstractTranscription, scenarios: int, objective: str = "mean",
                 alpha: float | None = None) -> NLP:
    """The scenario NLP (module docstring) of ``scenarios`` scenarios; its ``data`` is a
    :class:`~myriad.runtime.data.ProblemData` with a leading axis of that size (``scenario_data``), its
    ``unravel`` gives ``(times, states (S, K, n), controls)``. Built once per arguments (solvers cache per NLP)."""
    _check_objective(objective, alpha)
    if scenarios < 1:
        raise ValueError(f"a scenario NLP needs at least 1 scenario, got {scenarios}")
    base = transcribe(system, transcription)
    S = int(scenarios)
    layout = _layout(system, transcription, S, objective)
    functions = _functions(base, layout, objective, alpha)
    lower, upper = _bounds(base, layout, objective)
    scale = np.ones(base.n_variables) if base.z_scale is None else np.asarray(base.z_scale, np.float64)
    rows = 0 if objective == "mean" else S
    return NLP(
        **functions,
        c_lower=np.concatenate([np.tile(base.c_lower, S), np.full(rows, -np.inf)]),
        c_upper=np.concatenate([np.tile(base.c_upper, S), np.zeros(rows)]),
        z_lower=lower, z_upper=upper,
        z_scale=np.concatenate([layout.stack(np.broadcast_to(scale, (S, scale.size))), np.ones(layout.extra)]),
        jacobian_sparsity=_sparsity(base, layout, objective),
        name=f"{base.name} x {S} scenarios ({objective}{'' if alpha is None else f' {alpha:g}'})",
        key=program_key(base.key, f"robust:{objective}:{alpha!r}:{S}"),
    )


def _bounds(base: NLP, layout: Layout, objective: str) -> tuple[np.ndarray, np.ndarray]:
    S = layout.scenarios
    extra_lo = {"mean": [], "worst": [-np.inf], "cvar": [-np.inf] + [0.0] * S}[objective]
    lo = np.concatenate([layout.stack(np.broadcast_to(base.z_lower, (S, layout.n))), np.asarray(extra_lo)])
    hi = np.concatenate([layout.stack(np.broadcast_to(base.z_upper, (S, layout.n))), np.full(layout.extra, np.inf)])
    return lo, hi


def _functions(base: NLP, layout: Layout, objective: str, alpha: float | None) -> dict:
    """The scenario NLP's functions: every scenario's (J_s, c_s) from one vmapped evaluation of the transcription."""
    evaluate = evaluation(base.objective, base.constraints, base.objective_and_constraints)
    S = layout.scenarios

    def scenarios(w, data):
        u, X, extra = layout.split(w)
        J, C = jax.vmap(lambda x, d: evaluate(layout.member(u, x), d))(X, data)
        return J, jnp.reshape(C, (-1,)), extra

    def fused(w, data):
        J, c, e = scenarios(w, data)
        if objective == "mean":
            return jnp.mean(J), c
        if objective == "worst":
            return e[0], jnp.concatenate([c, J - e[0]])
        return e[0] + jnp.sum(e[1:]) / ((1.0 - alpha) * S), jnp.concatenate([c, J - e[0] - e[1:]])

    def initial_guess(data):
        Z = jax.vmap(base.initial_guess)(data)  # (S, n): the transcription's guess for each scenario's x0
        u = Z[0][layout.shared]
        X = Z[:, layout.private]
        J = jax.vmap(lambda x, d: base.objective(layout.member(u, x), d))(X, data)
        extra = {"mean": jnp.zeros(0, J.dtype), "worst": jnp.max(J)[None],
                 "cvar": jnp.concatenate([jnp.mean(J)[None], jnp.maximum(J - jnp.mean(J), 0.0)])}[objective]
        return jnp.concatenate([u, jnp.reshape(X, (-1,)), extra])

    def unravel(w, data):
        u, X, _ = layout.split(w)
        times, states, controls = jax.vmap(lambda x, d: base.unravel(layout.member(u, x), d))(X, data)
        return times[0], states, controls[0]

    # The guess is jitted: solvers call it eagerly, where its vmapped evaluation would compile each primitive apart.
    return dict(objective=lambda w, data: fused(w, data)[0], constraints=lambda w, data: fused(w, data)[1],
                objective_and_constraints=fused, initial_guess=jax.jit(initial_guess), unravel=unravel)


def _sparsity(base: NLP, layout: Layout, objective: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The transcription's pattern per scenario (shared columns in common), then the epigraph rows: J_s reads all of
    scenario s's ``z``, and t (worst) or eta and xi_s (cvar). None (dense) where the transcription gives none and
    nothing is private: a single-shooting plan is dense anyway."""
    if base.jacobian_sparsity is None and layout.n_private == 0:
        return None
    m, S = base.n_constraints, layout.scenarios
    if base.jacobian_sparsity is None:
        r0, c0 = (a.ravel() for a in np.indices((m, layout.n)))
    else:
        r0, c0 = (np.asarray(a, np.int64).ravel() for a in base.jacobian_sparsity)
    rows, cols = [], []
    for s in range(S):
        rows.append(r0 + s * m)
        cols.append(layout.column(s)[c0])
    if objective != "mean":
        first = layout.n_variables - layout.extra
        for s in range(S):
            reads = np.concatenate([layout.column(s), [first] + ([first + 1 + s] if objective == "cvar" else [])])
            rows.append(np.full(reads.size, S * m + s))
            cols.append(reads)
    return np.concatenate(rows).astype(np.int64), np.concatenate(cols).astype(np.int64)


def scenario_batch(system: System, params: dict | None = None, x0: Any = None, values: Any = None) -> ProblemData:
    """The scenarios' data (leading axis S): ``values`` (default the spec's scenarios or draws), the other
    parameters at ``params`` or the spec's values, every scenario from ``x0`` (default the spec's).

    Raises:
        ValueError: ``params`` sets an uncertain parameter (the scenarios set those).
    """
    names = uncertain_spec(system)[0]
    clash = sorted(set(params or {}) & set(names))
    if clash:
        raise ValueError(f"params: {', '.join(clash)} {'is' if len(clash) == 1 else 'are'} uncertain in "
                         f"{system.name}, so its scenarios set {'it' if len(clash) == 1 else 'them'}; solve the "
                         f"nominal problem (nominal=True, --nominal) to set {'it' if len(clash) == 1 else 'them'}")
    stacked = scenario_params(system, values)
    S = next(iter(stacked.values())).shape[0]
    nominal = default_data(system, params, x0)  # checks names and shapes as a nominal solve does
    given = {k: np.broadcast_to(np.asarray(nominal.params[k]), (S, *np.shape(nominal.params[k])))
             for k in (params or {})}
    return batch_data(system, {**stacked, **given}, np.broadcast_to(np.asarray(nominal.x0), (S, system.n_states)))


def solve_robust(system: System, transcription: Any, solver: Any = None, *, params: dict | None = None,
                 x0: Any = None, z0: Any = None, resimulate: bool = True, values: Any = None,
                 objective: str | None = None, alpha: float | None = None) -> Solution:
    """The robust plan of ``system`` (module docstring): what :func:`~myriad.runtime.solve.solve` does for a spec
    that declares ``scenarios`` or ``robust`` (``nominal=False``).

    Args:
        transcription: a direct transcription (an indirect method is refused: it has no NLP to stack).
        solver: any NLP solver (default IPOPT). The interior point takes its dense Newton step here: the scenario
            NLP has no stage-wise structure (``kkt="riccati"`` is refused by the solver itself).
        values: (S, n_uncertain) scenarios instead of the spec's; ``objective``, ``alpha``: instead of the spec's.
        z0: a start in the scenario NLP's variables, or in the transcription's (the same start for every scenario).
        resimulate: re-simulate the plan in every scenario and at the nominal parameters (``robust["nominal_cost"]``).

    Returns:
        A :class:`Solution` whose ``cost`` is the robust objective of the scenario costs, ``robust`` its record and
        ``scenario_states`` (S, K, n) every scenario's states; ``states``, ``defect`` are the first scenario's
        trajectory and the largest defect of each required final value over the scenarios.
    """
    if not isinstance(transcription, AbstractTranscription):
        raise ValueError(f"{system.name} asks for a robust plan (scenarios or robust in the spec), which needs a "
                         f"direct transcription; {getattr(transcription, 'label', transcription)} has no NLP to "
                         f"stack over scenarios: choose a direct one, or solve the nominal problem (--nominal)")
    if objective is None:
        objective, alpha = robust_objective(system)
    _check_objective(objective, alpha)
    data = scenario_batch(system, params, x0, values)
    S = int(np.shape(data.x0)[0])
    nlp = scenario_nlp(system, transcription, S, objective, None if objective != "cvar" else float(alpha))
    solver = Ipopt() if solver is None else solver  # the default, as for a nominal solve
    res = solver.solve(nlp, data, _start(system, transcription, nlp, data, objective, z0))
    sol = _solution(system, transcription, solver, nlp, res, data, objective, alpha)
    return with_robust_resimulation(system, sol, data, default_data(system, params, x0)) if resimulate else sol


def _start(system: System, transcription: AbstractTranscription, nlp: NLP, data: ProblemData, objective: str,
           z0: Any) -> Any:
    """``z0`` in the scenario NLP's variables: as given, or a transcription's start copied to every scenario (t or
    eta and the slacks then start where the epigraph rows hold, as in the NLP's own guess)."""
    if z0 is None:
        return None
    z0 = np.asarray(z0, dtype=np.float64)
    base = transcribe(system, transcription)
    if z0.shape != (base.n_variables,):
        return z0  # the solver checks the scenario NLP's length
    S = int(np.shape(data.x0)[0])
    layout = _layout(system, transcription, S, objective)
    J = np.asarray(jax.vmap(base.objective)(jnp.tile(jnp.asarray(z0), (S, 1)), data))
    extra = {"mean": [], "worst": [J.max()], "cvar": [J.mean(), *np.maximum(J - J.mean(), 0.0)]}[objective]
    return np.concatenate([layout.stack(np.tile(z0, (S, 1))), np.asarray(extra, dtype=np.float64)])


@program_cache(maxsize=64)
def _costs(base: NLP):
    """``(Z (S, n), data) -> (S,)`` the transcription's objective of each scenario, one program for all."""
    return jax.jit(jax.vmap(base.objective))


def _solution(system: System, transcription: AbstractTranscription, solver: Any, nlp: NLP, res: Any,
              data: ProblemData, objective: str, alpha: float | None) -> Solution:
    """The plan as a :class:`Solution`: every scenario's trajectory and cost from the transcription's own programs
    (batched over the scenarios), the robust objective of the costs as ``cost``."""
    S = int(np.shape(data.x0)[0])
    layout, base = _layout(system, transcription, S, objective), transcribe(system, transcription)
    w = np.asarray(res.z, dtype=np.float64)
    nu, nx = layout.shared.size, layout.n_private
    X = w[nu : nu + S * nx].reshape(S, nx)
    Z = np.concatenate([np.broadcast_to(w[:nu], (S, nu)), X], axis=1)[:, layout.inverse]
    trajectories = _trajectories(system, transcription, base, Z, data)
    times, states, controls, per_interval = (np.stack(a) for a in zip(*trajectories))
    costs = np.asarray(_costs(base)(Z, data), dtype=np.float64)
    midpoints = transcription.quadrature == "simpson"  # Simpson's grid interleaves midpoints (error.py)
    error = estimate(per_interval.max(axis=0), times[0][::2] if midpoints else times[0])
    defects = (states[:, -1] - np.asarray(system.final_values))[:, system.final_mask]
    members = _members(data, S)
    names = uncertain_spec(system)[0]
    return Solution(
        system=system.name, transcription=transcription.label, solver=solver.label,
        integrator=transcription.quadrature, times=times[0], states=states[0], controls=controls[0],
        cost=robust_value(costs, objective, alpha), defect=_largest(defects), converged=bool(res.success),
        status=res.status, solver_code=int(res.solver_code), message=res.message, iterations=int(res.iterations),
        constraint_violation=float(res.constraint_violation), compile_seconds=float(res.compile_seconds),
        solve_seconds=float(res.solve_seconds), error_estimate=error.value, interval_errors=error.intervals,
        intervals=transcription.grid_intervals, final_time=float(times[0][-1]),
        path_violation=max(path_violation(system, t, x, u, d.params)
                           for t, x, u, d in zip(times, states, controls, members)),
        robust={"objective": objective, "alpha": alpha,
                "scenarios": [{"params": {k: float(np.asarray(d.params[k])) for k in names}, "cost": float(J)}
                              for d, J in zip(members, costs)]},
        scenario_states=states,
    )


def _members(data: ProblemData, S: int) -> list[ProblemData]:
    return unstack(jax.device_get(data), S)


def _largest(defects: np.ndarray) -> list[float]:
    """Each column's entry of largest magnitude (the worst scenario's defect of each required final value)."""
    defects = np.asarray(defects, dtype=np.float64)
    if defects.size == 0:
        return []
    return [float(c[np.argmax(np.abs(c))]) for c in defects.T]


def with_robust_resimulation(system: System, sol: Solution, data: ProblemData, nominal: ProblemData,
                             tolerance: float = AGREEMENT_TOLERANCE) -> Solution:
    """The plan re-simulated in every scenario (the adaptive integrator of :func:`~myriad.runtime.solution.resimulate`)
    and at the nominal parameters: ``simulated_cost`` is the robust objective of the re-simulated costs, and the
    agreement gap the largest over the scenarios of the cost's and the required final values' (as a nominal solve's,
    :func:`~myriad.runtime.solution.agreement_gap`) and of the robust objective's."""
    members = _members(data, int(np.shape(data.x0)[0]))
    runs = [resimulate(system, sol.times, sol.controls, d) for d in members]
    costs = [c for c, _, _ in runs]
    rob = sol.robust
    value = robust_value(costs, rob["objective"], rob["alpha"])
    gaps = [abs(value - sol.cost) / max(1.0, abs(sol.cost))]
    mask = np.asarray(system.final_mask)
    for (cost, defect, _), scenario, x in zip(runs, rob["scenarios"], sol.scenario_states):
        scale = np.asarray(state_magnitudes(np.asarray(x, dtype=np.float64)))[mask]
        final = np.asarray(x[-1] - np.asarray(system.final_values))[mask]
        gaps.append(abs(cost - scenario["cost"]) / max(1.0, abs(scenario["cost"])))
        gaps += [abs(s - d) / c for s, d, c in zip(defect, final, scale)]
    gap = float("nan") if not all(math.isfinite(g) for g in gaps) else float(max(gaps))
    robust = {**rob, "scenarios": [{**s, "simulated_cost": float(c)} for s, c in zip(rob["scenarios"], costs)],
              "nominal_cost": resimulate(system, sol.times, sol.controls, nominal)[0]}
    return dataclasses.replace(
        sol, simulated_cost=value, simulated_defect=_largest(np.asarray([d for _, d, _ in runs])),
        simulated_bound_violation=max(v for _, _, v in runs), agreement=bool(gap <= tolerance), agreement_gap=gap,
        agreement_tolerance=float(tolerance), robust=robust)
