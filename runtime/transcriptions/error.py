"""The discretisation error of a direct solve: the relative local error of the dynamics on every interval.

A direct transcription replaces x' = f(x, u, t) by one step of some rule per interval (a Runge-Kutta step for
shooting, a collocation defect for trapezoidal and Hermite-Simpson). On interval k = [t_k, t_{k+1}] of its grid, the
local error compares the method's own end state with an accurate integration of the true dynamics from the method's
own start state, under the control the method assumes on that interval:

    e_k,i = | x_{k+1,i} - x~_i(t_{k+1}) | / s_i,     x~' = f(x~, u(t), t),  x~(t_k) = x_k,

with s_i = 1 + max |x_i| over the solution's points (:func:`~myriad.runtime.solution.state_magnitudes`, Betts' weight
w_i + 1), and the estimate is max over k and i. The scale is the solution's own magnitude, an absolute and a relative
tolerance in one, as an ODE solver's atol + rtol |x| with atol = rtol: never the state's bounds, so a wide safety bound
([-50, 50] around a state within [-2, 2]) cannot loosen the criterion (with the bounds as the scale it was 50 times
looser there). This is Betts' relative local error in its "re-integrate each interval" form (Betts 2010, sec. 4.7.1):
for a method of local order p + 1 it falls as h^{p+1}, so halving the step of Heun shooting or trapezoidal collocation
divides it by about 8, of RK4 shooting or Hermite-Simpson by about 32.

The control on an interval is the one the method's rule sees: the linear interpolant of its two node values
(shooting, trapezoidal), or for Hermite-Simpson (quadrature "simpson", whose grid interleaves nodes and midpoints)
the quadratic through u_k, u_{k+1/2}, u_{k+1}, which Simpson's rule integrates exactly; a linear interpolant with a
kink at the midpoint would add an O(h^3) control-interpolation term and hide the method's O(h^5).

The accurate integration is classical RK4 with 16 substeps per interval: its error is 16^4 = 65536 times below one
RK4 step of the same size, so it never limits the estimate of a method of order at most 4. It is explicit: on a
problem stiff enough that h/16 lies outside RK4's stability region it overestimates (a false warning, never a false
pass), and where it diverges outright the interval's error is +inf (a step far too long for the dynamics: refinement
splits it first); NaN is kept for a trajectory that is itself not finite. The intervals need not be equal: each is
integrated over its own [t_k, t_{k+1}], so a non-uniform grid (a transcription's ``grid``) is measured the same way.
Multiple shooting's node variables are the end states of their intervals, so an unconverged continuity
defect shows up here too. The times are physical (``unravel``'s): with a free final time each interval is
integrated over its length in t at the solved T, so the estimate is that of the dynamics the user wrote.

References:
    J. T. Betts, "Practical Methods for Optimal Control and Estimation Using Nonlinear Programming", 2nd ed.,
    SIAM 2010, sec. 4.7.1 (estimating the discretisation error).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.caches import program_cache
from ..solution import state_magnitudes
from ..system import System

__all__ = ["ErrorEstimate", "REFERENCE_SUBSTEPS", "estimate", "interval_errors", "local_errors"]

REFERENCE_SUBSTEPS = 16


@dataclasses.dataclass(frozen=True)
class ErrorEstimate:
    """The relative local error of a trajectory.

    Attributes:
        value: max over intervals and states: +inf where the reference integration diverged on an interval, NaN
            where the trajectory is not finite.
        intervals: (N,) the max over states on each interval of the method's grid.
        interval_times: (N + 1,) the interval boundaries.
    """

    value: float
    intervals: np.ndarray
    interval_times: np.ndarray


def _quadratic(u0, um, u1, c):
    # Lagrange basis on c = 0, 1/2, 1; with um = (u0 + u1) / 2 it is exactly the linear interpolant.
    return u0 * (1.0 - c) * (1.0 - 2.0 * c) + um * 4.0 * c * (1.0 - c) + u1 * c * (2.0 * c - 1.0)


def _reference_end(f, x, t, h, u0, um, u1, substeps):
    hs = h / substeps

    def body(j, x):
        c = j / substeps
        dc = 1.0 / substeps
        s = t + c * h
        k1 = f(x, _quadratic(u0, um, u1, c), s)
        k2 = f(x + 0.5 * hs * k1, _quadratic(u0, um, u1, c + 0.5 * dc), s + 0.5 * hs)
        k3 = f(x + 0.5 * hs * k2, _quadratic(u0, um, u1, c + 0.5 * dc), s + 0.5 * hs)
        k4 = f(x + hs * k3, _quadratic(u0, um, u1, c + dc), s + hs)
        return x + (hs / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    return jax.lax.fori_loop(0, substeps, body, x)


def _errors_body(system: System, substeps: int):
    def errors(params, scale, t0, h, x0, x1, u0, um, u1):
        f = lambda x, u, t: system.dynamics(x, u, t, params)  # noqa: E731
        ref = jax.vmap(lambda *a: _reference_end(f, *a, substeps))(x0, t0, h, u0, um, u1)
        finite = jnp.all(jnp.isfinite(jnp.concatenate([x0, x1, u0, um, u1], axis=1)), axis=1, keepdims=True)
        diverged = jnp.where(finite, jnp.inf, jnp.nan)  # the reference diverged / the trajectory is not finite
        return jnp.max(jnp.where(jnp.isfinite(ref), jnp.abs(x1 - ref) / scale, diverged), axis=1)

    return errors


@program_cache(maxsize=256)
def _local_errors_fn(system: System, midpoints: bool, substeps: int):
    # One jitted program per system and grid shape (jit's own cache); params are traced, so new parameters reuse it.
    return jax.jit(functools.partial(interval_errors, system, midpoints=midpoints, substeps=substeps))


def local_errors(system: System, times, states, controls, params, *, midpoints: bool = False,
                 substeps: int = REFERENCE_SUBSTEPS) -> ErrorEstimate:
    """The relative local error of a direct solution on its own grid (see the module docstring).

    Args:
        system: the system.
        times, states, controls: the trajectory as ``unravel`` returns it: (K,), (K, n), (K, m).
        params: the parameters the solve used.
        midpoints: the grid interleaves nodes and interval midpoints (Hermite-Simpson's 2N + 1 points): the
            intervals are every other step and the control on each is the quadratic through its three points.
        substeps: RK4 substeps of the reference integration per interval.

    Returns:
        An :class:`ErrorEstimate` over the N intervals.
    """
    times = np.asarray(times, dtype=np.float64)
    states = np.asarray(states, dtype=np.float64)
    controls = np.asarray(controls, dtype=np.float64)
    per_interval = _local_errors_fn(system, bool(midpoints), int(substeps))(times, states, controls, params)
    return estimate(per_interval, times[::2] if midpoints else times)


def interval_errors(system: System, times, states, controls, params, *, midpoints: bool = False,
                    substeps: int = REFERENCE_SUBSTEPS):
    """:func:`local_errors`' per-interval errors as a traceable function of the trajectory's arrays, to be part of a
    larger program (a solution's trajectory and its errors are one program, see ``transcriptions.base``)."""
    if midpoints:
        if times.shape[0] % 2 != 1:
            raise ValueError(f"a grid with midpoints has an odd number of points (2N + 1), got {times.shape[0]}")
        t, x, u, um = times[::2], states[::2], controls[::2], controls[1::2]
    else:
        t, x, u = times, states, controls
        um = 0.5 * (u[:-1] + u[1:])
    scale = state_magnitudes(states)
    return _errors_body(system, int(substeps))(params, scale, t[:-1], t[1:] - t[:-1], x[:-1], x[1:], u[:-1], um, u[1:])


def estimate(per_interval, interval_times) -> ErrorEstimate:
    """The :class:`ErrorEstimate` of per-interval errors (NaN anywhere: NaN)."""
    per_interval = np.asarray(per_interval, dtype=np.float64)
    value = float("nan") if np.any(np.isnan(per_interval)) else float(per_interval.max(initial=0.0))
    return ErrorEstimate(value=value, intervals=per_interval, interval_times=np.asarray(interval_times))
