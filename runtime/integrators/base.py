"""The integrator interface: one explicit step of x' = f(x, u, t) with a linearly interpolated control."""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, Callable, ClassVar

__all__ = ["AbstractIntegrator", "Dynamics"]

# f(x, u, t) -> dx/dt, parameters already closed over.
Dynamics = Callable[[Any, Any, Any], Any]


@dataclasses.dataclass(frozen=True)
class AbstractIntegrator(abc.ABC):
    """One step of an ODE integrator over [t, t + h], the control the linear interpolant u(t + c h) = (1 - c) u0 +
    c u1 of its values at the two ends (a control given at a grid's nodes is piecewise linear and continuous: the
    published setting's parametrisation). Concrete integrators are frozen, hashable dataclasses (static ``jax.jit``
    arguments, fields of other configuration objects).
    """

    label: ClassVar[str]  # the registry name ("heun")
    order: ClassVar[int]  # the global order p (error O(h^p)) for smooth f and smooth controls
    # False for an integrator that adapts its own steps (simulation only): the transcriptions need fixed steps.
    fixed_step: ClassVar[bool] = True

    @abc.abstractmethod
    def step(self, f: Dynamics, x: Any, t: Any, h: Any, u0: Any, u1: Any) -> Any:
        """x(t + h) from the state x (n,) at t under the vector field f(x, u, t), the controls u0 at t and u1 at
        t + h (m,); h may be negative (backwards)."""


def lerp(u0: Any, u1: Any, c: float) -> Any:
    """The control at fraction ``c`` of a step: (1 - c) u0 + c u1, written so c = 0 and c = 1 are exact."""
    return u0 + c * (u1 - u0)
