r"""Implicit gradients for end-to-end learning: differentiate a *converged* plan by the implicit function theorem on
its KKT conditions.

The rule is the solvers' one (:mod:`myriad.runtime.solvers.implicit`), reached through the solver's
``differentiable_solve``; here it only takes the learner's arguments ``(params, x0, z0)`` and answers an
:class:`ImplicitSolve`. A solve that did not converge, or an inaccurate KKT solve (a singular KKT matrix), gives NaN
cotangents, never a silent gradient; the learner checks ``converged`` (``E2EConfig.on_failure``).
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
    """``(params, x0, z0) -> ImplicitSolve``: ``solver``'s pure solve of ``nlp`` from ``z0``, differentiable in
    ``params`` and ``x0`` by the implicit function theorem (reverse mode); the start (the NLP's variables, or the
    interior point's primal-dual ``WarmStart``) is a warm start only and gets a zero cotangent. The default solver is
    an :class:`Extragradient` with ``tol=1e-9`` and 20,000 iterations: the implicit derivative is only as accurate as
    the solution."""
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
