r"""Dormand-Prince 5(4) with step-size control, for evaluation: the re-simulation every solve reports.

Why not :class:`~myriad.runtime.integrators.adaptive.Adaptive` (diffrax) there: that program is compiled once per
system and run once, so its compile time is what counts, and diffrax's general ``diffeqsolve`` compiles in about
twice the time (``python bench/resimulation.py``). What it gives up: reverse-mode gradients (``lax.while_loop`` has
none; forward mode works), so anything differentiated in reverse mode keeps ``Adaptive``.

One call of :meth:`DormandPrince.step` integrates ``x' = f(x, u(s), s)`` over one interval ``[t, t + h]`` with the
control linearly interpolated, restarting at every node as ``Adaptive`` does (a kink in the control between two
intervals would spoil an error estimate that straddled it). The interval is mapped to ``tau in [0, 1]``,
``dy/dtau = h f(y, u(tau), t + tau h)``, so a negative ``h`` needs no special case. Each step is the Dormand-Prince
pair (Hairer, Nørsett and Wanner, *Solving ODEs I*, table II.5.2; first same as last), the error

.. math:: e = \big\| (y_5 - \hat y_4) / (\mathrm{atol} + \mathrm{rtol} \max(|y|, |y_5|)) \big\|_{\mathrm{rms}},

accepted when at most 1, and the next step ``0.9 e^{-1/5}`` times this one, between 0.2 and 10 times (at most 1 after
a rejection), Hairer's controller. The first step tries the whole interval (the controls are smooth within it).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from .base import AbstractIntegrator, lerp

__all__ = ["DormandPrince"]

_C = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0)
_A = (
    (),
    (1 / 5,),
    (3 / 40, 9 / 40),
    (44 / 45, -56 / 15, 32 / 9),
    (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
    (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
    (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
)
_B5 = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0])
_B4 = np.array([5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40])
_E = tuple(_B5 - _B4)
SAFETY, SHRINK_MIN, GROW_MAX = 0.9, 0.2, 10.0


def _combine(coefficients, ks):
    return sum(c * k for c, k in zip(coefficients, ks) if c != 0.0)


@dataclasses.dataclass(frozen=True)
class DormandPrince(AbstractIntegrator):
    """Dormand-Prince 5(4) (see the module docstring). A step whose interval does not finish (``max_steps`` reached, a
    non-finite value) returns NaN, so a failure shows in the result, also under ``vmap``.

    Attributes:
        rtol, atol: relative and absolute tolerances of the local error (rms norm over the state).
        max_steps: the most steps, accepted or rejected, one interval may take.
    """

    label: ClassVar[str] = "dopri5"
    fixed_step: ClassVar[bool] = False
    order: ClassVar[int] = 5

    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = 4096

    def __post_init__(self):
        if not (self.rtol > 0 and self.atol > 0):
            raise ValueError(f"DormandPrince: rtol and atol must be positive, got rtol={self.rtol}, atol={self.atol}")
        if self.max_steps < 1:
            raise ValueError(f"DormandPrince: max_steps must be at least 1, got {self.max_steps}")

    def step(self, f, x, t, h, u0, u1):
        x = jnp.asarray(x)
        dtype = x.dtype

        def field(tau, y):
            return h * f(y, lerp(u0, u1, tau), t + tau * h)

        def attempt(carry):
            tau, y, dtau, k1, count, ok, rejected = carry
            dtau = jnp.minimum(dtau, 1.0 - tau)
            ks = [k1]
            for c, a in zip(_C[1:], _A[1:]):
                ks.append(field(tau + c * dtau, y + dtau * _combine(a, ks)))
            y_new = y + dtau * _combine(_B5, ks)  # equals the last stage's argument: ks[6] is f(y_new) (FSAL)
            scale = self.atol + self.rtol * jnp.maximum(jnp.abs(y), jnp.abs(y_new))
            err = jnp.sqrt(jnp.mean((dtau * _combine(_E, ks) / scale) ** 2))
            finite = jnp.isfinite(err) & jnp.all(jnp.isfinite(y_new))
            accept = finite & (err <= 1.0)
            factor = SAFETY * jnp.maximum(err, 1e-10) ** -0.2
            factor = jnp.clip(factor, SHRINK_MIN, jnp.where(rejected, 1.0, GROW_MAX))
            factor = jnp.where(finite, factor, SHRINK_MIN)
            # The last step lands on tau = 1 exactly, whatever the rounding of the sum.
            tau_new = jnp.where(dtau >= 1.0 - tau, 1.0, tau + dtau)
            return (jnp.where(accept, tau_new, tau), jnp.where(accept, y_new, y), dtau * factor,
                    jnp.where(accept, ks[6], k1), count + 1, ok & jnp.all(jnp.isfinite(y)), ~accept)

        def unfinished(carry):
            tau, _, _, _, count, ok, _ = carry
            return (tau < 1.0) & (count < self.max_steps) & ok

        one = jnp.ones((), dtype)
        start = (0.0 * one, x, one, field(0.0 * one, x), jnp.array(0), jnp.array(True), jnp.array(False))
        tau, y, _, _, _, ok, _ = jax.lax.while_loop(unfinished, attempt, start)
        return jnp.where(ok & (tau >= 1.0), y, jnp.nan)
