"""The certified optimum of an environment's own problem: the N held controls that minimise J = -return, found by
two independent NLP solvers on the same program and accepted only when they agree (README.md in this folder:
reference scores).

    controls, certificate = certified_optimum(env)    # env: Env with controls in their units (reference_env)

The program is the planning problem of :mod:`.mpc` at step 0 with the env's terminal penalty: single shooting
whose stages are the env's ``step_env`` (zero-order hold, its integrator and substeps, the running cost integrated
alongside, the terminal cost and penalty at T), so its objective *is* the env's cost of the controls, not an
approximation of it. The two solvers share only that program and the starting point: IPOPT (cyipopt, MUMPS,
filter line search in C++) and the pure-JAX :class:`~myriad.runtime.solvers.InteriorPoint` (its own KKT algebra,
line search and restoration in one ``lax.while_loop``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..data import ProblemData
from ..solvers import InteriorPoint, Ipopt
from ..transcriptions.nlp_parts import guess_controls
from .env import Env, play
from .mpc import _planning_nlp

__all__ = ["AGREEMENT_RTOL", "SOLVER_TOL", "CertificationError", "certified_optimum", "played_controls"]

# The two methods' env costs must agree to this, relative to max(|J*|, |J_random - J*|) (the score's own scale), so
# the other method's controls would score 100 within 1e-4; both solve to SOLVER_TOL, measured agreement ~1e-9.
AGREEMENT_RTOL = 1e-6
SOLVER_TOL = 1e-10


class CertificationError(RuntimeError):
    """The two methods did not both converge, or converged to costs that disagree beyond :data:`AGREEMENT_RTOL`."""


def played_controls(env: Env, sol) -> np.ndarray:
    """A trajectory optimiser's control at the middle of each env step, (N, m): a start for the env's problem."""
    T, N = float(env.system.horizon), env.options.steps
    times, us = np.asarray(sol.times), np.asarray(sol.controls)
    tu = times if us.shape[0] == times.shape[0] else np.linspace(0.0, T, us.shape[0])
    mid = (np.arange(N) + 0.5) * (T / N)
    return np.stack([np.interp(mid, tu, us[:, j]) for j in range(us.shape[1])], axis=1)


def _starts(env: Env) -> dict[str, np.ndarray]:
    """The starting points: the transcriptions' cold guess, and the continuous problem's single-shooting optimum on
    the env's grid (its controls at the steps' middles) where that converges: a nonconvex problem's cold start
    can end in a worse local minimum than the continuous optimum's neighbourhood."""
    from ..solve import solve
    from ..transcriptions import SingleShooting

    lo, hi = env.control_bounds
    N = env.options.steps
    starts = {"cold": np.clip(guess_controls(env.system, N), lo, hi)}
    sol = solve(env.system, SingleShooting(intervals=N, integrator=env.options.integrator), Ipopt(tol=1e-8),
                resimulate=False)
    if sol.converged and np.all(np.isfinite(np.asarray(sol.controls))):
        starts["single_shooting"] = np.clip(played_controls(env, sol), lo, hi)
    return starts


def _solve(env: Env, solver, start: np.ndarray) -> tuple[np.ndarray, Any, float]:
    """One method from ``start``: (controls (N, m), the NLPResult, the env's cost of the controls played)."""
    nlp = _planning_nlp(env, "penalty")
    d = env.default_params()
    data = ProblemData({"model": d.params, "k": np.int32(0), "prev": start}, np.asarray(d.x0, np.float64))
    result = solver.solve(nlp, data, start.reshape(-1))
    controls = np.asarray(result.z, np.float64).reshape(start.shape)
    return controls, result, float(play(env, controls, d).cost)


def certified_optimum(env: Env, scale_of: Any = None) -> tuple[np.ndarray, dict[str, Any]]:
    """The env's optimal controls (N, m) and their certificate (methods, costs, agreement, start).

    IPOPT runs from every start (:func:`_starts`) and the lowest converged cost's start is kept; the pure-JAX
    interior point then solves from that same start. ``scale_of(J*)`` gives the agreement's scale (default
    ``max(|J*|, 1)``; the reference scores pass ``max(|J*|, |J_random - J*|)``). The returned controls are the
    lower-cost method's. Float64 is the caller's (``jax.enable_x64``).

    Raises:
        CertificationError: no IPOPT solve converged, the interior point did not converge, or the two costs disagree
            beyond :data:`AGREEMENT_RTOL`.
    """
    name = env.system.name
    runs, starts = {}, _starts(env)
    for label, start in starts.items():
        controls, result, cost = _solve(env, Ipopt(tol=SOLVER_TOL), start)
        if result.success and math.isfinite(cost):
            runs[label] = (controls, result, cost)
    if not runs:
        raise CertificationError(f"{name}: IPOPT converged from no start on the env's problem; no certified optimum")
    start = min(runs, key=lambda k: runs[k][2])
    u_a, r_a, j_a = runs[start]
    u_b, r_b, j_b = _solve(env, InteriorPoint(tol=SOLVER_TOL), starts[start])
    if not (r_b.success and math.isfinite(j_b)):
        raise CertificationError(f"{name}: the interior point did not converge on the env's problem from the "
                                 f"{start} start ({r_b.status}); IPOPT's cost {j_a!r} is not certified")
    best = min(j_a, j_b)
    scale = scale_of(best) if scale_of is not None else max(abs(best), 1.0)
    agreement = abs(j_a - j_b) / scale
    if not agreement <= AGREEMENT_RTOL:
        raise CertificationError(f"{name}: IPOPT ({j_a!r}) and the interior point ({j_b!r}) disagree on the env's "
                                 f"optimum by {agreement:.3g} of the score's scale {scale:.6g} (tolerance "
                                 f"{AGREEMENT_RTOL:g}): a local minimum or an unconverged solve; not certified")
    certificate = {
        "problem": "single shooting on the env's grid: zero-order hold, the env's integrator and substeps, "
                   "terminal cost and penalty (the env's cost exactly)",
        "methods": ["ipopt", "interior_point"],
        "costs": {"ipopt": j_a, "interior_point": j_b},
        "iterations": {"ipopt": int(r_a.iterations), "interior_point": int(r_b.iterations)},
        "solver_tol": SOLVER_TOL,
        "agreement": agreement,
        "tolerance": AGREEMENT_RTOL,
        "start": start,
        "starts": {k: v[2] for k, v in runs.items()},
    }
    return (u_a if j_a <= j_b else u_b), certificate
