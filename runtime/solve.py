"""The single entry point: ``solve(system, method, solver)`` and its batched twin.

    solve(system, MultipleShooting(intervals=20), Ipopt(tol=1e-8))
    solve(system, HermiteSimpson(intervals=20), tolerance=1e-6)     # mesh refinement until the error estimate <= 1e-6

Both only call the method interface (:class:`~myriad.runtime.method.AbstractMethod`): a direct transcription hands
its NLP to the solver, an indirect method (the sweep) solves on its own and refuses a solver.

Precision: both need float64 and refuse JAX's default float32 before any work, with the one-line fix
(``jax.config.update("jax_enable_x64", True)``; :func:`~myriad.runtime.data.require_float64`). In float32 a
solve does not fail loudly: it stops at the iteration limit or calls a feasible problem infeasible. Enabling x64 on
``import myriad.runtime`` instead was rejected: a library that flips a global JAX flag changes the precision (and
memory, and speed) of all the user's other JAX code, which diffrax and optimistix users do not expect; an explicit
line with a clear refusal is the JAX way. Bad ``x0`` and ``params`` are refused as early, naming the states or
parameters (:func:`~myriad.runtime.data.default_data`).
"""

from __future__ import annotations

from typing import Any

from .compilation.blas import one_blas_thread
from .data import batch_data, default_data, require_float64
from .loader import load
from .method import AbstractMethod
from .solution import AGREEMENT_TOLERANCE, Solution, with_resimulation
from .system import System
from .transcriptions import TRANSCRIPTIONS, SingleShooting
from .transcriptions.base import AbstractTranscription, transcribe
from .transcriptions.refine import MeshRefinement, solve_refined
from .uncertainty.robust import asks_robust, solve_robust

__all__ = ["Solution", "solve", "solve_batch", "transcribe", "label"]


def label(obj: Any) -> str:
    """The registry name of a transcription, solver or integrator object (``"hermite_simpson"``, ``"ipopt"``)."""
    return getattr(obj, "label", type(obj).__name__)


def _method(transcription: AbstractMethod | None) -> AbstractMethod:
    method = SingleShooting() if transcription is None else transcription
    if not isinstance(method, AbstractMethod):
        raise TypeError(f"expected a transcription or an indirect method, got {type(method).__name__}")
    return method


@one_blas_thread()  # the solve's LAPACK calls on one BLAS thread (compilation/blas.py)
def solve(
    system: System | str,
    transcription: AbstractMethod | None = None,
    solver: Any = None,
    *,
    params: dict | None = None,
    x0: Any = None,
    z0: Any = None,
    resimulate: bool = True,
    tolerance: float | None = None,
    max_refinements: int | None = None,
    max_intervals: int | None = None,
    nominal: bool = False,
) -> Solution:
    """Solve one optimal-control problem, once or with mesh refinement; a robust plan where the spec asks for one.

    Args:
        system: a system object or a name/path for :func:`myriad.runtime.load`.
        transcription: how to solve (default: the published setting, ``SingleShooting(intervals=100)`` with Heun): a
            direct transcription, or an indirect method such as :class:`ForwardBackwardSweep`.
        solver: the NLP solver of a direct transcription (default ``Ipopt()``); an indirect method takes none, and
            refuses one.
        params: parameter values overriding the spec's (a partial dict is fine).
        x0: the initial state (default: the spec's).
        z0: a starting point for the method (default: its own guess).
        resimulate: also evaluate the controls with the adaptive integrator, and say whether the discretised and
            re-simulated answers agree (``agreement``, within ``tolerance`` or else
            :data:`~myriad.runtime.solution.AGREEMENT_TOLERANCE`). Mesh refinement re-simulates whatever this says.
        tolerance: refine the mesh (:mod:`~myriad.runtime.transcriptions.refine`): solve again on non-uniform grids,
            splitting the intervals whose error estimate exceeds ``tolerance``, until the estimate meets it and the
            discretised and re-simulated cost and final values agree within it, or a limit is reached (direct
            transcriptions only; with a free final time the grid is refined in tau = t / T and
            each level starts from the previous T). None: one solve on the transcription's own grid.
        max_refinements: the most refined grids after the first solve (default 10); needs ``tolerance``.
        max_intervals: the largest grid refinement may build (default 2000); needs ``tolerance``.
        nominal: solve the nominal problem (the spec's parameter values) even where the spec declares ``scenarios``
            or ``robust`` (schema 3); otherwise such a spec gets one control trajectory for all its scenarios
            (:mod:`~myriad.runtime.uncertainty.robust`: ``cost`` is the robust objective, ``robust`` its record;
            direct transcriptions only, no mesh refinement, and ``params`` may not set an uncertain parameter).

    Returns:
        A :class:`Solution`; check ``converged`` (a failed solve is returned, never reported as a success) and,
        after refinement, ``refinement["met"]`` (or ``accurate`` for both); ``agreement`` (and
        ``accuracy_warning``) whether the discretised answer survives re-simulation. Schema 2 systems: ``final_time``
        is the solved T of a free final time, ``path_violation`` the largest path-constraint violation over the points.

    Raises:
        RuntimeError: JAX is in float32 (its default): the message gives the one-line fix.
        KeyError: a parameter name the system does not have (with the closest names).
        ValueError: ``x0`` or a parameter of the wrong shape (naming the states); refinement options without
            ``tolerance``, invalid ones, or ``tolerance`` for an indirect method; all raised before any work.
        UnsupportedFeature: an indirect method on a system with path constraints or a free final time
            (:meth:`~myriad.runtime.system.System.require_schema1_features`); every direct transcription enforces
            both.
    """
    require_float64("solve")
    refine = _refinement(tolerance, max_refinements, max_intervals)
    system = load(system) if isinstance(system, str) else system
    method = _method(transcription)
    if refine is not None and not isinstance(method, AbstractTranscription):
        raise ValueError(f"tolerance: mesh refinement needs a direct transcription ({', '.join(TRANSCRIPTIONS)}); "
                         f"{method.label} has no grid to refine")
    if not nominal and asks_robust(system):
        if refine is not None:
            raise ValueError(f"tolerance: mesh refinement of a robust plan is not supported; {system.name} declares "
                             f"scenarios or robust: drop tolerance, or solve the nominal problem (nominal=True)")
        return solve_robust(system, method, solver, params=params, x0=x0, z0=z0, resimulate=resimulate)
    data = default_data(system, params, x0)
    if refine is None:
        sol = method.solve_problem(system, solver, data, z0)
    else:
        sol = solve_refined(system, method, solver, data, refine, z0)
    if resimulate and sol.agreement is None:  # refinement re-simulates its last grid itself
        sol = with_resimulation(system, sol, data, AGREEMENT_TOLERANCE if refine is None else refine.tolerance)
    return sol


def _refinement(tolerance, max_refinements, max_intervals) -> MeshRefinement | None:
    if tolerance is None:
        given = [name for name, v in (("max_refinements", max_refinements), ("max_intervals", max_intervals))
                 if v is not None]
        if given:
            raise ValueError(f"{' and '.join(given)} {'is' if len(given) == 1 else 'are'} only for mesh refinement: "
                             f"pass tolerance= as well")
        return None
    options = {k: v for k, v in (("max_refinements", max_refinements), ("max_intervals", max_intervals))
               if v is not None}
    return MeshRefinement(tolerance, **options)


@one_blas_thread()
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
    require_float64("solve_batch")
    system = load(system) if isinstance(system, str) else system
    method = _method(transcription)
    return method.solve_problems(system, solver, batch_data(system, params, x0))
