"""The nonlinear program that a transcription produces and an NLP solver consumes.

    minimise    F(z; data)
    subject to  c_lower <= c(z; data) <= c_upper      (equalities have c_lower == c_upper)
                z_lower <= z <= z_upper

``data`` is a pytree of problem data that may change between solves without recompiling: for a transcription, the
system's parameters and initial state as a :class:`~myriad.runtime.data.ProblemData`; solvers treat it as opaque.
Everything shape-like (sizes, bounds, sparsity) is static.
Batches of problems that differ only in ``data`` can therefore be solved by ``jax.vmap`` over ``data``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax.numpy as jnp
import numpy as np

from .status import Status

__all__ = ["NLP", "NLPResult", "evaluation"]

Data = Any  # a pytree; ProblemData(params, x0) for a transcription's NLP


@dataclasses.dataclass(frozen=True, eq=False)
class NLP:
    """A transcribed optimal-control problem.

    Attributes:
        objective: F(z, data) -> scalar.
        constraints: c(z, data) -> (n_constraints,). May be absent (None) when there are none.
        c_lower, c_upper: constraint bounds, NumPy float64 (n_constraints,).
        z_lower, z_upper: variable bounds, NumPy float64 (n_variables,); +-inf where unbounded.
        initial_guess: data -> z0 (n_variables,).
        unravel: (z, data) -> (times (K,), states (K, n_states), controls (K, n_controls)) on the transcription grid.
        jacobian_sparsity: optional (rows, cols) of the structurally non-zero entries of dc/dz.
        z_scale: optional positive (n_variables,) nominal magnitudes; solvers may work in z / z_scale.
        name: a label for reports.
        objective_and_constraints: optional (z, data) -> (F, c) computing both in one pass. A shooting
            transcription's F and c come from the same rollout; fusing them halves the integration work of every
            evaluation and of every derivative program built on both (the Lagrangian's Hessian). Must agree with
            ``objective`` and ``constraints``; :meth:`evaluate` falls back to calling them separately.
        lagrangian_derivatives: optional (z, lam, data, objective_weight=1, hessian=True) -> (F, c, dF/dz, dc/dz,
            Hessian of objective_weight F + lam^T c; zeros where the traced boolean ``hessian`` is false), the
            second-order solvers' derivatives by the transcription's own structure (single shooting: stage by stage,
            :mod:`~myriad.runtime.transcriptions.staged`). Must agree with differentiating ``evaluate``; solvers
            fall back to that (forward over reverse) without it.
        stage_derivatives, stage_index: optional, with ``lagrangian_derivatives``: the same derivatives with the
            Hessian left as the rollout's stages (:class:`~myriad.runtime.transcriptions.staged.Stages`), step ``k``
            reading the decisions ``z[stage_index[k]]``; for a stage-wise (Riccati) Newton step.
        stage_structure: optional :class:`~myriad.runtime.transcriptions.stage_structure.StageStructure`, the stage
            of every variable and row of a transcription that is a chain of stages (collocation, multiple shooting),
            for a block-banded Newton step and derivatives by stage; None: no such structure (dense).
        key: what the functions depend on, as text (a spec-generated system's source and a transcription's
            configuration; :func:`~myriad.runtime.transcriptions.transcribe` sets it), so that their traced
            programs may be kept on disk for later processes (:mod:`~myriad.runtime.compilation.programs`); None:
            never kept.
    """

    objective: Callable[[Any, Data], Any]
    constraints: Callable[[Any, Data], Any] | None
    c_lower: np.ndarray
    c_upper: np.ndarray
    z_lower: np.ndarray
    z_upper: np.ndarray
    initial_guess: Callable[[Data], Any]
    unravel: Callable[[Any, Data], tuple[Any, Any, Any]]
    jacobian_sparsity: tuple[np.ndarray, np.ndarray] | None = None
    z_scale: np.ndarray | None = None
    name: str = "nlp"
    objective_and_constraints: Callable[[Any, Data], tuple[Any, Any]] | None = None
    lagrangian_derivatives: Callable[[Any, Any, Data], tuple[Any, Any, Any, Any, Any]] | None = None
    stage_derivatives: Callable[[Any, Any, Data], tuple[Any, Any, Any, Any, Any]] | None = None
    stage_index: np.ndarray | None = None
    stage_structure: Any = None
    key: str | None = None

    def evaluate(self, z: Any, data: Data) -> tuple[Any, Any]:
        """``(F(z), c(z))``, fused when the transcription provides it; ``c`` is an empty array without constraints."""
        return evaluation(self.objective, self.constraints, self.objective_and_constraints)(z, data)

    @property
    def n_variables(self) -> int:
        return int(self.z_lower.shape[0])

    @property
    def n_constraints(self) -> int:
        return int(self.c_lower.shape[0])


def evaluation(
    objective: Callable[[Any, Data], Any],
    constraints: Callable[[Any, Data], Any] | None,
    fused: Callable[[Any, Data], tuple[Any, Any]] | None,
) -> Callable[[Any, Data], tuple[Any, Any]]:
    """``(z, data) -> (F, c)`` from an NLP's functions: ``fused`` itself when given, else both calls.

    Takes the functions rather than the NLP so that solvers can keep the result in a cache keyed weakly by the NLP.
    """
    if fused is not None:
        return fused
    if constraints is None:
        return lambda z, data: (objective(z, data), jnp.zeros(0, dtype=jnp.result_type(z)))
    return lambda z, data: (objective(z, data), constraints(z, data))


@dataclasses.dataclass(frozen=True)
class NLPResult:
    """What every NLP solver returns. ``success`` is True only for a converged, feasible solve.

    Attributes:
        z: the final iterate.
        objective: F(z).
        status: the outcome (:class:`~myriad.runtime.status.Status`); only ``Status.CONVERGED`` (converged to the
            solver's tolerance and within the constraint tolerance) is a success.
        message: the solver's own words on the outcome.
        iterations: iterations taken.
        constraint_violation: max over constraint and bound violations at z.
        multipliers: constraint multipliers if the solver provides them, else None.
        compile_seconds: time spent tracing/compiling (first call only; 0 when cached).
        solve_seconds: wall time of the solve itself.
        solver_code: the solver's own status code (IPOPT's return status, SciPy's exit mode, ...), kept for
            reference beside ``status``.
    """

    z: Any
    objective: float
    status: Status
    message: str
    iterations: int
    constraint_violation: float
    multipliers: Any = None
    compile_seconds: float = 0.0
    solve_seconds: float = 0.0
    solver_code: int = 0

    @property
    def success(self) -> bool:
        return self.status is Status.CONVERGED
