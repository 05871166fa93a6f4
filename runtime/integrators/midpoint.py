"""The explicit midpoint method."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from .base import AbstractIntegrator, lerp

__all__ = ["Midpoint"]


@dataclasses.dataclass(frozen=True)
class Midpoint(AbstractIntegrator):
    """Explicit midpoint rule, order 2:

        k1 = f(x_k, u_k, t_k)
        x_{k+1} = x_k + h f(x_k + h k1 / 2, (u_k + u_{k+1}) / 2, t_k + h / 2).
    """

    label: ClassVar[str] = "midpoint"
    order: ClassVar[int] = 2

    def step(self, f, x, t, h, u0, u1):
        k1 = f(x, u0, t)
        return x + h * f(x + 0.5 * h * k1, lerp(u0, u1, 0.5), t + 0.5 * h)
