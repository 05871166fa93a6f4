"""The fixed-step explicit Runge-Kutta methods the transcriptions step with: Euler, Heun, midpoint and RK4."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from .base import AbstractIntegrator, lerp

__all__ = ["Euler", "Heun", "Midpoint", "RK4"]


@dataclasses.dataclass(frozen=True)
class Euler(AbstractIntegrator):
    """Forward Euler, order 1: x_{k+1} = x_k + h f(x_k, u_k, t_k) (the control at the start of the step only)."""

    label: ClassVar[str] = "euler"
    order: ClassVar[int] = 1

    def step(self, f, x, t, h, u0, u1):
        del u1
        return x + h * f(x, u0, t)


@dataclasses.dataclass(frozen=True)
class Heun(AbstractIntegrator):
    """Heun's method (explicit trapezoidal rule), order 2: the integrator of the published setting.

        k1 = f(x_k, u_k, t_k)
        k2 = f(x_k + h k1, u_{k+1}, t_k + h)
        x_{k+1} = x_k + h (k1 + k2) / 2.

    With the running cost appended as an extra state this is exactly how the published setting measures cost
    (see :func:`~myriad.runtime.integrators.rollout_with_cost`): L is evaluated at the Euler predictor, not at the
    corrected x_{k+1}.
    """

    label: ClassVar[str] = "heun"
    order: ClassVar[int] = 2

    def step(self, f, x, t, h, u0, u1):
        k1 = f(x, u0, t)
        k2 = f(x + h * k1, u1, t + h)
        return x + 0.5 * h * (k1 + k2)


@dataclasses.dataclass(frozen=True)
class Midpoint(AbstractIntegrator):
    """Explicit midpoint rule, order 2: x_{k+1} = x_k + h f(x_k + h k1 / 2, (u_k + u_{k+1}) / 2, t_k + h / 2),
    k1 = f(x_k, u_k, t_k)."""

    label: ClassVar[str] = "midpoint"
    order: ClassVar[int] = 2

    def step(self, f, x, t, h, u0, u1):
        k1 = f(x, u0, t)
        return x + h * f(x + 0.5 * h * k1, lerp(u0, u1, 0.5), t + 0.5 * h)


@dataclasses.dataclass(frozen=True)
class RK4(AbstractIntegrator):
    """Classical Runge-Kutta, order 4:

        k1 = f(x_k, u_k, t_k)
        k2 = f(x_k + h k1 / 2, u_m, t_k + h / 2)
        k3 = f(x_k + h k2 / 2, u_m, t_k + h / 2)
        k4 = f(x_k + h k3, u_{k+1}, t_k + h)
        x_{k+1} = x_k + h (k1 + 2 k2 + 2 k3 + k4) / 6,      u_m = (u_k + u_{k+1}) / 2.

    Order 4 holds for the piecewise-linear control itself; the error of approximating a curved control by its
    linear interpolant is a separate O(h^2) effect of the control parametrisation, not of the integrator.
    """

    label: ClassVar[str] = "rk4"
    order: ClassVar[int] = 4

    def step(self, f, x, t, h, u0, u1):
        um = lerp(u0, u1, 0.5)
        th = t + 0.5 * h
        k1 = f(x, u0, t)
        k2 = f(x + 0.5 * h * k1, um, th)
        k3 = f(x + 0.5 * h * k2, um, th)
        k4 = f(x + h * k3, u1, t + h)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
