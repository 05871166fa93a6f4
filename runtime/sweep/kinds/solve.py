"""``solve``: one trajectory optimisation, as ``myriad solve`` does it, optionally from a seeded start state.

    --method solve:transcription=hermite_simpson,intervals=50,solver=ipopt
    --method solve:solver_options={"max_iter":50},x0_std=0.05

The solve itself is deterministic; the seed matters only with ``x0_std`` > 0, where the start state is
``x(0) = clip(x0 + N(0, diag(sigma^2)))``, ``sigma_i = x0_std * max(|x0_i|, 1)``, clipped to the state bounds,
drawn with ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import numpy as np

from ...system import System
from .base import AbstractKind, Outcome, refuse_unsupported

__all__ = ["Solve", "SolveSettings"]


def _methods() -> dict:
    from ...transcriptions import INDIRECT, TRANSCRIPTIONS

    return {**TRANSCRIPTIONS, **INDIRECT}


@dataclasses.dataclass(frozen=True)
class SolveSettings:
    """Attributes:
        transcription: a registry name (``single_shooting``, ``trapezoidal``, ..., ``fbsm``).
        solver: an NLP solver's registry name (default: the method's own, IPOPT); an indirect method takes none.
        integrator: a fixed-step integrator for the shooting transcriptions (default: each one's own).
        intervals: the control grid, ``on_grid(intervals)`` (default: the method's own).
        solver_options: keyword arguments of the solver class, e.g. ``{"max_iter": 50, "tol": 1e-6}``.
        x0_std: the seeded start-state perturbation (module docstring); 0: the spec's x0.
        resimulate: also re-simulate the controls with the adaptive integrator (``simulated_cost``).
    """

    transcription: str = "single_shooting"
    solver: str | None = None
    integrator: str | None = None
    intervals: int | None = None
    solver_options: dict = dataclasses.field(default_factory=dict)
    x0_std: float = 0.0
    resimulate: bool = True

    def __post_init__(self):
        if not isinstance(self.solver_options, dict):
            raise ValueError(f"solve: solver_options must be a mapping, got {self.solver_options!r}")
        if isinstance(self.x0_std, bool) or not isinstance(self.x0_std, (int, float)) \
                or not (math.isfinite(self.x0_std) and self.x0_std >= 0):
            raise ValueError(f"solve: x0_std must be a finite number >= 0, got {self.x0_std!r}")
        if not isinstance(self.resimulate, bool):
            raise ValueError(f"solve: resimulate must be true or false, got {self.resimulate!r}")
        build(self)  # every name and option is checked by building the objects themselves


def build(s: SolveSettings) -> tuple[Any, Any]:
    """The method and solver objects of checked settings (``ValueError`` naming the bad setting otherwise)."""
    from ...integrators import INTEGRATORS
    from ...solvers import SOLVERS

    methods = _methods()
    if s.transcription not in methods:
        raise ValueError(f"solve: unknown transcription {s.transcription!r}; known: {', '.join(methods)}")
    cls = methods[s.transcription]
    kwargs = {}
    if s.integrator is not None:
        fixed = [n for n, c in INTEGRATORS.items() if c.fixed_step]
        if s.integrator not in fixed:
            raise ValueError(f"solve: unknown integrator {s.integrator!r}; fixed-step ones: {', '.join(fixed)}")
        if not any(f.name == "integrator" for f in dataclasses.fields(cls)):
            raise ValueError(f"solve: integrator applies to the shooting transcriptions, not {s.transcription}")
        kwargs["integrator"] = INTEGRATORS[s.integrator]()
    if s.intervals is None:
        method = cls(**kwargs)
    elif isinstance(s.intervals, bool) or not isinstance(s.intervals, int) or s.intervals < 1:
        raise ValueError(f"solve: intervals must be an integer >= 1, got {s.intervals!r}")
    else:
        try:
            method = cls.on_grid(s.intervals, **kwargs)
        except ValueError as exc:
            raise ValueError(f"solve: {exc}") from None
    if not method.uses_solver:
        if s.solver is not None or s.solver_options:
            raise ValueError(f"solve: {s.transcription} solves Pontryagin's conditions itself and takes no solver")
        return method, None
    name = s.solver or "ipopt"
    if name not in SOLVERS:
        raise ValueError(f"solve: unknown solver {name!r}; known: {', '.join(SOLVERS)}")
    try:
        solver = SOLVERS[name](**s.solver_options)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"solve: solver_options for {name}: {exc}") from None
    return method, solver


def perturbed_x0(system: System, x0_std: float, seed: int) -> np.ndarray:
    """The seeded start state of the module docstring."""
    a = system.arrays()
    x0 = np.asarray(a["x0"], dtype=np.float64)
    noise = np.random.default_rng(seed).standard_normal(x0.shape)
    return np.clip(x0 + noise * x0_std * np.maximum(np.abs(x0), 1.0), a["x_lower"], a["x_upper"])


class Solve(AbstractKind):
    """One ``solve(system, method, solver)``; a success is a converged solve."""

    name: ClassVar[str] = "solve"
    Settings: ClassVar[type] = SolveSettings
    columns: ClassVar[tuple[str, ...]] = ("cost", "max_defect", "iterations", "solver_status", "simulated_cost")

    def check_system(self, system: System, settings: dict[str, Any]) -> None:
        method, _ = build(SolveSettings(**settings))
        if not method.uses_solver:  # the indirect methods; every direct transcription enforces both
            refuse_unsupported(system, f"solve with {method.label}")

    def run(self, system: System, settings: dict[str, Any], seed: int) -> Outcome:
        from ...solve import solve

        s = SolveSettings(**settings)
        method, solver = build(s)
        x0 = perturbed_x0(system, s.x0_std, seed) if s.x0_std > 0 else None
        sol = solve(system, method, solver, x0=x0, resimulate=s.resimulate)
        fields = sol.record()
        del fields["system"], fields["message"]  # the task's own fields (the system as given: a name or a path)
        fields["solver_status"] = fields.pop("status")
        fields["max_defect"] = sol.max_defect
        if x0 is not None:
            fields["x0"] = x0.tolist()
        return Outcome(success=bool(sol.converged), message=sol.message, fields=fields)
