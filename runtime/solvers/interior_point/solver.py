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
from ..stepper import Stepper
from .loop import InteriorPointSolution, InteriorPointStepper, WarmStart
from .problem import Layout

__all__ = ["InteriorPoint"]

# A vmapped batch on a CPU, in chunks of this many members: 1024 Epidemic / Mould Fungicide NLPs (published setting,
# 2-core AMD EPYC, quiet) took 3.64 / 0.48 s vmapped at once, 2.76 / 0.42 s in chunks of 256, 2.61 / 0.40 s of 128
# and 2.65 / 0.42 s of 64: a wide batch's stage data (~40 per member and stage) streams from memory on every sweep.
CPU_CHUNK = 128
# With the batch spread over several host devices (one thread each, solve_batch), smaller chunks: two devices share
# the caches. 1024 NLPs on two devices, program alone, interleaved runs (2026-12-04, medians of 4): Epidemic 2.83 /
# 3.07 / 3.23 s in chunks of 32 / 64 / 128 (48 and 32 alike in a second run), Mould Fungicide 0.47 / 0.42 / 0.44 s
# (32 / 64 / 128). On one device chunks of 36 were slower than 128 (Epidemic 5.9 against 4.5 s). With the places of
# stopped members refilled (stepper.queued), Epidemic on two devices, interleaved, medians of 4: 4.02 / 4.03 / 3.98 /
# 4.27 s with 32 / 48 / 64 / 96 members in flight (a slower hour: chunks of 48 took 5.10 s against the queue's 4.44).
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

    are solved by Newton steps on the primal-dual optimality conditions for a decreasing ``mu``. The Hessian of the
    Lagrangian is exact (forward over reverse, or the transcription's own ``lagrangian_derivatives``: single
    shooting's stages), the Newton system is factorised densely with inertia correction (:mod:`.kkt`), steps obey
    the fraction-to-the-boundary rule and are globalised by IPOPT's filter line search with a second-order
    correction (:mod:`.loop`), and IPOPT's feasibility restoration phase where that search fails
    (:mod:`.restoration`). Everything runs in ``w = z / z_scale`` (:class:`ScaledProblem`), with IPOPT's
    gradient-based scaling of the objective and rows on top.

    Statuses: ``CONVERGED`` (optimality error at most ``tol`` and the NLP's violation at most ``constr_viol_tol``);
    ``ITERATION_LIMIT``; ``INFEASIBLE`` (the restoration phase failed at an infeasible point, typically converging
    to a minimiser of the infeasibility: an honest failure, not a proof of infeasibility); ``NOT_FINITE`` (a NaN or
    inf in a value or derivative at an iterate; a non-finite *trial* point is only rejected by the line search);
    ``NOT_CONVERGED`` (line search, restoration or inertia correction failed at a feasible point). Only
    ``CONVERGED`` is a success.

    Pure tier: :meth:`solve_fn` is the jit-compiled ``(data, z0) ->`` :class:`InteriorPointSolution`, compiled once per
    NLP and shapes; :meth:`solve_batch` runs a batch as one program (each member keeps its status): ``batch="vmap"``
    vectorises the members (members that stop early are frozen), ``batch="map"`` solves them in turn. The Newton
    system is dense (:mod:`.kkt`) or, for single shooting without path rows, slacks or free time, stage by stage
    (:mod:`.riccati`: a Riccati recursion over the rollout's stages, the same certificate and steps); ``kkt="auto"``
    (the default) takes the stage-wise step in vmapped batches and the dense one elsewhere, and ``batch="auto"``
    vmaps on an accelerator and, on a CPU, vmaps where the stage-wise step applies and maps otherwise. Measured on
    the 2-core CPU (README.md): the stage-wise step vectorises across a vmapped batch where dense Cholesky
    factorisations of 101 variables do not, while a single solve of Epidemic or Van der Pol took 2.3x as long with
    it as with the dense step.
    ``jax.grad`` of a function of its ``z``, ``objective`` or ``multipliers`` with respect to ``data`` works through
    a ``jax.custom_vjp`` (implicit function theorem, :mod:`..implicit`), also under ``vmap``; a solve that did not
    converge gives NaN cotangents, never a silent gradient. Forward mode (``jax.jvp``) is not supported.

    Attributes:
        tol: the scaled optimality error (IPOPT's ``tol``) at which the solve stops.
        constr_viol_tol: the largest violation of the NLP's constraints a converged solve may have.
        max_iter: the iteration limit.
        second_order_correction: try one second-order correction when the full step is rejected.
        batch: how :meth:`solve_batch` runs its members: ``"auto"``, ``"vmap"`` or ``"map"`` (above).
        kkt: the Newton system's method: ``"auto"``, ``"dense"`` or ``"riccati"`` (above; ``"riccati"`` raises for
            an NLP without the stage structure).
        chunk: how many members a vmapped batch solves at once (on each device): ``"auto"`` (``CPU_CHUNK`` on a
            CPU, ``CPU_CHUNK_SHARED`` where the batch is spread over several host devices: their stage data stays
            in cache; all at once on an accelerator), ``None`` (all at once) or a positive int. The place of a
            member that stops is taken by the next waiting one (:func:`~myriad.runtime.solvers.stepper.queued`), so
            no chunk waits for its slowest member.

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
        if self.kkt not in ("auto", "dense", "riccati"):
            raise ValueError(f"InteriorPoint: kkt must be 'auto', 'dense' or 'riccati', got {self.kkt!r}")
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
        return self._batch_compiled(nlp).raw

    def batch_stepper(self, nlp: NLP) -> Stepper:
        """:meth:`pure_solve_batch`'s solve as a :class:`Stepper`: a chunked batch keeps ``chunk`` members in flight
        and refills the places of those that stop (:func:`~myriad.runtime.solvers.stepper.queued`)."""
        return self._batch_compiled(nlp).stepper

    def cold_start(self, nlp: NLP) -> Callable[[Any, Any], WarmStart]:
        """The pure ``(data, z0) ->`` :class:`WarmStart` of IPOPT's default start from ``z0``: what
        :meth:`pure_solve` does with an array ``z0``, as a start that a ``jnp.where`` can choose against the
        ``warm`` of an earlier solution (one program for both)."""
        return self._compiled(nlp).cold

    def batch_strategy(self, problem: Any = None) -> str:
        """``batch``, with ``"auto"`` resolved: vmap on an accelerator; on a CPU, vmap where the Newton step can be
        stage-wise (``kkt`` not ``"dense"``, ``problem`` an NLP that allows it) and map otherwise (measured: the
        class docstring)."""
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
        """The Newton system's method for ``nlp``: ``kkt``, with ``"auto"`` resolved: stage-wise (Riccati) for a
        vmapped batch of an NLP that allows it, dense otherwise (see the class docstring)."""
        if self.kkt != "auto":
            return self.kkt
        return "riccati" if vmapped and _stagewise(nlp) else "dense"

    def outcome(self, out: InteriorPointSolution, z: np.ndarray, objective: float,
                violation: float) -> tuple[Status, int, str]:
        """The loop's status; ``CONVERGED`` only if the host's violation and objective agree (finite, within
        ``constr_viol_tol``)."""
        status = Status(int(out.status))
        if status is Status.CONVERGED and not (np.isfinite(objective) and violation <= self.constr_viol_tol):
            status = Status.NOT_CONVERGED
        return status, int(out.status), _MESSAGES[status]

    # ---- implementation ----------------------------------------------------------------------------------------

    def _batch_compiled(self, nlp: NLP) -> _Compiled:
        """What :meth:`solve_batch` runs: stage-wise where the batch is vmapped (:meth:`kkt_method`)."""
        return self._compiled(nlp, vmapped=self.batch_strategy(nlp) == "vmap")

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
        self.cold, self.stepper = stepper.cold, stepper.stepper
        self.raw = differentiable(stepper.stepper.solve, problem, _held,
                                  lambda out: out.status == int(Status.CONVERGED), multipliers=True)


def _held(data: Any, out: InteriorPointSolution) -> Active:
    """Where the implicit rule linearises: the solution's own verdict, a bound multiplier larger than the gap to its
    bound (at the barrier solution ``z_l (w - l) = mu``: the two sides are ``sqrt(mu)`` apart only for a degenerate
    bound), a row active when it is an equality or its slack is held; and its own multipliers (IPOPT's sign)."""
    y = jnp.where(out.active_rows, out.multipliers, 0.0)
    return Active(y, ~(out.active_lower | out.active_upper), out.active_rows)
