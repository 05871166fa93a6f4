"""How to solve one system, as data: ``METHODS`` (every method by name) and :class:`SolveConfig`, the one
configuration of ``myriad solve``, of the sweep's ``solve`` kind and of :meth:`SolveConfig.solve` in Python::

    SolveConfig(transcription="hermite_simpson", intervals=50, tolerance=1e-6).solve(load("van_der_pol"))

The config builds the method and solver objects (:meth:`~SolveConfig.build`, the one place that does) and checks
every name and option by building them on construction, before any system is loaded.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .configs import FieldError
from .indirect import INDIRECT
from .integrators import INTEGRATORS
from .method import AbstractMethod
from .solvers import SOLVERS
from .system import System
from .transcriptions import TRANSCRIPTIONS

__all__ = ["METHODS", "SolveConfig", "takes_integrator"]

# Name -> class of every method: the direct transcriptions, then the indirect methods (which take no NLP solver).
METHODS: dict[str, type[AbstractMethod]] = {**TRANSCRIPTIONS, **INDIRECT}


def takes_integrator(cls: type) -> bool:
    """Whether a method class has an ``integrator`` (the shooting transcriptions)."""
    return any(f.name == "integrator" for f in dataclasses.fields(cls))


def _whole(v: Any, low: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= low


@dataclasses.dataclass(frozen=True)
class SolveConfig:
    """One solve: the method, its grid and solver, mesh refinement and the start state (checked on construction).

    Attributes:
        transcription: the method, a name in METHODS: a direct transcription or the indirect fbsm (default:
            single_shooting, the published setting).
        solver: the NLP solver of a direct transcription (default: ipopt); indirect methods take none.
        integrator: a fixed-step integrator for the shooting transcriptions, single_shooting and multiple_shooting
            (default: each one's own).
        intervals: the control grid: N uniform intervals (N + 1 control nodes), the same grid for every method
            (multiple shooting groups them into shooting intervals of 5 steps); default: each method's own.
        solver_options: keyword arguments of the solver class, e.g. {"max_iter": 50, "tol": 1e-6} (default: none).
        tolerance: mesh refinement: solve again on non-uniform grids, splitting the intervals whose error estimate
            exceeds TOL, until it meets TOL (exit 1 if a limit stops it first); direct transcriptions only, starting
            from intervals.
        max_refinements: with tolerance: the most refined grids after the first solve (default 10).
        max_intervals: with tolerance: the largest grid refinement may build (default 2000).
        x0_std: start from x(0) = clip(x0 + N(0, diag(sigma^2))), sigma_i = x0_std * max(|x0_i|, 1), clipped to the
            state bounds and drawn with numpy.random.default_rng(seed) (default 0: the spec's x0).
        seed: the seed of the x0_std draw (a sweep's task seed).
        resimulate: also re-simulate the controls with the adaptive integrator (the simulated cost and defect;
            default: yes).
        nominal: solve the nominal problem (the spec's parameter values) where the spec declares scenarios or
            robust (schema 3), instead of its robust plan (default: the robust plan).
    """

    transcription: str = "single_shooting"
    solver: str | None = None
    integrator: str | None = None
    intervals: int | None = None
    solver_options: dict = dataclasses.field(default_factory=dict)
    tolerance: float | None = None
    max_refinements: int | None = None
    max_intervals: int | None = None
    x0_std: float = 0.0
    seed: int = 0
    resimulate: bool = True
    nominal: bool = False

    def __post_init__(self):
        if not isinstance(self.solver_options, dict):
            raise FieldError(f"solver_options must be a mapping, got {self.solver_options!r}", "solver_options")
        if isinstance(self.x0_std, bool) or not isinstance(self.x0_std, (int, float)) \
                or not (math.isfinite(self.x0_std) and self.x0_std >= 0):
            raise FieldError(f"x0_std must be a finite number >= 0, got {self.x0_std!r}", "x0_std")
        if not _whole(self.seed, 0):
            raise FieldError(f"seed must be an integer >= 0, got {self.seed!r}", "seed")
        if not isinstance(self.resimulate, bool):
            raise FieldError(f"resimulate must be true or false, got {self.resimulate!r}", "resimulate")
        if not isinstance(self.nominal, bool):
            raise FieldError(f"nominal must be true or false, got {self.nominal!r}", "nominal")
        method, _ = self.build()  # every name and option is checked by building the objects themselves
        self._check_refinement(method)

    def build(self) -> tuple[AbstractMethod, Any]:
        """The method and solver objects; the solver is None for an indirect method.

        Raises:
            ValueError: naming the bad field (a :class:`~myriad.runtime.configs.FieldError`), or the method's own.
        """
        return self._method(), self._solver()

    def _method(self) -> AbstractMethod:
        if self.transcription not in METHODS:
            raise FieldError(f"unknown transcription {self.transcription!r}; known: {', '.join(METHODS)}",
                             "transcription")
        cls = METHODS[self.transcription]
        options = {}
        if self.integrator is not None:
            fixed = [n for n, c in INTEGRATORS.items() if c.fixed_step]
            if self.integrator not in fixed:
                raise FieldError(f"unknown integrator {self.integrator!r}; fixed-step ones: {', '.join(fixed)}",
                                 "integrator")
            if not takes_integrator(cls):
                raise FieldError(f"integrator applies to the shooting transcriptions, not {self.transcription}",
                                 "integrator")
            options["integrator"] = INTEGRATORS[self.integrator]()
        if not cls.uses_solver and (self.solver is not None or self.solver_options):
            raise FieldError(f"{self.transcription} solves Pontryagin's conditions itself and takes no solver",
                             "solver" if self.solver is not None else "solver_options")
        if self.intervals is None:
            return cls(**options)
        if not _whole(self.intervals, 1):
            raise FieldError(f"intervals must be an integer >= 1 (a grid of at least 1 interval), got "
                             f"{self.intervals!r}", "intervals")
        return cls.on_grid(self.intervals, **options)

    def _solver(self) -> Any:
        if not METHODS[self.transcription].uses_solver:
            return None
        name = self.solver or "ipopt"
        if name not in SOLVERS:
            raise FieldError(f"unknown solver {name!r}; known: {', '.join(SOLVERS)}", "solver")
        try:
            return SOLVERS[name](**self.solver_options)
        except (TypeError, ValueError) as exc:
            raise FieldError(f"solver_options for {name}: {exc}", "solver_options") from None

    def _check_refinement(self, method: AbstractMethod) -> None:
        from .transcriptions.refine import MeshRefinement

        limits = {k: getattr(self, k) for k in ("max_refinements", "max_intervals") if getattr(self, k) is not None}
        if self.tolerance is None:
            if limits:
                verb = "is" if len(limits) == 1 else "are"
                raise FieldError(f"{' and '.join(limits)} {verb} only for mesh refinement: add tolerance",
                                 *limits, "tolerance")
            return
        if not method.uses_solver:
            raise FieldError(f"tolerance refines the grid of a direct transcription; {self.transcription} has none",
                             "tolerance")
        MeshRefinement(self.tolerance, **limits)  # its ValueError starts with the field's name

    def x0(self, system: System) -> np.ndarray | None:
        """The seeded start state (``x0_std``), or None for the spec's."""
        if self.x0_std == 0:
            return None
        a = system.arrays()
        x0 = np.asarray(a["x0"], dtype=np.float64)
        noise = np.random.default_rng(self.seed).standard_normal(x0.shape)
        return np.clip(x0 + noise * self.x0_std * np.maximum(np.abs(x0), 1.0), a["x_lower"], a["x_upper"])

    def solve(self, system: System, **options: Any) -> Any:
        """:func:`~myriad.runtime.solve.solve` with this configuration (``options``: its other keywords)."""
        from .solve import solve

        return solve(system, *self.build(), x0=self.x0(system), resimulate=self.resimulate,
                     tolerance=self.tolerance, max_refinements=self.max_refinements,
                     max_intervals=self.max_intervals, nominal=self.nominal, **options)
