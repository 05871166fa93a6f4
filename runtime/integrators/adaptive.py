"""An adaptive-step integrator (diffrax) for simulation and evaluation, not for transcription."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from .base import AbstractIntegrator, lerp

__all__ = ["Adaptive"]

# diffrax (and equinox under it: ~2.5 s of imports) is imported when a step is first traced, not with the package: a
# process whose programs come from the store (myriad.runtime.compilation.programs) never traces one.
_SOLVERS = ("tsit5", "dopri5", "dopri8")


@dataclasses.dataclass(frozen=True)
class Adaptive(AbstractIntegrator):
    """An embedded Runge-Kutta pair with PID step-size control, via ``diffrax.diffeqsolve``.

    Each call of :meth:`step` solves x' = f(x, u(s), s) on [t, t + h] to the tolerance

        ||e||_rms <= 1,   e_i = err_i / (atol + rtol |x_i|),

    with the control linear in s, as for the fixed-step integrators. Restarting the solver at every node is
    deliberate: a piecewise-linear control has a kink at each node, and a step that straddles a kink would degrade the
    embedded error estimate. Differentiable in reverse mode only (diffrax's checkpointed adjoint), unlike
    :class:`~myriad.runtime.integrators.DormandPrince`, every solve's re-simulation. A step whose solve fails
    (``max_steps`` exhausted, non-finite values) returns NaN rather than raising, so failures survive ``jax.vmap``.

    Attributes:
        method: "tsit5" (default), "dopri5" or "dopri8".
        rtol, atol: relative and absolute tolerances.
        pcoeff, icoeff: PID controller coefficients (a PI controller by default: the vector field is smooth
            within one interval).
        max_steps: the most steps one interval may take.
    """

    label: ClassVar[str] = "adaptive"
    fixed_step: ClassVar[bool] = False
    order: ClassVar[int] = 5

    method: str = "tsit5"
    rtol: float = 1e-8
    atol: float = 1e-10
    pcoeff: float = 0.4
    icoeff: float = 1.0
    max_steps: int = 4096

    def __post_init__(self):
        if self.method not in _SOLVERS:
            raise ValueError(f"Adaptive: unknown method {self.method!r}; expected one of {sorted(_SOLVERS)}")
        if not (self.rtol > 0 and self.atol > 0):
            raise ValueError(f"Adaptive: rtol and atol must be positive, got rtol={self.rtol}, atol={self.atol}")
        if self.max_steps < 1:
            raise ValueError(f"Adaptive: max_steps must be at least 1, got {self.max_steps}")

    def step(self, f, x, t, h, u0, u1):
        def field(s, y, args):
            return f(y, lerp(u0, u1, (s - t) / h), s)

        import diffrax

        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(field),
            {"tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8}[self.method](),
            t0=t,
            t1=t + h,
            dt0=None,
            y0=x,
            stepsize_controller=diffrax.PIDController(
                rtol=self.rtol, atol=self.atol, pcoeff=self.pcoeff, icoeff=self.icoeff
            ),
            max_steps=self.max_steps,
            throw=False,
        )
        ok = sol.result == diffrax.RESULTS.successful
        return jnp.where(ok, sol.ys[-1], jnp.nan)
