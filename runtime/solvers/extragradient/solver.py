r"""The ``Extragradient`` configuration: validation, and the hooks of the pure tier (:class:`AbstractPureSolver`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar, Literal, final

import jax.numpy as jnp
import numpy as np
import optax

from ...nlp import NLP
from ...status import Status
from ..base import ScaledProblem, cached
from ..implicit import differentiable, estimated_active
from ..pure import PureNLPSolver, ScaledEvaluation
from ..stepper import Stepper
from .loop import ExtragradientSolution, ExtragradientStepper

__all__ = ["Extragradient"]

_BOUNDS_MODES = ("projection", "sigmoid")
_SCALING_MODES = ("guess", "bounds")
_MESSAGES = {
    Status.CONVERGED: "converged: KKT residual and constraint violation below tol",
    Status.ITERATION_LIMIT: "maximum number of iterations reached before the KKT residual fell below tol",
    Status.NOT_FINITE: "stopped at a non-finite iterate (NaN or inf); try smaller steps",
}


@final
@dataclasses.dataclass(frozen=True)
class Extragradient(PureNLPSolver):
    r"""Gradient descent-ascent on the (augmented) Lagrangian with an extragradient look-ahead, in pure JAX.

    With equalities ``h(w) = 0`` and one-sided inequalities ``g(w) <= 0`` (each finite side of a non-equality row),
    the method seeks a saddle point of the augmented Lagrangian

    .. math::
        L_\rho(w, \lambda, \mu) = F(w) + \lambda^\top h + \frac{\rho}{2}\lVert h\rVert^2
            + \frac{1}{2\rho}\sum_i \big(\max(0, \mu_i + \rho g_i)^2 - \mu_i^2\big),
            \qquad \min_{w \in B}\ \max_{\lambda,\ \mu \ge 0}\ L_\rho

    (``rho = penalty``; ``rho = 0`` is the plain Lagrangian ``F + lambda^T h + mu^T g``). Writing
    ``v = (w, lambda, mu)`` and ``G(v) = (grad_w L, -grad_lambda L, -grad_mu L)``, one iteration is Korpelevich's
    extragradient step, with optax step rules ``T`` in place of a fixed step:

    .. math::
        v_{k+1/2} = \Pi\big(v_k + T(G(v_k))\big), \qquad v_{k+1} = \Pi\big(v_k + T(G(v_{k+1/2}))\big)

    The look-ahead damps the rotation that makes plain descent-ascent cycle around saddle points. ``Pi`` projects
    ``mu`` onto ``mu >= 0`` (projected multipliers, no slack variables) and the variables onto their box.

    Convergence is the KKT test at the current point (``lagrangian.py``): projected stationarity, feasibility and
    complementarity all at most ``tol``. Everything runs in ``w = z / z_scale`` (:class:`ScaledProblem`).

    Scaling:
        ``"guess"`` (default): a column scale ``d`` (the start's magnitudes) for the step rules and a row scale ``r``
        (the start Jacobian's rows in ``w / d``) for the Lagrangian, changes of variables that leave the KKT test,
        the violation and the multipliers as they are (the formulas: ``scaling.py``). Why: AMSGrad's steps are about
        ``lr`` whatever the gradient, so ``d`` makes them proportional to each variable's magnitude, and ``r`` turns
        the huge multipliers of rows of small variables into ``O(1)`` ones the dual ascent can reach.
        ``"bounds"``: ``d = 1`` and ``r = 1``, only ``z_scale``.

    Bounds:
        ``"projection"``: clip ``w`` to the box after every half-step. ``"sigmoid"``: ``w = l + (u - l) sigmoid(p)``
        for the variables with both bounds finite (the others clipped), approaching a bound only asymptotically.

    Penalty:
        When the violation stalls, ``rho`` grows by ``penalty_growth`` up to ``penalty_max`` (``penalty.py``); the
        dual steps are in units of ``rho / penalty``. Why: a small fixed ``rho`` stalls transcribed OCPs short of
        feasibility, a large one from the start stalls HS71.

    Step rules:
        The default primal rule is AMSGrad, Adam whose normaliser ``sqrt(v_max)`` never decreases. Why not Adam: its
        step stays about ``lr`` however small the gradient, so with its moments threaded through both half-steps it
        can settle where the gradients at the point and at the look-ahead cancel (KKT residual
        ``O(lr * ||Hessian||)``). AMSGrad's weakness is the converse: a huge gradient at the start shrinks that
        variable's steps for good. The dual step (plain ascent) sets the pace on equality-constrained problems; too
        large a one diverges.

    Measurements behind these choices and defaults: docs/notes/extragradient-tuning.md.

    The whole solve is one ``lax.while_loop`` over its iteration (:meth:`stepper`, also the end-to-end learner's
    unrolled planner): :meth:`solve_fn` and :meth:`solve_batch` are the pure tier's.

    Attributes:
        step: the primal step rule, an ``optax.GradientTransformation`` applied to ``grad_w L`` (descent), or a
            learning rate for ``optax.amsgrad`` (see "Step rules").
        dual_step: the dual step rule, applied to ``-grad_(lambda, mu) L`` (so that descent is ascent), or a learning
            rate for plain gradient ascent ``optax.sgd``.
        penalty: the initial augmented-Lagrangian weight ``rho >= 0``; 0 is the plain Lagrangian.
        penalty_growth: the factor by which ``rho`` grows when the violation stalls (1 keeps it fixed).
        penalty_max: the largest ``rho``.
        max_iter: the iteration limit.
        tol: the KKT tolerance (absolute, infinity norms).
        bounds: ``"projection"`` or ``"sigmoid"`` (see above).
        scale_objective: scale F so that its gradient at the start (with respect to ``v``) is at most 100 in the
            infinity norm (IPOPT's gradient-based rule); the KKT test then holds in the scaled units, and multipliers
            are reported unscaled.
        scaling: ``"guess"`` or ``"bounds"`` (see "Scaling").

    References:
        Korpelevich (1976), The extragradient method for finding saddle points and other problems.
        Gidel, Berard, Vignoud, Vincent & Lacoste-Julien (2019), A variational inequality perspective on generative
        adversarial networks. Reddi, Kale & Kumar (2018), On the convergence of Adam and beyond (AMSGrad).
        Howe, Dufort-Labbe, Rajkumar & Bacon (2022), Myriad: a real-world testbed to bridge trajectory optimization
        and deep learning.
    """

    label: ClassVar[str] = "extragradient"

    step: optax.GradientTransformation | float = 0.1
    dual_step: optax.GradientTransformation | float = 0.1
    penalty: float = 1.0
    penalty_growth: float = 10.0
    penalty_max: float = 1e4
    max_iter: int = 100_000
    tol: float = 1e-6
    bounds: Literal["projection", "sigmoid"] = "projection"
    scale_objective: bool = True
    scaling: Literal["guess", "bounds"] = "guess"

    def __post_init__(self):
        if self.bounds not in _BOUNDS_MODES:
            raise ValueError(f"Extragradient(bounds={self.bounds!r}): expected one of {_BOUNDS_MODES}")
        if self.scaling not in _SCALING_MODES:
            raise ValueError(f"Extragradient(scaling={self.scaling!r}): expected one of {_SCALING_MODES}")
        if not self.tol > 0 or self.max_iter < 1 or not self.penalty >= 0:
            raise ValueError("Extragradient: tol must be positive, max_iter at least 1 and penalty non-negative")
        if not self.penalty_growth >= 1 or not self.penalty_max >= self.penalty:
            raise ValueError("Extragradient: penalty_growth must be >= 1 (1 keeps the penalty fixed) and "
                             "penalty_max >= penalty")
        for name in ("step", "dual_step"):
            value = getattr(self, name)
            if not isinstance(value, (optax.GradientTransformation, float, int)):
                raise TypeError(f"Extragradient({name}=...): expected an optax.GradientTransformation or a learning "
                                f"rate, got {type(value).__name__}")

    # ---- the pure tier (see AbstractPureSolver) ----------------------------------------------------------------

    def pure_solve(self, nlp: NLP) -> Callable[[Any, Any], ExtragradientSolution]:
        return self._compiled(nlp).stepper.solve

    def stepper(self, nlp: NLP) -> ExtragradientStepper:
        """The solve of ``nlp`` with its iteration apart (built once per NLP and configuration)."""
        return self._compiled(nlp).stepper

    def differentiable_solve(self, nlp: NLP) -> Callable[[Any, Any], ExtragradientSolution]:
        """:meth:`pure_solve` with reverse mode in ``data`` by the implicit-function rule at active sets estimated from
        the solution (the cotangent of ``multipliers`` is ignored); NaN cotangents unless it converged."""
        problem = self._compiled(nlp).problem
        scale = jnp.asarray(problem.scale)
        return differentiable(self.pure_solve(nlp), problem,
                              lambda data, out: estimated_active(problem, data, out.z / scale),
                              lambda out: out.converged)

    def batch_stepper(self, nlp: NLP) -> Stepper:
        return self._compiled(nlp).stepper.stepper

    def outcome(self, out: ExtragradientSolution, z: np.ndarray, objective: float,
                violation: float) -> tuple[Status, int, str]:
        """``CONVERGED`` when the loop's KKT test passed and the objective is finite; ``ITERATION_LIMIT`` at
        ``max_iter`` at a finite point; otherwise ``NOT_FINITE`` (the loop stops early only at a non-finite point)."""
        if bool(out.converged) and np.isfinite(objective):
            status = Status.CONVERGED
        elif int(out.iterations) >= self.max_iter and np.all(np.isfinite(z)) and np.isfinite(objective):
            status = Status.ITERATION_LIMIT
        else:
            status = Status.NOT_FINITE
        return status, int(status), _MESSAGES[status]

    # ---- implementation ----------------------------------------------------------------------------------------

    def _compiled(self, nlp: NLP) -> _Compiled:
        return cached(nlp, ("extragradient", self), lambda: _Compiled(ScaledProblem.from_nlp(nlp), self))


class _Compiled(ScaledEvaluation):
    """The pure solve and the objective and constraints for the report, for one NLP and one solver configuration."""

    def __init__(self, problem: ScaledProblem, solver: Extragradient):
        super().__init__(problem)
        self.stepper = ExtragradientStepper(problem, solver)
