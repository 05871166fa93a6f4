"""Explicit (forward) Euler."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from .base import AbstractIntegrator

__all__ = ["Euler"]


@dataclasses.dataclass(frozen=True)
class Euler(AbstractIntegrator):
    """Forward Euler, order 1:

        x_{k+1} = x_k + h f(x_k, u_k, t_k).

    Only the control at the start of the step is used.
    """

    label: ClassVar[str] = "euler"
    order: ClassVar[int] = 1

    def step(self, f, x, t, h, u0, u1):
        del u1
        return x + h * f(x, u0, t)
