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
    """One step of an ODE integrator over [t, t + h].

    The control is the linear interpolant of its values at the two ends of the step,

        u(t + c h) = (1 - c) u0 + c u1,   c in [0, 1],

    so a control trajectory given at the nodes of a grid is piecewise linear and continuous (the parametrisation of
    the published setting). A stage at fraction c of the step sees exactly that control.

    Concrete integrators are frozen, hashable dataclasses, so they can be static arguments of ``jax.jit`` and fields
    of other configuration objects.

    Attributes:
        label: the registry name (``"heun"``), used by the CLI and in reports.
        order: the global order of accuracy p (error O(h^p)) for smooth f and smooth controls.
        fixed_step: whether a transcription may use it (one step per grid interval, no step control).
    """

    label: ClassVar[str]
    order: ClassVar[int]
    # False for an integrator that adapts its own steps (simulation only): the transcriptions need fixed steps.
    fixed_step: ClassVar[bool] = True

    @abc.abstractmethod
    def step(self, f: Dynamics, x: Any, t: Any, h: Any, u0: Any, u1: Any) -> Any:
        """Advance x(t) to x(t + h).

        Args:
            f: the vector field f(x, u, t) -> dx/dt, shape (n,).
            x: the state at t, shape (n,).
            t: the time at the start of the step (scalar).
            h: the step size (scalar; may be negative to integrate backwards).
            u0: the control at t, shape (m,).
            u1: the control at t + h, shape (m,).

        Returns:
            The state at t + h, shape (n,).
        """


def lerp(u0: Any, u1: Any, c: float) -> Any:
    """The control at fraction ``c`` of a step: (1 - c) u0 + c u1, written so c = 0 and c = 1 are exact."""
    return u0 + c * (u1 - u0)
