r"""The interior point's reverse mode: the one implicit-function rule (:mod:`myriad.runtime.solvers.implicit`) at the
solution's own active sets and multipliers.

"Held" is the interior-point solution's own verdict: the bound multiplier exceeds the distance to the bound
(``z_l > w - l``; at the barrier solution ``z_l (w - l) = mu``, so the two sides are ``sqrt(mu)`` apart only for a
degenerate bound), and a row is active when it is an equality or its slack is held. Its multipliers are IPOPT's sign,
so the rule pulls back the cotangents of ``z``, ``objective`` and ``multipliers``. Check ``status`` (or
``jnp.isfinite`` of the gradient): a solve that did not converge gives NaN cotangents.
"""

from __future__ import annotations

from typing import Any, Callable

import jax.numpy as jnp

from ...status import Status
from ..base import ScaledProblem
from ..implicit import Active
from ..implicit import differentiable as _differentiable
from .loop import InteriorPointSolution

__all__ = ["differentiable"]


def differentiable(raw: Callable[[Any, Any], InteriorPointSolution],
                   problem: ScaledProblem) -> Callable[[Any, Any], InteriorPointSolution]:
    """``raw`` with a ``jax.custom_vjp``: reverse mode in ``data`` by the implicit function theorem; ``z0`` gets a
    zero cotangent (a converged solution does not depend on the start). Forward mode (``jax.jvp``) is not defined."""
    m = problem.n_constraints

    def active(data: Any, out: InteriorPointSolution) -> Active:
        y = jnp.where(out.active_rows, out.multipliers, 0.0) if m else jnp.zeros(0, out.z.dtype)
        return Active(y, ~(out.active_lower | out.active_upper), out.active_rows)

    return _differentiable(raw, problem, active, lambda out: out.status == int(Status.CONVERGED), multipliers=True)
