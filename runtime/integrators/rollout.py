"""Rollouts: many steps of one integrator over a uniform grid, with ``lax.scan``."""

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
    """Integrate x' = f(x, u, t) from x(t0) = x0 over the grid t_k = t0 + k h, k = 0..N.

    The control is piecewise linear between its node values: on [t_k, t_k + h] it runs from controls[k] to
    controls[k + 1].

    Args:
        integrator: the one-step method.
        f: the vector field f(x, u, t).
        x0: initial state, shape (n,).
        t0: initial time (scalar).
        h: step size (scalar; negative integrates backwards in time).
        controls: control values at the N + 1 nodes, shape (N + 1, m).
        checkpoint: differentiate with rematerialisation: reverse mode keeps only the state at each node and
            recomputes the step's intermediates on the way back. Values are unchanged; derivatives are the same up
            to rounding. See :class:`~myriad.runtime.transcriptions.SingleShooting` for when it pays.

    Returns:
        The states at the N + 1 nodes, shape (N + 1, n); row 0 is x0.
    """
    x0 = jnp.asarray(x0)
    controls = jnp.asarray(controls)
    n_steps = controls.shape[0] - 1
    # t_k = t0 + k h rather than a running sum, so rounding does not accumulate along the grid.
    ks = jnp.arange(n_steps, dtype=x0.dtype)

    def body(x, inputs):
        k, u0, u1 = inputs
        x_next = integrator.step(f, x, t0 + k * h, h, u0, u1)
        return x_next, x_next

    if checkpoint:
        # prevent_cse=False: inside a scan the loop already keeps XLA from merging the recomputation away.
        body = jax.checkpoint(body, prevent_cse=False, policy=jax.checkpoint_policies.nothing_saveable)
    _, xs = jax.lax.scan(body, x0, (ks, controls[:-1], controls[1:]))
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
    """A rollout of the state augmented with the accumulated running cost.

    The augmented system is

        d/dt [x, c] = [f(x, u, t), L(x, u, t)],   c(t0) = 0,

    integrated by the same ``integrator``, so the cost carries exactly the discretisation error of the states. With
    Heun on the 100-step grid this is how the published setting measures cost.

    Args:
        integrator, f, x0, t0, h, controls, checkpoint: as in :func:`rollout`.
        running_cost: L(x, u, t) -> scalar.

    Returns:
        ``(states, cost)``: states at the nodes, shape (N + 1, n), and the accumulated integral int_{t0}^{t_k} L dt
        at each node, shape (N + 1,) (so ``cost[-1]`` is the whole integral).
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
