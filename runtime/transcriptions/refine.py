"""Mesh refinement: solve, estimate the error on every interval, split the intervals that miss the tolerance, repeat.

``solve(system, transcription, solver, tolerance=1e-6)`` (:func:`~myriad.runtime.solve.solve`) calls
:func:`solve_refined`. Each level solves the NLP on the current grid (warm-started from the previous level's solution,
interpolated onto the new grid with the transcription's ``sample``), reads the relative local error of every
interval (:mod:`~myriad.runtime.transcriptions.error`), and stops when its maximum meets the tolerance; otherwise every
mesh interval k whose error e_k exceeds the tolerance is cut into n_k equal pieces, and the grid becomes
non-uniform (the transcription's ``grid`` option, :meth:`AbstractTranscription.with_grid`).

How many pieces (Betts 2010, sec. 4.7, in its per-interval form): a method of order p has local error
O(h^{p+1}), so cutting an interval into n pieces divides its error by n^{p+1}. Where the asymptotic rate does not
hold yet (a coarse grid across a boundary layer, a state constraint) the error falls more slowly; like Betts we
measure the order actually seen: an interval that came from cutting a parent of error e_parent into n pieces has
observed local order q = log(e_parent / e_k) / log(n), clipped to [1, p + 1], and the next cut uses that q. Then

    n_k = ceil( (e_k / (safety * tol))^(1 / q) ),   clipped to [2, max_split],

with safety = 1/2 (aim below the tolerance, so one more level usually suffices) and max_split = 6 (Betts' M1 = 5
points added per interval: a cut never trusts an extrapolation over more than that). An interval whose error is
infinite (the reference integration diverged: far too long for the dynamics) gets max_split pieces. Intervals that
meet the tolerance are kept as they are; none are merged (GPOPS-II and PSOPT may also remove points where the error
is far below the tolerance; we do not, so the grid only grows). Multiple shooting refines its shooting intervals,
each keeping its S integrator steps, equal within the interval.

The local errors meeting the tolerance is not enough: summed over the horizon they can still move the cost and the
final values (a hyper-sensitive problem met 1e-6 locally at a cost 1.2e-4 off), and the control's representation
can cost more than the dynamics' error (Hermite-Simpson on the hyper-sensitive problem with T = 50: local errors,
re-simulated cost and final value all within 1e-6 on 79 intervals, the cost 9e-6 above the optimum). So where the
local errors meet it, the grid is re-simulated (:func:`~myriad.runtime.solution.with_resimulation`), and where the
re-simulated cost and required final values disagree with the discrete ones by more than the tolerance (relative to
max(1, |J|) and to the states' magnitudes), the local target is lowered in proportion to the gap (every interval
halved where none misses the lower target). Where they agree, every interval is halved once more and the cost's
change must meet the tolerance too: on a grid halved from the last one, that change is the coarser grid's cost error,
so the finer grid's is below it (by 2^p asymptotically).

The cost's change is judged relative to the cost itself, |J_h - J_2h| / max(|J|, COST_FLOOR) with COST_FLOOR = 1e-3:
an ODE solver's rtol with an atol, so that a cost of zero (or one that crosses it) can still converge, in absolute
terms, to 1e-3 tol. This is stricter than max(1, |J|) on purpose: a tolerance asked of a cost is asked of its
digits, whatever its units. With max(1, |J|) a cost of size 0.048 (COPS' catalyst mixing, trapezoidal from 400
intervals) moved by 1.7e-5 of itself on a halving to 812 intervals and was reported "met" at 1e-6, 1.4e-5 off its
optimum; relative to |J| it halves on and reports the limit that stops it (docs/notes/2026-12-06-peer-tolerance.md).
The agreement verdict of the re-simulation (:mod:`~myriad.runtime.solution`, ``agreement_tolerance``) keeps
max(1, |J|): it is a warning that the two answers disagree, not the cost's accuracy, which the halving bounds.

Stopping: all three meet the tolerance (``met``); or a limit is reached, which is reported and never called a
success: ``max_refinements`` levels after the first solve, a next grid above ``max_intervals``, an NLP that did not
converge, an estimate that is not a number, a re-simulation gap that does not fall where it must (:func:`_stalled`:
an unstable system or bang-bang and singular controls re-simulated open-loop). The last solution is returned either
way (where a refined grid's NLP did not converge, the last grid's that did), with ``refinement`` =
``{"met", "tolerance", "reason", "history"}`` (see :class:`~myriad.runtime.solution.Solution`; each level of the
history has its ``error``, re-simulation ``gap`` and cost ``change``, NaN where not measured).

Each level changes the NLP's shapes, so each level is traced and compiled once (its ``compile_seconds``); a second
refinement of the same problem reuses every level's compiled code, since the grids come out the same.

References:
    J. T. Betts, "Practical Methods for Optimal Control and Estimation Using Nonlinear Programming", 2nd ed.,
    SIAM 2010, sec. 4.7 (mesh refinement; 4.7.1 the error estimate, 4.7.4 the order reduction and the number of
    points to add).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np

from ..data import ProblemData
from ..solution import Solution, with_resimulation
from ..system import System
from .base import AbstractTranscription

__all__ = ["COST_FLOOR", "MeshRefinement", "refine_positions", "solve_refined", "split_counts"]

SAFETY = 0.5
# The cost's change on a halved grid is relative to max(|J|, COST_FLOOR) (see the module docstring): relative for any
# cost above 1e-3 in size, absolute (1e-3 tol) near zero.
COST_FLOOR = 1e-3


@dataclasses.dataclass(frozen=True)
class MeshRefinement:
    """What mesh refinement aims at and where it stops.

    Attributes:
        tolerance: the target for the error estimate (the relative local error of the dynamics, max over
            intervals and states).
        max_refinements: the most refined grids solved after the first one.
        max_intervals: the largest control grid (intervals) refinement may build.
        max_split: the most pieces one interval is cut into per level (at least 2).
    """

    tolerance: float
    max_refinements: int = 10
    max_intervals: int = 2000
    max_split: int = 6

    def __post_init__(self):
        if not (isinstance(self.tolerance, (int, float)) and math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"tolerance must be a positive number, got {self.tolerance!r}")
        if not (isinstance(self.max_refinements, int) and self.max_refinements >= 0):
            raise ValueError(f"max_refinements must be a whole number >= 0, got {self.max_refinements!r}")
        if not (isinstance(self.max_intervals, int) and self.max_intervals >= 1):
            raise ValueError(f"max_intervals must be a whole number >= 1, got {self.max_intervals!r}")
        if not (isinstance(self.max_split, int) and self.max_split >= 2):
            raise ValueError(f"max_split must be a whole number >= 2, got {self.max_split!r}")


def split_counts(errors: np.ndarray, tolerance: float, order: int, max_split: int,
                 parent_errors: np.ndarray | None = None, pieces: np.ndarray | None = None) -> np.ndarray:
    """How many equal pieces to cut each mesh interval into (1: keep it); see the module docstring.

    Args:
        errors: (K,) the error of each mesh interval (+inf allowed).
        tolerance: the target.
        order: p, the method's global order (local error O(h^{p+1})).
        max_split: the most pieces per interval.
        parent_errors, pieces: (K,) for intervals made by the previous cut, the error of the interval they were cut
            from and into how many pieces (1 where not cut); None on the first level.

    Returns:
        (K,) int counts >= 1.
    """
    errors = np.asarray(errors, dtype=np.float64)
    q = np.full(errors.shape, order + 1.0)
    if parent_errors is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            seen = np.log(parent_errors / errors) / np.log(pieces)
        cut = (pieces > 1) & np.isfinite(seen) & np.isfinite(parent_errors)
        q = np.where(cut, np.clip(seen, 1.0, order + 1.0), q)
        # No decrease at all (or worse) after a cut: the asymptotic model says nothing; assume the lowest order.
        q = np.where((pieces > 1) & np.isfinite(parent_errors) & ~(errors < parent_errors), 1.0, q)
    with np.errstate(over="ignore", invalid="ignore"):
        n = np.ceil((errors / (SAFETY * tolerance)) ** (1.0 / q))
    n = np.where(np.isfinite(n), n, max_split)
    n = np.clip(n, 2, max_split)
    return np.where(errors > tolerance, n, 1).astype(np.int64)


def refine_positions(mesh: np.ndarray, counts: np.ndarray, steps: int = 1) -> np.ndarray:
    """The new control grid: mesh interval k cut into counts[k] equal pieces, each of ``steps`` equal steps.

    Args:
        mesh: (K + 1,) normalised mesh nodes (0 ... 1).
        counts: (K,) pieces per mesh interval.
        steps: grid intervals per mesh interval (multiple shooting's S).

    Returns:
        (sum(counts) * steps + 1,) normalised node positions, 0 and 1 exact.
    """
    parts = [np.linspace(a, b, int(c) * steps + 1)[:-1] for a, b, c in zip(mesh[:-1], mesh[1:], counts)]
    return np.concatenate(parts + [np.ones(1)])


def _interpolant(times: np.ndarray, values: np.ndarray):
    return lambda t: np.stack([np.interp(np.asarray(t), times, values[:, i]) for i in range(values.shape[1])], 1)


def solve_refined(system: System, transcription: AbstractTranscription, solver: Any, data: ProblemData,
                  config: MeshRefinement, z0: Any = None) -> Solution:
    """Solve on successively refined grids until the error estimate meets ``config.tolerance`` and the discretised
    and re-simulated answers agree within it, or a limit is hit.

    Returns:
        The last level's :class:`Solution`, re-simulated where its error estimate met the tolerance, with
        ``refinement`` filled in.
    """
    tr, history, tol = transcription, [], config.tolerance
    parent_errors = pieces = coarse_cost = last = None
    previous_gap = math.inf
    S = transcription.steps_per_mesh_interval
    for level in range(config.max_refinements + 1):
        start = time.perf_counter()
        sol = tr.solve_problem(system, solver, data, z0)
        N, error = tr.grid_intervals, sol.error_estimate
        if sol.converged and error <= tol:  # only now is the re-simulation's verdict worth its integration
            sol = with_resimulation(system, sol, data, tol)
        # The cost's change from the grid this one halves: the coarser grid's cost error, a bound on this one's.
        change = math.nan if coarse_cost is None else abs(sol.cost - coarse_cost) / max(abs(sol.cost), COST_FLOOR)
        history.append({"intervals": N, "error": float(error), "gap": float(sol.agreement_gap), "change": change,
                        "cost": float(sol.cost), "converged": bool(sol.converged),
                        "seconds": time.perf_counter() - start})
        met = False
        if not sol.converged:
            reason = f"the NLP did not converge on the grid of {N} intervals ({sol.status}: {sol.message})"
            if last is not None:  # a finer grid that failed from its warm start: the coarser answer is worth more
                reason += f"; the last converged grid, {last.intervals} intervals, is returned"
                sol = last
        elif math.isnan(error):
            reason = f"the error estimate is not a number on the grid of {N} intervals (a non-finite trajectory)"
        elif sol.agreement and change <= tol:
            met, reason = True, (f"the error estimate {error:.2e} met the tolerance on {N} intervals, the re-simulated "
                                 f"cost and final values agree within it ({sol.agreement_gap:.2e}), and the cost "
                                 f"moved by {change:.2e} from the grid of half as many")
        elif level == config.max_refinements:
            reason = f"max_refinements = {config.max_refinements} reached" + _shortfall(sol, change)
        elif _stalled(sol, previous_gap, halved=coarse_cost is not None):
            # Alp rider: y3, y4 have the eigenvalue +2, so re-simulating open-loop controls over T = 20 amplifies any
            # difference by e^40; its gap stays near 1e23 on every grid. The robot arm's bang-bang controls: 1.5e-4
            # on 126 intervals, 3.0e-4 on 252 (the interpolated switches). Refining cannot close such a gap.
            reason = (f"the re-simulated answer does not approach the discretised one as the grid is refined (gap "
                      f"{sol.agreement_gap:.2e} after {previous_gap:.2e}): re-simulating the controls open-loop does "
                      f"not converge here (an unstable system amplifies any difference; bang-bang or singular controls "
                      f"are re-simulated through their interpolation between nodes), which refining cannot fix")
        else:
            last = sol
            previous_gap = sol.agreement_gap if sol.agreement is False else math.inf
            mesh_errors = np.asarray(sol.interval_errors).reshape(-1, S).max(axis=1)
            counts = _next_counts(sol, mesh_errors, tol, tr.order, config.max_split, parent_errors, pieces)
            positions = refine_positions(tr.positions()[::S], counts, S)
            if positions.size - 1 > config.max_intervals:
                reason = (f"the next grid would have {positions.size - 1} intervals, more than max_intervals = "
                          f"{config.max_intervals}" + _shortfall(sol, change))
            else:
                parent_errors, pieces = np.repeat(mesh_errors, counts), np.repeat(counts, counts)
                coarse_cost = sol.cost if np.all(counts == 2) else None
                tr = tr.with_grid(tuple(positions))
                # The grid is in tau = t / T: a free final time keeps the solved T, and the new nodes are T s_k.
                z0 = tr.sample(system, _interpolant(sol.times, sol.states), _interpolant(sol.times, sol.controls),
                               final_time=sol.final_time if system.free_horizon else None)
                continue
        break
    refinement = {"met": met, "tolerance": float(tol), "reason": reason, "history": history}
    return dataclasses.replace(sol, refinement=refinement)


def _next_counts(sol: Solution, mesh_errors, tol, order, max_split, parent_errors, pieces) -> np.ndarray:
    """The pieces of each mesh interval on the next grid: by the local errors while they miss ``tol``; once they meet
    it, against a target lowered in proportion to the re-simulation's gap; once that agrees too, every interval
    halved, so that the cost's change measures the cost's discretisation error."""
    if sol.agreement:
        return np.full(mesh_errors.shape, 2, dtype=np.int64)
    target = tol
    if sol.error_estimate <= tol:  # the local errors meet tol, their sum in the cost or the final values does not
        target = tol * max(1e-3, tol / sol.agreement_gap) if sol.agreement_gap > 0 else tol * 1e-3
    counts = split_counts(mesh_errors, target, order, max_split, parent_errors, pieces)
    # The gap is not in the local errors (a non-finite one included): halve every interval.
    return counts if np.any(counts > 1) else np.full_like(counts, 2)


def _stalled(sol: Solution, previous_gap: float, halved: bool) -> bool:
    """The re-simulation's gap did not fall from the previous grid, where it must have: every interval was halved
    (it did not fall at all), or the answers differ by more than the states' and the cost's own size (it did not
    halve: Alp rider's, 8.1e23 on 1469 intervals, fell by under 3 % a level for three more levels, 290 s, before it
    rose). A small gap may wander between grids before the asymptotic rate holds (the hyper-sensitive
    problem's went from 4.6e-6 to 5.8e-6 on a finer grid): below 1 only a halved grid judges it."""
    if sol.agreement is not False or not math.isfinite(previous_gap):
        return False
    if halved:
        return not sol.agreement_gap < previous_gap
    return not sol.agreement_gap <= 1.0 and not sol.agreement_gap < 0.5 * previous_gap


def _shortfall(sol: Solution, change: float) -> str:
    words = f" with the error estimate at {sol.error_estimate:.2e}"
    if sol.agreement is not None:
        words += f", the re-simulated answer {sol.agreement_gap:.2e} from the discretised one"
    if not math.isnan(change):
        words += f", the cost {change:.2e} from the grid of half as many intervals"
    return words
