r"""The ``InteriorPoint`` configuration: validation, and the hooks of the pure tier (:class:`AbstractPureSolver`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar, final

import jax
import jax.numpy as jnp
import numpy as np

from ...nlp import NLP
from ...status import Status
from ..base import ScaledProblem, cached
from ..implicit import Active, differentiable
from ..pure import PureNLPSolver, ScaledEvaluation
from ..stepper import Staged, Stepper
from .loop import InteriorPointSolution, InteriorPointStepper, WarmStart
from .problem import Layout

__all__ = ["InteriorPoint"]

# A vmapped batch on a CPU runs in chunks of CPU_CHUNK members (a wide batch's stage data streams from memory on every
# sweep), of CPU_CHUNK_SHARED where the batch is spread over several host devices (they share the caches). Measured:
# docs/notes/2026-12-05-solver-code-measurements.md.
# A single solve of single shooting takes the Riccati step from this many rollout steps (the published settings'
# 100 stay dense): Van der Pol, warm, 2-core AMD EPYC at load 4 (2026-12-06): 100 steps 0.017 s dense against
# 0.032 s Riccati, 400: 0.204 against 0.146, 800: 1.32 against 0.19 (dense grows like N^3, the recursion like N).
RICCATI_SINGLE_MIN = 250
CPU_CHUNK = 128
CPU_CHUNK_SHARED = 48

_MESSAGES = {
    Status.CONVERGED: "converged: scaled optimality error below tol and violation below constr_viol_tol",
    Status.ITERATION_LIMIT: "maximum number of iterations reached before convergence",
    Status.NOT_FINITE: "a non-finite value (NaN or inf) in the objective, constraints or their derivatives",
    Status.INFEASIBLE: "the restoration phase failed at an infeasible point (it converged to a minimiser of the "
                       "infeasibility, its line search failed, or its steps vanished): the problem looks locally "
                       "infeasible",
    Status.NOT_CONVERGED: "the line search, the restoration phase or the inertia correction failed at a feasible "
                          "point",
}


@final
@dataclasses.dataclass(frozen=True)
class InteriorPoint(PureNLPSolver):
    r"""A primal-dual interior-point method with exact second derivatives, entirely in JAX (one ``lax.while_loop``).

    After Wächter & Biegler (2006), the algorithm of IPOPT: inequality rows get slacks, bounds are handled by
    logarithmic barriers, and the barrier problems

    .. math::
        \min_x\ \sigma F(w) - \mu \sum_j \big(\ln(x_j - x^l_j) + \ln(x^u_j - x_j)\big)
        \quad\text{s.t.}\quad g(x) = 0,\qquad x = (w, s),

    are solved by Newton steps on the primal-dual optimality conditions for a decreasing ``mu``, with the exact
    Hessian, inertia correction, IPOPT's filter line search and its feasibility restoration phase (the modules, in
    this package's README). Everything runs in ``w = z / z_scale``, with IPOPT's gradient-based scaling on top.

    Statuses (each with its message): only ``CONVERGED`` (optimality error at most ``tol`` and the NLP's violation at
    most ``constr_viol_tol``) is a success; ``INFEASIBLE`` is an honest failure, not a proof of infeasibility, and a
    non-finite *trial* point is only rejected by the line search (``NOT_FINITE`` is a non-finite iterate).

    Pure tier: :meth:`solve_fn` is the jit-compiled ``(data, z0) ->`` :class:`InteriorPointSolution`;
    :meth:`solve_batch` runs a batch as one program: ``batch="vmap"`` vectorises the members, ``batch="map"`` solves
    them in turn. The Newton system is dense (:mod:`.kkt`), block-tridiagonal for collocation and multiple shooting
    (:mod:`.banded`: stage by stage, the exact inertia, cost linear in the number of stages) or, for single shooting
    without path rows, slacks or free time, stage by stage (:mod:`.riccati`: a Riccati recursion, the same
    certificate and steps); ``kkt="auto"`` (the default) takes the banded step for collocation and multiple
    shooting (single solves and batches), the Riccati step in vmapped batches of single shooting and in its single
    solves from ``RICCATI_SINGLE_MIN`` steps, and the dense one elsewhere, and ``batch="auto"``
    vmaps on an accelerator and, on a CPU, vmaps where the Riccati step applies and maps otherwise (see
    :meth:`batch_strategy`).
    ``jax.grad`` with respect to ``data`` of its ``z``, ``objective`` or ``multipliers`` is the implicit function
    theorem's (:mod:`..implicit`, stage by stage where the NLP has a stage structure; NaN cotangents for a solve that
    did not converge). Forward mode is not supported.

    Attributes:
        tol: the scaled optimality error (IPOPT's ``tol``) at which the solve stops.
        constr_viol_tol: the largest violation of the NLP's constraints a converged solve may have.
        max_iter: the iteration limit.
        second_order_correction: try one second-order correction when the full step is rejected.
        batch: how :meth:`solve_batch` runs its members: ``"auto"``, ``"vmap"`` or ``"map"`` (above).
        kkt: the Newton system's method: ``"auto"``, ``"dense"``, ``"riccati"`` or ``"banded"`` (above;
            ``"riccati"`` and ``"banded"`` raise for an NLP without their structure).
        chunk: how many members a vmapped batch keeps in flight (on each device; a stopped member's place is taken
            by the next waiting one): ``"auto"`` (``CPU_CHUNK`` on a CPU, ``CPU_CHUNK_SHARED`` over several host
            devices, all at once on an accelerator), ``None`` (all at once) or a positive int.

    References:
        Wächter & Biegler (2006), On the implementation of an interior-point filter line-search algorithm for
        large-scale nonlinear programming, Math. Programming 106. Nocedal & Wright (2006), Numerical Optimization,
        chapter 19.
    """

    label: ClassVar[str] = "interior_point"

    tol: float = 1e-8
    constr_viol_tol: float = 1e-6
    max_iter: int = 3000
    second_order_correction: bool = True
    batch: str = "auto"
    kkt: str = "auto"
    chunk: Any = "auto"

    def __post_init__(self):
        if not self.tol > 0 or not self.constr_viol_tol > 0:
            raise ValueError(f"InteriorPoint: tol ({self.tol}) and constr_viol_tol ({self.constr_viol_tol}) must "
                             f"be positive")
        if not isinstance(self.max_iter, int) or self.max_iter < 0:
            raise ValueError(f"InteriorPoint: max_iter must be a non-negative int, got {self.max_iter!r}")
        if self.batch not in ("auto", "vmap", "map"):
            raise ValueError(f"InteriorPoint: batch must be 'auto', 'vmap' or 'map', got {self.batch!r}")
        if self.kkt not in ("auto", "dense", "riccati", "banded"):
            raise ValueError(f"InteriorPoint: kkt must be 'auto', 'dense', 'riccati' or 'banded', got {self.kkt!r}")
        if not (self.chunk in ("auto", None) or (isinstance(self.chunk, int) and not isinstance(self.chunk, bool)
                                                 and self.chunk > 0)):
            raise ValueError(f"InteriorPoint: chunk must be 'auto', None or a positive int, got {self.chunk!r}")

    # ---- the pure tier (see AbstractPureSolver) ----------------------------------------------------------------

    def pure_solve(self, nlp: NLP) -> Callable[[Any, Any], InteriorPointSolution]:
        return self._compiled(nlp).raw

    def differentiable_solve(self, nlp: NLP) -> Callable[[Any, Any], InteriorPointSolution]:
        """:meth:`pure_solve`, which is differentiable already (the implicit-function rule at the solution's own
        active sets and multipliers, :mod:`..implicit`)."""
        return self.pure_solve(nlp)

    def pure_solve_batch(self, nlp: NLP) -> Callable[[Any, Any], InteriorPointSolution]:
        """The batch's solve: with ``kkt="auto"``, stage-wise (Riccati) when the batch is vmapped and the NLP
        allows it (see the class docstring)."""
        return self._compiled(nlp, vmapped=self.batch_strategy(nlp) == "vmap").raw

    def batch_stepper(self, nlp: NLP) -> Stepper:
        """:meth:`pure_solve_batch`'s solve as a :class:`Stepper` (a chunked batch's queue)."""
        return self._compiled(nlp, vmapped=self.batch_strategy(nlp) == "vmap").stepper

    def staged(self, nlp: NLP, batch: bool = False) -> Staged:
        """:meth:`solve`'s and :meth:`solve_batch`'s solve as two programs: the first without the restoration phase,
        the second, with it, compiled only when a solve (a batch's member) needs it (see the README)."""
        return self._compiled(nlp, vmapped=batch and self.batch_strategy(nlp) == "vmap").staged

    def cold_start(self, nlp: NLP) -> Callable[[Any, Any], WarmStart]:
        """The pure ``(data, z0) ->`` :class:`WarmStart` of IPOPT's default start from ``z0``, which a ``jnp.where``
        can choose against the ``warm`` of an earlier solution (one program for both)."""
        return self._compiled(nlp).cold

    def batch_strategy(self, problem: Any = None) -> str:
        """``batch``, with ``"auto"`` resolved (the class docstring): on a CPU, vmap only where the Riccati step
        applies (``kkt`` not ``"dense"``, ``problem`` single shooting that allows it). Collocation and multiple
        shooting map on a CPU: vmapped through :meth:`solve_batch`, their batches of 128 members or more have hung
        in XLA's CPU runtime (a batched LAPACK kernel waiting on its own thread pool; the same vmapped program called
        directly did not), which is open (docs/notes/2026-12-06-ipm-scaling.md); ``batch="vmap"`` asks for it."""
        if self.batch != "auto":
            return self.batch
        if jax.default_backend() != "cpu":
            return "vmap"
        return "vmap" if problem is not None and self.kkt != "dense" and _stagewise(problem) else "map"

    def batch_chunk(self, problem: Any = None) -> int | None:
        """``chunk``, with ``"auto"`` resolved (see the class docstring)."""
        if self.chunk != "auto":
            return self.chunk
        if jax.default_backend() != "cpu" or self.batch_strategy(problem) != "vmap":
            return None
        return CPU_CHUNK if len(jax.devices()) < 2 else CPU_CHUNK_SHARED

    def kkt_method(self, nlp: NLP, vmapped: bool = False) -> str:
        """The Newton system's method for ``nlp``: ``kkt``, with ``"auto"`` resolved: block-tridiagonal for an NLP
        with a stage structure (collocation, multiple shooting), stage-wise (Riccati) for a vmapped batch or a large
        single solve (``RICCATI_SINGLE_MIN`` steps) of single shooting that allows it, dense otherwise (see the class
        docstring; measured in docs/notes/2026-12-06-ipm-scaling.md)."""
        if self.kkt != "auto":
            return self.kkt
        if isinstance(nlp, NLP) and nlp.stage_structure is not None:
            return "banded"
        if vmapped:
            return "riccati" if _stagewise(nlp) else "dense"
        large = isinstance(nlp, NLP) and nlp.stage_index is not None and len(nlp.stage_index) >= RICCATI_SINGLE_MIN
        return "riccati" if large and _stagewise(nlp) else "dense"

    def outcome(self, out: InteriorPointSolution, z: np.ndarray, objective: float,
                violation: float) -> tuple[Status, int, str]:
        """The loop's status; ``CONVERGED`` only if the host's violation and objective agree (finite, within
        ``constr_viol_tol``)."""
        status = Status(int(out.status))
        if status is Status.CONVERGED and not (np.isfinite(objective) and violation <= self.constr_viol_tol):
            status = Status.NOT_CONVERGED
        return status, int(out.status), _MESSAGES[status]

    # ---- implementation ----------------------------------------------------------------------------------------

    def _compiled(self, nlp: NLP, vmapped: bool = False) -> _Compiled:
        method = self.kkt_method(nlp, vmapped)
        return cached(nlp, ("interior_point", self, method), lambda: _Compiled(ScaledProblem.from_nlp(nlp), self,
                                                                              method))


def _stagewise(nlp: NLP) -> bool:
    """Whether the stage-wise Newton step applies to ``nlp`` (:meth:`.problem.Layout.stagewise`), once per NLP."""
    return isinstance(nlp, NLP) and cached(nlp, ("interior_point", "stagewise"),
                                           lambda: Layout.stagewise(ScaledProblem.from_nlp(nlp)))


class _Compiled(ScaledEvaluation):
    """The pure (differentiable) solve and the report's objective and constraints, for one NLP and configuration."""

    def __init__(self, problem: ScaledProblem, solver: InteriorPoint, method: str):
        super().__init__(problem)
        layout = Layout(problem, method)
        stepper = InteriorPointStepper(layout, solver.tol, solver.constr_viol_tol, solver.max_iter,
                                       solver.second_order_correction)
        self.cold, self.stepper, self.staged = stepper.cold, stepper.stepper, stepper.staged
        self.raw = differentiable(stepper.stepper.solve, problem, _held,
                                  lambda out: out.status == int(Status.CONVERGED), multipliers=True)


def _held(data: Any, out: InteriorPointSolution) -> Active:
    """Where the implicit rule linearises: the solution's own verdict, a bound multiplier larger than the gap to its
    bound (at the barrier solution ``z_l (w - l) = mu``: the two sides are ``sqrt(mu)`` apart only for a degenerate
    bound), a row active when it is an equality or its slack is held; and its own multipliers (IPOPT's sign)."""
    y = jnp.where(out.active_rows, out.multipliers, 0.0)
    return Active(y, ~(out.active_lower | out.active_upper), out.active_rows)
