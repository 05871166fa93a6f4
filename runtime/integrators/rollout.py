"""Rollouts: many steps of one integrator over a grid, with ``lax.scan``."""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp

from .base import AbstractIntegrator, Dynamics

__all__ = ["rollout", "rollout_with_cost", "with_running_cost"]


def rollout(
    integrator: AbstractIntegrator,
    f: Dynamics,
    x0: Any,
    t0: Any,
    h: Any,
    controls: Any,
    checkpoint: bool = False,
) -> Any:
    """The states (N + 1, n) at the nodes t_k = t0 + k h (``h`` negative: backwards in time), or at the node times
    ``t0`` themselves (any spacing) when ``h`` is None, of x' = f(x, u, t) from x0 (row 0), one ``integrator`` step per
    interval, the control linear from controls[k] to controls[k + 1] (``controls``: (N + 1, m)) on interval k.

    ``checkpoint``: differentiate with rematerialisation: reverse mode keeps only the state at each node and
    recomputes the step's intermediates on the way back; values unchanged, derivatives the same up to rounding (when
    it pays: :class:`~myriad.runtime.transcriptions.SingleShooting`).
    """
    x0 = jnp.asarray(x0)
    controls = jnp.asarray(controls)
    if h is None:
        times = jnp.asarray(t0)
        steps = (times[:-1], times[1:] - times[:-1])
        at = lambda t, dt: (t, dt)  # noqa: E731
    else:
        # t_k = t0 + k h rather than a running sum, so rounding does not accumulate along the grid.
        steps = (jnp.arange(controls.shape[0] - 1, dtype=x0.dtype),)
        at = lambda k: (t0 + k * h, h)  # noqa: E731

    def body(x, inputs):
        *when, u0, u1 = inputs
        x_next = integrator.step(f, x, *at(*when), u0, u1)
        return x_next, x_next

    if checkpoint:
        # prevent_cse=False: inside a scan the loop already keeps XLA from merging the recomputation away.
        body = jax.checkpoint(body, prevent_cse=False, policy=jax.checkpoint_policies.nothing_saveable)
    _, xs = jax.lax.scan(body, x0, (*steps, controls[:-1], controls[1:]))
    return jnp.concatenate([x0[None], xs], axis=0)


def rollout_with_cost(
    integrator: AbstractIntegrator,
    f: Dynamics,
    running_cost: Callable[[Any, Any, Any], Any],
    x0: Any,
    t0: Any,
    h: Any,
    controls: Any,
    checkpoint: bool = False,
) -> tuple[Any, Any]:
    """:func:`rollout` of the state augmented with the running cost, d/dt [x, c] = [f(x, u, t), L(x, u, t)],
    c(t0) = 0, by the same ``integrator``, so the cost carries exactly the discretisation error of the states (with
    Heun on the 100-step grid, how the published setting measures cost).

    Returns:
        ``(states (N + 1, n), cost (N + 1,))``: ``cost[k]`` is the integral of L from t0 to t_k.
    """
    x0 = jnp.asarray(x0)
    n = x0.shape[0]
    y0 = jnp.concatenate([x0, jnp.zeros((1,), dtype=x0.dtype)])
    ys = rollout(integrator, with_running_cost(f, running_cost, n), y0, t0, h, controls, checkpoint)
    return ys[:, :n], ys[:, n]


def with_running_cost(f: Dynamics, running_cost: Callable[[Any, Any, Any], Any], n: int) -> Dynamics:
    """The vector field of ``[x, c]`` with ``c' = L(x, u, t)``: the augmented system every cost-carrying rollout
    integrates (one definition, so that all of them accumulate the cost identically)."""

    def f_aug(y, u, t):
        x = y[:n]
        return jnp.concatenate([f(x, u, t), jnp.reshape(running_cost(x, u, t), (1,))])

    return f_aug
