"""Heun's method (explicit trapezoidal rule): the integrator of the published setting."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from .base import AbstractIntegrator

__all__ = ["Heun"]


@dataclasses.dataclass(frozen=True)
class Heun(AbstractIntegrator):
    """Heun's method, order 2:

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
