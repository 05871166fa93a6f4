"""The transcription interface: an optimal-control problem in, a finite-dimensional NLP out."""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import Any, Callable, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation import CompiledFunction, program_key, programs
from ..compilation.caches import program_cache
from ..data import ProblemData
from ..integrators import rollout, rollout_with_cost
from ..method import AbstractMethod
from ..nlp import NLP
from ..solution import Solution
from ..solvers import SOLVERS, AbstractNLPSolver, AbstractPureSolver, Extragradient, Ipopt
from ..solvers.base import unstack
from ..system import System
from .error import REFERENCE_SUBSTEPS, estimate, interval_errors
from .grid import check_grid, free_node_times, grid_argument, node_times
from .nlp_parts import (
    collocation_blocks,
    final_time_variable,
    final_value_rows,
    guess_controls,
    guess_states,
    node_state_bounds,
    path_bounds,
    sparsity,
)
from .nominal_scales import control_scale, state_scale
from .stage_structure import collocation_structure

__all__ = ["AbstractTranscription", "Transcribed", "TrajectoryFn", "path_violation", "transcribe"]

# t (K,) -> values (K, d): a trajectory evaluated at an array of times.
TrajectoryFn = Callable[[np.ndarray], Any]


@dataclasses.dataclass(frozen=True)
class AbstractTranscription(AbstractMethod):
    """Turns a :class:`~myriad.runtime.system.System` into an :class:`~myriad.runtime.nlp.NLP`.

    Conventions shared by every transcription (so solvers and the bench can treat them alike):

    - The decision vector ``z`` never contains the initial state: x(0) is read from ``data.x0`` in every
      function, so the initial state can change without recompiling (and bounds, which are static, never depend
      on it).
    - The objective is J = phi(x(T)) + int L dt in minimisation form, in the transcription's quadrature.
    - Constraints are ordered ``[dynamics defects (collocation / multiple shooting), required final values,
      final-state bounds (single shooting), path constraints]``. Equality rows are residuals with
      c_lower = c_upper = 0; required final values appear as x_i(T) - x_final,i. Defect rows are divided by the
      state's nominal scale; required final values are *not* scaled, so a solver's constraint tolerance is the
      absolute tolerance on x_i(T).
    - Path constraints (schema 2) are the last rows, point-major, divided by their nominal scale, at every point
      ``unravel`` returns; a free final time is the *last* entry of ``z``, the grid in tau = t / T in [0, 1]
      (README.md in this folder).
    - Control and state bounds are ``z_lower`` / ``z_upper`` (infinite where unbounded), none at the final node for a
      state with a required final value (:func:`~.nlp_parts.node_state_bounds`); ``z_scale`` holds nominal
      magnitudes (:mod:`.nominal_scales`).
    - The functions are pure and not jitted: the solver jits them with ``data`` as a traced argument, so new
      parameters or a new x0 reuse the compiled code, and a batch of ``data`` is one ``jax.vmap``.
    - ``unravel(z, data)`` returns ``(times, states, controls)`` on the transcription's own grid, x(0) included,
      in physical time (ending at the solved T when it is free).
    - Every transcription has a ``grid`` field: None for the uniform grid, or a tuple of normalised node positions
      (``grid.py``); ``on_grid`` accepts an interval count or such positions, ``with_grid`` re-grids an instance
      (mesh refinement, ``refine.py``).

    Concrete transcriptions are frozen, hashable dataclasses (static ``jax.jit`` arguments).

    Class attributes (besides ``label``), or properties:
        quadrature, order: the rule and the global order p of the discretisation (its local error on an interval is
            O(h^{p+1})): the ``integrator``'s for shooting, 2 for trapezoidal, 4 for Hermite-Simpson.
        steps_per_mesh_interval: how many grid intervals refinement treats as one (multiple shooting: the S steps
            of a shooting interval; 1 elsewhere).
    """

    steps_per_mesh_interval: ClassVar[int] = 1

    @property
    def quadrature(self) -> str:
        return getattr(self, "integrator").label

    @property
    def order(self) -> int:
        return getattr(self, "integrator").order

    # The grid: ``intervals`` mesh intervals of ``steps_per_mesh_interval`` steps and a ``grid`` field, checked here
    # for every transcription whose N is its own size field (single shooting and the collocations); multiple
    # shooting, whose ``intervals`` counts shooting intervals of S steps each, overrides on_grid and __post_init__.

    @classmethod
    def on_grid(cls, intervals, **options: Any) -> "AbstractTranscription":
        intervals, grid = grid_argument(intervals)
        return cls(intervals=intervals, grid=grid, **options)

    def __post_init__(self):
        owner, intervals = type(self).__name__, getattr(self, "intervals")
        if intervals < 1:
            raise ValueError(f"{owner}: intervals must be at least 1, got {intervals}")
        object.__setattr__(self, "grid", check_grid(owner, getattr(self, "grid"), intervals))

    @property
    def grid_intervals(self) -> int:
        """N, the number of intervals of the control grid (the size ``on_grid(N)`` takes)."""
        return getattr(self, "intervals") * self.steps_per_mesh_interval

    def with_grid(self, grid: tuple[float, ...]) -> "AbstractTranscription":
        """This transcription, every other option kept, on the grid of normalised node positions ``grid``.

        Raises:
            ValueError: a grid this transcription cannot have (see ``__post_init__``).
        """
        steps, S = len(grid) - 1, self.steps_per_mesh_interval
        if steps % S:
            raise ValueError(f"{type(self).__name__}: a grid of {steps} steps cannot be cut into shooting intervals "
                             f"of {S} steps")
        return dataclasses.replace(self, intervals=steps // S, grid=tuple(grid))

    def positions(self) -> np.ndarray:
        """The normalised node positions of the control grid, (N + 1,): the ``grid``, or the uniform one."""
        grid = getattr(self, "grid")
        return np.linspace(0.0, 1.0, self.grid_intervals + 1) if grid is None else np.asarray(grid)

    @abc.abstractmethod
    def transcribe(self, system: System) -> NLP:
        """Build the NLP for ``system``; every function of it takes ``(z, data)`` with ``data`` a
        :class:`~myriad.runtime.data.ProblemData` (see :func:`~myriad.runtime.data.default_data`)."""

    def sample(self, system: System, states: TrajectoryFn, controls: TrajectoryFn,
               final_time: float | None = None) -> np.ndarray:
        """``z`` (float64) sampling given trajectories, ``states`` and ``controls`` (times (K,) -> values (K, d)), on
        this transcription's grid: a warm start from another solution, or a known solution to check.

        ``final_time``: the horizon the trajectories live on (with a free final time, the sample's T); None for
        ``system.horizon``. An argument because the functions are plain callables without a domain.

        Raises:
            ValueError: a final time other than the fixed horizon of a system whose horizon is not free.
        """
        if final_time is None:
            T = float(system.horizon)
        else:
            T = float(final_time)
            if not system.free_horizon and not math.isclose(T, float(system.horizon), rel_tol=1e-12):
                raise ValueError(f"sample: final_time = {T:g}, but {system.name}'s horizon is fixed at "
                                 f"{system.horizon:g}; pass final_time=None")
            if not (math.isfinite(T) and T > 0.0):
                raise ValueError(f"sample: final_time must be a positive number, got {final_time!r}")
        parts = [np.asarray(part, dtype=np.float64).ravel() for part in self.sample_parts(system, states, controls, T)]
        return np.concatenate(parts + ([np.array([T])] if system.free_horizon else []))

    @abc.abstractmethod
    def sample_parts(self, system: System, states: TrajectoryFn, controls: TrajectoryFn, T: float) -> list:
        """:meth:`sample`'s blocks of ``z`` before a free final time, in order, on the horizon ``T``."""

    # ---- the method interface (see AbstractMethod) -------------------------------------------------------------

    def solve_problem(self, system: System, solver: Any, data: ProblemData, z0: Any = None) -> Solution:
        solver = Ipopt() if solver is None else solver
        if not isinstance(solver, AbstractNLPSolver):
            raise TypeError(f"{self.label}: the solver must be an NLP solver (ipopt, slsqp, extragradient), "
                            f"got {type(solver).__name__}")
        nlp = transcribe(system, self)
        return _solution(system, self, solver, nlp, solver.solve(nlp, data, z0), data)

    def solve_problems(self, system: System, solver: Any, data: ProblemData) -> list[Solution]:
        solver = Extragradient() if solver is None else solver
        if not isinstance(solver, AbstractPureSolver):
            pure = ", ".join(name for name, cls in SOLVERS.items() if issubclass(cls, AbstractPureSolver))
            raise TypeError(
                f"a batched solve needs a solver whose whole solve is a JAX function ({pure}), got "
                f"{type(solver).__name__}, which leaves JAX at every iteration; solve the problems one at a time "
                f"with solve()"
            )
        nlp = transcribe(system, self)
        results = solver.solve_batch(nlp, data)
        # Slice on the host: per-problem device slicing dominated small batches.
        members = unstack(jax.device_get(data), len(results))
        z = np.stack([np.asarray(res.z, dtype=np.float64) for res in results])
        trajectories = _trajectories(system, self, nlp, z, data)
        return [_solution(system, self, solver, nlp, res, members[i], trajectories[i])
                for i, res in enumerate(results)]


class Transcribed:
    """A transcription's NLP for one system on N grid intervals: the constants every transcription reads, its clock
    and vector fields; each transcription's functions are methods of a subclass."""

    def __init__(self, method: AbstractTranscription, system: System, N: int):
        self.method, self.system, self.N = method, system, N
        self.n, self.m = system.n_states, system.n_controls
        self.T_fixed = float(system.horizon)
        self.times, self.h = node_times(method.grid, N, self.T_fixed)
        self.positions = method.positions()
        self.free = system.free_horizon
        self.uniform = method.grid is None and not self.free
        self.fixed, self.final = final_value_rows(system)
        self.sx = state_scale(system)
        self.T_lo, self.T_hi, self.T_scale, self.T_guess = final_time_variable(system)

    def clock(self, z):
        """(T, node times, steps): constants, or from the decision T (see grid.free_node_times)."""
        if self.free:
            return (z[-1], *free_node_times(self.positions, z[-1]))
        return self.T_fixed, jnp.asarray(self.times), self.h

    def fields(self, params):
        f = lambda x, u, t: self.system.dynamics(x, u, t, params)  # noqa: E731
        L = lambda x, u, t: self.system.running_cost(x, u, t, params)  # noqa: E731
        return f, L

    def run(self, f, x0, start, us, checkpoint=False, L=None):
        """The shooting rollout of ``method.integrator`` from x0 at ``start``, the running cost L an extra state when
        given: the uniform fixed grid steps from the start time by h as it always did; any other grid through
        ``start``, its node times."""
        h = self.h if self.uniform else None
        if L is None:
            return rollout(self.method.integrator, f, x0, start, h, us, checkpoint)
        return rollout_with_cost(self.method.integrator, f, L, x0, start, h, us, checkpoint)

    def objective(self, z, data):
        return self.objective_and_constraints(z, data)[0]

    def name(self, sizes: str, extra: str = "") -> str:
        graded, free = "" if self.method.grid is None else ", graded", ", free T" if self.free else ""
        return f"{self.system.name}/{self.method.label}({sizes}{graded}{free}{extra})"

    def initial_guess_of(self, state_times, controls: int):
        """``data ->`` z0: states moving linearly at ``state_times``, ``controls`` middle controls, then T's guess."""
        system, T_guess = self.system, self.T_guess

        def initial_guess(data):
            X = guess_states(system, data.x0, state_times)
            return jnp.concatenate([X.ravel(), jnp.asarray(guess_controls(system, controls).ravel()),
                                    jnp.asarray(T_guess)])

        return initial_guess

    def collocation_nodes(self, z, data):
        """A collocation's ``z`` as the states x_0..x_N (x_0 = data.x0), the node controls and the rest of ``z``."""
        N, n, m = self.N, self.n, self.m
        nX, nU = N * n, (N + 1) * m
        X = jnp.reshape(z[:nX], (N, n))
        xs = jnp.concatenate([jnp.asarray(data.x0)[None], X], axis=0)
        return xs, jnp.reshape(z[nX : nX + nU], (N + 1, m)), z[nX + nU :]

    def collocation_nlp(self, midpoints: bool = False) -> NLP:
        """:meth:`node_nlp` of a collocation: states at its N nodes, controls and path rows at each node (and
        ``midpoints``)."""
        N, controls = self.N, 2 * self.N + 1 if midpoints else self.N + 1
        blocks = collocation_blocks(N, self.n, self.m, self.fixed, self.system.n_path, self.T_lo.size, midpoints)
        return self.node_nlp(
            N, controls, controls, objective=self.objective, constraints=self.constraints,
            initial_guess=self.initial_guess_of(self.times[1:], controls), unravel=self.unravel,
            jacobian_sparsity=sparsity(blocks), name=self.name(f"N={N}"),
            stage_structure=collocation_structure(N, self.n, self.m, self.fixed.size, self.system.n_path,
                                                  self.T_lo.size, midpoints),
        )

    def node_nlp(self, nodes: int, controls: int, path_points: int, **functions) -> NLP:
        """The NLP of decisions ``[states at `nodes` nodes, `controls` controls, T]`` bounded on every node, whose
        rows are the defects (``nodes`` n, = 0), the required final values, then path rows at ``path_points``."""
        system, arrays = self.system, self.system.arrays()
        x_lo, x_hi = node_state_bounds(system, nodes)
        p_lo, p_hi = path_bounds(system, path_points)
        zeros = np.zeros(nodes * self.n + self.fixed.size)
        return NLP(
            c_lower=np.concatenate([zeros, p_lo]),
            c_upper=np.concatenate([zeros, p_hi]),
            z_lower=np.concatenate([x_lo, np.tile(arrays["u_lower"], controls), self.T_lo]),
            z_upper=np.concatenate([x_hi, np.tile(arrays["u_upper"], controls), self.T_hi]),
            z_scale=np.concatenate([np.tile(self.sx, nodes), np.tile(control_scale(system), controls), self.T_scale]),
            **functions,
        )


@program_cache(maxsize=256)
def _path_violation_fn(system: System):
    lower = jnp.asarray(np.asarray(system.path_lower, dtype=np.float64))
    upper = jnp.asarray(np.asarray(system.path_upper, dtype=np.float64))

    @jax.jit
    def violation(times, states, controls, params):
        g = jax.vmap(lambda x, u, t: system.path_constraints(x, u, t, params))(states, controls, times)
        return jnp.max(jnp.maximum(jnp.maximum(lower - g, g - upper), 0.0))

    return violation


def path_violation(system: System, times, states, controls, params) -> float:
    """max over the points and the path constraints of the amount by which g leaves [path_lower, path_upper], in
    the constraints' own units (0.0 for a system without path constraints); NaN where g is not finite."""
    if not system.n_path:
        return 0.0
    return float(_path_violation_fn(system)(jnp.asarray(times), jnp.asarray(states), jnp.asarray(controls), params))


@program_cache(maxsize=256)
def transcribe(system: System, transcription: AbstractTranscription) -> NLP:
    """The NLP for (system, transcription), built once: solvers cache their compiled functions per NLP object.

    Its ``key`` (:mod:`myriad.runtime.compilation.programs`) is the system's source and the transcription's
    configuration when both are plain; otherwise None, and its programs are traced afresh in every process."""
    nlp = transcription.transcribe(system)
    key = program_key(programs.system_key(system), programs.describe(transcription))
    return nlp if key is None or nlp.key is not None else dataclasses.replace(nlp, key=key)


@program_cache(maxsize=256)
def _trajectory(nlp: NLP, system: System, midpoints: bool, batched: bool = False) -> CompiledFunction:
    """``(z, data) ->`` the trajectory on the grid and its per-interval local errors, one program per NLP and shapes
    (an eager unravel would re-trace its scan on every solve). ``batched``: vmapped over a batch's members, one
    dispatch for all of them (one per member dominated large batches)."""

    def trajectory(z, data):
        times, states, controls = nlp.unravel(z, data)
        return times, states, controls, interval_errors(system, times, states, controls, data.params,
                                                        midpoints=midpoints)

    return CompiledFunction(jax.vmap(trajectory) if batched else trajectory,
                            program_key(nlp.key, f"trajectory:{midpoints}:{REFERENCE_SUBSTEPS}:{batched}"))


def _trajectories(system: System, transcription: AbstractTranscription, nlp: NLP, z: np.ndarray, data,
                  batched: bool = True) -> Any:
    """``(times, states, controls, per-interval errors)`` as host arrays; ``batched``: each member's, from one
    program over a batch (``z`` and ``data`` with a leading batch axis)."""
    program, args = _trajectory(nlp, system, transcription.quadrature == "simpson", batched), (z, data)
    program.compile(*args)
    arrays = [np.asarray(a) for a in program(*args)]
    return [tuple(a[i] for a in arrays) for i in range(z.shape[0])] if batched else tuple(arrays)


def _solution(system: System, transcription: AbstractTranscription, solver, nlp: NLP, res, data,
              trajectory: tuple | None = None) -> Solution:
    """A Solution from an NLP result: the trajectory on the transcription's grid (``trajectory``, or computed here),
    the discretised defect and the relative local error of the dynamics on that grid."""
    # Simpson's rule sees a midpoint control: the grid interleaves nodes and midpoints (see error.py).
    midpoints = transcription.quadrature == "simpson"
    if trajectory is None:
        trajectory = _trajectories(system, transcription, nlp, np.asarray(res.z, dtype=np.float64), data, False)
    times, states, controls, per_interval = trajectory
    defect = (states[-1] - np.asarray(system.final_values))[system.final_mask]
    error = estimate(per_interval, times[::2] if midpoints else times)
    return Solution(
        system=system.name, transcription=transcription.label, solver=solver.label,
        integrator=transcription.quadrature, times=times, states=states, controls=controls,
        cost=float(res.objective), defect=[float(d) for d in defect], converged=bool(res.success),
        status=res.status, solver_code=int(res.solver_code), message=res.message, iterations=int(res.iterations),
        constraint_violation=float(res.constraint_violation), compile_seconds=float(res.compile_seconds),
        solve_seconds=float(res.solve_seconds), error_estimate=error.value, interval_errors=error.intervals,
        intervals=transcription.grid_intervals, final_time=float(times[-1]),
        path_violation=path_violation(system, times, states, controls, data.params),
    )
