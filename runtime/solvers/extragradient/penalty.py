r"""The augmented-Lagrangian penalty ``rho`` (``Extragradient``'s "Penalty"): every ``_PENALTY_CHECK`` iterations,
``rho <- min(gamma rho, rho_max)`` if the violation fell by less than 10% since the last check and is above ``tol``;
the dual "gradients" are multiplied by ``rho / rho_0`` (:meth:`PenaltySchedule.dual_ratio`), as in the method of
multipliers. Measurements, and the schedules that were tried: docs/notes/extragradient-tuning.md ("Penalty schedule").
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["PenaltySchedule"]

# Iterations between checks of the constraint violation's progress. A short interval grows the penalty during a slow
# start (see the note's "Penalty schedule").
_PENALTY_CHECK = 2000
# The violation must fall below this fraction of its value at the previous check, or the penalty grows.
_STALL_RATIO = 0.9


class PenaltySchedule(NamedTuple):
    """The penalty's static schedule (the solver's ``penalty``, ``penalty_growth`` and ``penalty_max``); no growth
    once the violation is at most ``tol``, a check every ``every`` iterations."""

    rho0: float
    growth: float
    rho_max: float
    tol: float
    every: int = _PENALTY_CHECK

    def initial(self, dtype: Any) -> jax.Array:
        """``rho_0`` as a scalar of ``dtype`` (the loop carries ``rho``)."""
        return jnp.asarray(self.rho0, dtype=dtype)

    def dual_ratio(self, rho: jax.Array, dtype: Any) -> jax.Array:
        """The factor ``rho / rho_0`` on the dual "gradients" (1 when ``rho_0 = 0``)."""
        return rho / self.rho0 if self.rho0 > 0 else jnp.ones((), dtype=dtype)

    def update(self, k: jax.Array, rho: jax.Array, v_ref: jax.Array,
               violation: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(rho, v_ref)`` after iteration ``k`` (0-based) ended at ``violation``; unchanged except at checkpoints,
        i.e. when ``k + 1`` is a multiple of ``every``."""
        checkpoint = (k + 1) % self.every == 0
        stalled = checkpoint & (violation > _STALL_RATIO * v_ref) & (violation > self.tol)
        rho = jnp.where(stalled, jnp.minimum(rho * self.growth, self.rho_max), rho)
        v_ref = jnp.where(checkpoint, violation, v_ref)
        return rho, v_ref
