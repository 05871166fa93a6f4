"""SLSQP (Kraft's sequential least-squares quadratic programming) through SciPy, with exact JAX derivatives."""

from __future__ import annotations

import dataclasses
import time
from typing import Any, ClassVar, final

import jax
import numpy as np

from ..compilation import CompiledFunction
from ..data import require_float64
from ..nlp import NLP, NLPResult
from ..status import from_scipy_slsqp
from .base import (
    AbstractNLPSolver,
    ScaledProblem,
    cached,
    canonical_data,
    constraint_violation,
    initial_point,
    split_constraints,
)

__all__ = ["SLSQP"]


@final
@dataclasses.dataclass(frozen=True)
class SLSQP(AbstractNLPSolver):
    """Sequential quadratic programming with a BFGS Lagrangian Hessian, ``scipy.optimize.minimize(method="SLSQP")``.

    Each iteration solves the quadratic program

    .. math::
        \\min_d\\ \\nabla F^\\top d + \\tfrac12 d^\\top B d \\quad\\text{s.t.}\\quad
        h(w) + \\nabla h^\\top d = 0,\\quad g(w) + \\nabla g^\\top d \\ge 0,\\quad w^l \\le w + d \\le w^u

    (as a least-squares problem on the LDL factors of the BFGS matrix ``B``) and line-searches along ``d`` on an
    L1 merit function. The NLP's constraints are split into SciPy's one-sided form (:func:`split_constraints`).

    Gradient and (dense) Jacobian are exact and jit-compiled once per NLP; SLSQP works in ``w = z / nlp.z_scale``
    like every solver (see :class:`ScaledProblem`). SLSQP is dense (``O(n^2)`` memory, ``O(n^3)`` per iteration):
    meant for small transcriptions and for cross-checking.

    The returned ``multipliers`` follow IPOPT's sign convention, ``dF/dz + (dc/dz)^T y = bound terms``: SciPy's
    ``mu`` (for ``L = F - mu^T [h; g]``) becomes ``y_E = -mu_E`` and ``y_i = mu_{U,i} - mu_{L,i}``.

    Attributes:
        tol: SciPy's ``ftol``: the stopping accuracy on the objective change, the Lagrangian gradient and the sum
            of constraint violations. On ill-conditioned problems ``z`` is only about ``sqrt(tol)`` accurate.
        max_iter: SciPy's ``maxiter``.
        constr_viol_tol: the largest constraint or bound violation a successful solve may have.
    """

    label: ClassVar[str] = "slsqp"

    tol: float = 1e-9
    max_iter: int = 500
    constr_viol_tol: float = 1e-6

    def __post_init__(self):
        if not self.tol > 0 or not self.constr_viol_tol > 0:
            raise ValueError("SLSQP: tol and constr_viol_tol must be positive")
        if self.max_iter < 1:
            raise ValueError("SLSQP: max_iter must be at least 1")

    def solve(self, nlp: NLP, data: Any, z0: Any = None) -> NLPResult:
        require_float64("SLSQP.solve")
        import scipy.optimize  # here, not at the top: its import costs every other solver's first solve about 0.15 s
        fns = cached(nlp, "slsqp", lambda: _Derivatives(ScaledProblem.from_nlp(nlp)))
        problem = fns.problem
        data = canonical_data(data)
        w0 = np.clip(problem.to_w(initial_point(nlp, data, z0)), problem.w_lower, problem.w_upper)
        compile_seconds = fns.prepare(w0, data)

        f = fns.objective.executable(w0, data)
        g = fns.gradient.executable(w0, data)
        constraints = []
        eq, upper, lower = split_constraints(problem.c_lower, problem.c_upper)
        c_lo, c_up = problem.c_lower, problem.c_upper
        if problem.n_constraints:
            cw, jw = _Last(fns.constraints.executable(w0, data), data), _Last(fns.jacobian.executable(w0, data), data)
            if eq.size:
                constraints.append(
                    {"type": "eq", "fun": lambda w: cw(w)[eq] - c_lo[eq], "jac": lambda w: jw(w)[eq]}
                )
            if upper.size + lower.size:
                constraints.append(
                    {
                        "type": "ineq",
                        "fun": lambda w: np.concatenate([c_up[upper] - cw(w)[upper], cw(w)[lower] - c_lo[lower]]),
                        "jac": lambda w: np.concatenate([-jw(w)[upper], jw(w)[lower]]),
                    }
                )

        start = time.perf_counter()
        res = scipy.optimize.minimize(
            lambda w: float(f(w, data)),
            w0,
            jac=lambda w: np.asarray(g(w, data)),
            method="SLSQP",
            bounds=scipy.optimize.Bounds(problem.w_lower, problem.w_upper),
            constraints=constraints,
            options={"ftol": self.tol, "maxiter": self.max_iter},
        )
        solve_seconds = time.perf_counter() - start

        z = problem.to_z(res.x)
        multipliers = c = None
        if problem.n_constraints:
            c = np.asarray(fns.constraints(res.x, data))
            multipliers = _to_ipopt_multipliers(np.asarray(res.multipliers), problem.n_constraints, eq, upper, lower)
        violation = constraint_violation(nlp, z, c)
        objective = float(f(res.x, data))
        success = res.status == 0 and violation <= self.constr_viol_tol and np.isfinite(objective)
        message = str(res.message)
        if res.status == 0 and not success:
            message = (
                f"SLSQP terminated successfully, but the constraint violation {violation:.3g} exceeds "
                f"constr_viol_tol={self.constr_viol_tol:.3g} (or the objective is not finite)"
            )
        return NLPResult(
            z=z,
            objective=objective,
            status=from_scipy_slsqp(int(res.status), bool(success)),
            solver_code=int(res.status),
            message=message,
            iterations=int(res.nit),
            constraint_violation=violation,
            multipliers=multipliers,
            compile_seconds=compile_seconds,
            solve_seconds=solve_seconds,
        )


def _to_ipopt_multipliers(mu: np.ndarray, m: int, eq: np.ndarray, upper: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """SciPy's multipliers of ``[h; g_U; g_L]`` as one multiplier per NLP constraint, in IPOPT's convention."""
    y = np.zeros(m)
    y[eq] = -mu[: eq.size]
    y[upper] += mu[eq.size : eq.size + upper.size]
    y[lower] -= mu[eq.size + upper.size : eq.size + upper.size + lower.size]
    return y


class _Derivatives:
    """The compiled functions SLSQP calls, for one NLP (in scaled variables ``w``)."""

    def __init__(self, problem: ScaledProblem):
        self.problem = problem
        f, c = problem.objective, problem.constraints
        self.objective = CompiledFunction(f)
        self.gradient = CompiledFunction(jax.grad(f))
        if problem.n_constraints:
            self.constraints = CompiledFunction(c)
            # Dense Jacobian: reverse mode costs one pass per constraint, forward mode one per variable.
            jacobian = jax.jacrev(c) if problem.n_constraints < problem.n_variables else jax.jacfwd(c)
            self.jacobian = CompiledFunction(jacobian)

    def prepare(self, w0: np.ndarray, data: Any) -> float:
        seconds = self.objective.compile(w0, data) + self.gradient.compile(w0, data)
        if self.problem.n_constraints:
            seconds += self.constraints.compile(w0, data) + self.jacobian.compile(w0, data)
        return seconds


class _Last:
    """``fn(w, data)`` of the last ``w``: SciPy asks for the equality and inequality parts of ``c`` separately."""

    def __init__(self, fn, data):
        self._fn, self._data, self._key = fn, data, None

    def __call__(self, w):
        key = np.asarray(w).tobytes()
        if key != self._key:
            self._value, self._key = np.asarray(self._fn(w, self._data)), key
        return self._value
