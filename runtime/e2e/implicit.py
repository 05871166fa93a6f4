r"""Implicit gradients for end-to-end learning: differentiate a *converged* plan by the implicit function theorem on
its KKT conditions.

The rule is the solvers' one (:mod:`myriad.runtime.solvers.implicit`), reached through the solver's
``differentiable_solve``: the interior point's pure solve at its own active sets and multipliers, the extragradient's
at active sets estimated from the solution (distances to the bounds) with least-squares multipliers, so the rule does
not depend on the solver's own multiplier convention. Here it only takes the learner's arguments ``(params, x0,
z0)`` and answers an :class:`ImplicitSolve`.

A solve that did not converge never yields a silent gradient: the backward pass returns NaN for every cotangent
then, and also when the KKT solve is inaccurate (a singular KKT matrix: active constraints that are not linearly
independent, or a free direction of zero curvature). The learner checks ``converged`` and skips the step or falls
back to unrolling (``E2EConfig.on_failure``).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax

from ..data import ProblemData
from ..nlp import NLP
from ..solvers.extragradient import Extragradient
from ..solvers.interior_point import InteriorPoint
from ..status import Status

__all__ = ["ImplicitSolve", "make_implicit_solve"]


class ImplicitSolve(NamedTuple):
    """A converged solve: ``z`` carries the implicit derivative; ``converged``, ``iterations`` and ``kkt`` do not."""

    z: jax.Array
    converged: jax.Array
    iterations: jax.Array
    violation: jax.Array
    warm: Any = None  # the interior point's primal-dual warm start for the next solve (None: the extragradient's)


def make_implicit_solve(nlp: NLP, solver: Extragradient | InteriorPoint | None = None
                        ) -> Callable[[Any, Any, Any], ImplicitSolve]:
    """``(params, x0, z0) -> ImplicitSolve``: the solver's pure solve from ``z0``, differentiable in ``params`` and
    ``x0`` by the implicit function theorem (reverse mode, ``jax.custom_vjp``); the start (the NLP's variables, or the
    interior point's primal-dual ``WarmStart``) is a warm start only and gets a zero cotangent.

    Args:
        nlp: the problem; solver: an :class:`Extragradient` run to its tolerance (default ``tol=1e-9``, 20,000
            iterations: the implicit derivative is only as accurate as the solution), or an :class:`InteriorPoint`.

    A non-converged solve returns NaN cotangents (never a silent gradient); check ``converged``.
    """
    solver = Extragradient(tol=1e-9, max_iter=20_000) if solver is None else solver
    if not isinstance(solver, (Extragradient, InteriorPoint)):
        raise TypeError(f"make_implicit_solve: expected an Extragradient or an InteriorPoint, got "
                        f"{type(solver).__name__}")
    raw = solver.differentiable_solve(nlp)

    def solve(params, x0, z0):
        out = raw(ProblemData(params, x0), jax.lax.stop_gradient(z0))
        # The extragradient says whether it converged, the interior point gives its status and a warm start.
        converged = out.converged if hasattr(out, "converged") else out.status == int(Status.CONVERGED)
        warm = getattr(out, "warm", None)
        return ImplicitSolve(out.z, converged, out.iterations, out.violation,
                             None if warm is None else jax.lax.stop_gradient(warm))

    return solve
