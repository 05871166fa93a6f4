"""The single entry point: ``solve(system, method, solver)`` and its batched twin.

    solve(system, MultipleShooting(intervals=20), Ipopt(tol=1e-8))

Both only call the method interface (:class:`~myriad.runtime.method.AbstractMethod`): a direct transcription hands
its NLP to the solver, an indirect method (the sweep) solves on its own and refuses a solver.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .data import batch_data, default_data
from .loader import load
from .method import AbstractMethod
from .solution import Solution
from .solution import resimulate as _resimulate  # solve() has a keyword argument `resimulate`
from .system import System
from .transcriptions import SingleShooting
from .transcriptions.base import transcribe

__all__ = ["Solution", "solve", "solve_batch", "transcribe", "label"]


def label(obj: Any) -> str:
    """The registry name of a transcription, solver or integrator object (``"hermite_simpson"``, ``"ipopt"``)."""
    return getattr(obj, "label", type(obj).__name__)


def _method(transcription: AbstractMethod | None) -> AbstractMethod:
    method = SingleShooting() if transcription is None else transcription
    if not isinstance(method, AbstractMethod):
        raise TypeError(f"expected a transcription or an indirect method, got {type(method).__name__}")
    return method


def solve(
    system: System | str,
    transcription: AbstractMethod | None = None,
    solver: Any = None,
    *,
    params: dict | None = None,
    x0: Any = None,
    z0: Any = None,
    resimulate: bool = True,
) -> Solution:
    """Solve one optimal-control problem.

    Args:
        system: a system object or a name/path for :func:`myriad.runtime.load`.
        transcription: how to solve (default: the published setting, ``SingleShooting(controls=100)`` with Heun): a
            direct transcription, or an indirect method such as :class:`ForwardBackwardSweep`.
        solver: the NLP solver of a direct transcription (default ``Ipopt()``); an indirect method takes none, and
            refuses one.
        params: parameter values overriding the spec's (a partial dict is fine).
        x0: the initial state (default: the spec's).
        z0: a starting point for the method (default: its own guess).
        resimulate: also evaluate the controls with the adaptive integrator.

    Returns:
        A :class:`Solution`; check ``converged`` (a failed solve is returned, never reported as a success).
    """
    system = load(system) if isinstance(system, str) else system
    method = _method(transcription)
    data = default_data(system, params, x0)
    sol = method.solve_problem(system, solver, data, z0)
    if resimulate:
        cost, defect, violation = _resimulate(system, sol.times, sol.controls, data)
        sol = dataclasses.replace(sol, simulated_cost=cost, simulated_defect=defect,
                                  simulated_bound_violation=violation)
    return sol


def solve_batch(
    system: System | str,
    transcription: AbstractMethod | None = None,
    solver: Any = None,
    *,
    params: dict | None = None,
    x0: Any = None,
) -> list[Solution]:
    """Solve a batch of problems that differ in parameters and/or initial state as one vmapped program.

    Args:
        system: the system (or its name/path).
        transcription: default ``SingleShooting()``.
        solver: a pure-JAX solver (:class:`~myriad.runtime.solvers.AbstractPureSolver`; default
            ``Extragradient()``); others are refused with a message.
        params: dict of arrays with a leading batch axis (names not given keep the spec's value).
        x0: (B, n_states) initial states, or None for the spec's.

    Returns:
        One :class:`Solution` per problem (not re-simulated: call :func:`solve` for a single one to get that).
    """
    system = load(system) if isinstance(system, str) else system
    method = _method(transcription)
    return method.solve_problems(system, solver, batch_data(system, params, x0))
