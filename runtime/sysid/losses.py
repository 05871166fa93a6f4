"""The trajectory loss of system identification, and its multiple-shooting and curriculum variants.

On the uniform grid t_k = t_0 + k h, k = 0..N, the model with parameters theta is rolled out by a one-step integrator
Phi (the data's own, :func:`fit_integrator`) from an *observed* state x_{b,s} under the observed, piecewise-linear
controls, in windows of W steps starting at the nodes s in S: x~_{b,s+l} = Phi^l(x_{b,s}), l = 1..W. The loss is

    loss(theta) = sum_b m_b sum_{s in S} sum_{l=1..W} c_{s,l} gamma^l sum_i ((x~_{b,s+l,i} - x_{b,s+l,i}) / s_i)^2
                  / (sum_b m_b * K * n),

with m_b in {0, 1} a trajectory mask (a fixed-shape minibatch's padding), s_i a per-state scale, gamma in (0, 1] a
per-step discount (the published "crude curriculum"), c_{s,l} = 1 / (the number of windows predicting node s + l)
and K the number of distinct predicted nodes, so each predicted node weighs 1 in total. The layouts:

* single shooting, S = {0}, W = N: with gamma = 1 and s = 1 the published loss ``1/(B N n) sum ||x~ - x||^2``;
* multiple shooting (``tile=True``): S = {0, W, 2W, ...}; where W does not divide N the last window starts at N - W
  (overlapping its neighbour), so no rollout runs past t_N on invented controls. K = N;
* a horizon prefix (``tile=False``): S = {0}, the first W steps only (K = W), a curriculum stage.

Scales: ``"none"`` (s = 1, published), ``"range"`` (x_max,i - x_min,i where both bounds are finite, else max |x_i|
observed, else 1: HIV Treatment's T ~ 1000 and I ~ 0.04 then weigh alike) or ``"data"`` (the spread of x_i in the
training data where smaller than that: Glucose's hormone moves over 0.2 % of its range).

:func:`validation_loss` and :func:`train_epoch` are the two compiled functions :func:`~.fit.fit` runs, jit-cached
on their static configuration (model, integrator, optimiser, layout, shapes): a second fit compiles nothing.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..integrators import RK4, AbstractIntegrator, rollout

__all__ = ["SCALES", "TRACES", "WindowLayout", "fit_integrator", "layout", "state_scale", "train_epoch",
           "validation_loss", "window_losses"]

SCALES = ("none", "range", "data")


def fit_integrator(sampling: Any) -> AbstractIntegrator:
    """The integrator a fit rolls the model out with: the one that generated the data, except ``Adaptive`` (reverse-mode
    gradients only, and a loss only piecewise smooth in theta through its step-size controller), replaced by ``RK4``
    on the same grid: one differentiable step per interval, whose error is small next to any modelling error."""
    integ = sampling.integrator
    return integ if integ.fixed_step else RK4()


def state_scale(system: Any, states: Any, scale: str) -> np.ndarray:
    """The per-state scale s (n,) of the loss: ones for ``"none"``; see the module docstring for ``"range"`` and
    ``"data"``."""
    n = np.shape(states)[-1]
    if scale == "none":
        return np.ones(n)
    if scale not in SCALES:
        raise ValueError(f"scale must be one of {SCALES}, got {scale!r}")
    states = np.asarray(states, dtype=np.float64)  # concrete data: the scale is a constant of the loss
    a = system.arrays()
    s = a["x_upper"] - a["x_lower"]
    flat = states.reshape(-1, n)
    observed = np.max(np.abs(flat), axis=0) if states.size else np.zeros(n)
    s = np.where(np.isfinite(s) & (s > 0), s, observed)
    s = np.where(np.isfinite(s) & (s > 0), s, 1.0)
    if scale == "data" and states.size:
        spread = np.ptp(flat, axis=0)
        s = np.where(np.isfinite(spread) & (spread > 1e-12 * s), np.minimum(spread, s), s)
    return s


class WindowLayout(NamedTuple):
    """Where the windows of a loss start and how each predicted node is weighted (host arrays, fixed shapes).

    Attributes:
        starts: (J,) int, the windows' first nodes.
        window: W, the steps per window.
        weights: (J, W) float, c_{s,l} gamma^l for l = 1..W.
        count: K, the number of distinct predicted nodes (the loss divides by K n).
    """

    starts: np.ndarray
    window: int
    weights: np.ndarray
    count: int


def layout(n_steps: int, window: int | None = None, *, tile: bool = True, gamma: float = 1.0) -> WindowLayout:
    """The window layout over N = ``n_steps`` intervals of windows of W = ``window`` steps (None: N), tiled over the
    trajectory or only the first (``tile=False``), discounted by ``gamma`` (see the module docstring)."""
    window = n_steps if window is None else int(window)
    if not 1 <= window <= n_steps:
        raise ValueError(f"window must be between 1 and the N = {n_steps} steps of the grid, got {window}")
    if tile:
        starts = list(range(0, n_steps - window + 1, window))
        if starts[-1] + window < n_steps:
            starts.append(n_steps - window)  # an overlapping last window, rather than a rollout past t_N
    else:
        starts = [0]
    starts = np.asarray(starts, dtype=np.int64)
    nodes = starts[:, None] + np.arange(1, window + 1)[None, :]  # (J, W): the predicted nodes
    cover = np.bincount(nodes.ravel(), minlength=n_steps + 1)
    disc = gamma ** np.arange(1, window + 1, dtype=np.float64)
    weights = disc[None, :] / cover[nodes]
    return WindowLayout(starts, window, weights, int(np.count_nonzero(cover)))


def window_losses(model: Any, integrator: AbstractIntegrator, lay: WindowLayout, theta: Any, spec_params: Any,
                  t0: Any, h: Any, controls: Any, states: Any, inv_scale: Any) -> jax.Array:
    """Per-trajectory losses (B,) of the module docstring on observed ``controls`` (B, N+1, m) and ``states`` (B, N+1,
    n), with ``inv_scale`` = 1 / s (n,); traceable (``lay`` holds host arrays)."""

    def f(x, u, t):
        return model.vector_field(x, u, t, theta, spec_params)

    idx = lay.starts[:, None] + np.arange(lay.window + 1)[None, :]  # (J, W+1) node indices of each window
    x_start = states[:, lay.starts]  # (B, J, n): every window starts at an observed state
    u_win = controls[:, idx]  # (B, J, W+1, m)
    t_start = t0 + jnp.asarray(lay.starts, dtype=states.dtype) * h  # t_s, as the data's own grid computes it

    def one(x0, ts, us):
        return rollout(integrator, f, x0, ts, h, us)

    pred = jax.vmap(jax.vmap(one, in_axes=(0, 0, 0)), in_axes=(0, None, 0))(x_start, t_start, u_win)
    err = (pred[:, :, 1:] - states[:, idx[:, 1:]]) * inv_scale  # (B, J, W, n)
    per_node = jnp.sum(err * err, axis=-1)  # (B, J, W)
    n = states.shape[-1]
    return jnp.sum(per_node * jnp.asarray(lay.weights, dtype=states.dtype), axis=(1, 2)) / (lay.count * n)


# Incremented while tracing the two compiled functions below (Python runs only when JAX traces): how many times they
# were (re)compiled, for :func:`~.fit.fit`'s ``compile_count`` and the tests' "no recompiles" check.
TRACES = {"validation_loss": 0, "train_epoch": 0}


@functools.partial(jax.jit, static_argnames=("model", "integrator", "n_steps"))
def validation_loss(train, frozen, spec, inv, t0, h, x, u, *, model, integrator, n_steps):
    """The full-horizon single-shooting loss (gamma = 1) of ``model.combine(train, frozen)`` on (x, u)."""
    TRACES["validation_loss"] += 1
    theta = model.combine(train, frozen)
    return jnp.mean(window_losses(model, integrator, layout(n_steps), theta, spec, t0, h, u, x, inv))


@functools.partial(jax.jit, static_argnames=("model", "integrator", "optimizer", "shape", "batch_size"))
def train_epoch(train, frozen, opt_state, key, spec, inv, t0, h, x_all, u_all, *, model, integrator, optimizer,
                shape, batch_size):
    """One epoch: a permutation of the B trajectories from ``key``, padded with weight-0 repeats to whole batches of
    ``batch_size``, one optimiser step per batch on the loss of the layout ``shape = (N, W, tile, gamma)``. Returns
    ``(train, opt_state, key, mean training loss at the batches' pre-update parameters, all finite)``.
    """
    TRACES["train_epoch"] += 1
    n_steps, window, tile, gamma = shape
    lay = layout(n_steps, window, tile=tile, gamma=gamma)
    n_train = x_all.shape[0]
    n_batches = -(-n_train // batch_size)
    pad = n_batches * batch_size - n_train
    key, sub = jax.random.split(key)
    order = jax.random.permutation(sub, n_train) if n_batches > 1 else jnp.arange(n_train)
    order = jnp.concatenate([order, order[:pad]]).reshape(n_batches, batch_size)
    mask = jnp.concatenate([jnp.ones(n_train), jnp.zeros(pad)]).reshape(n_batches, batch_size)

    def batch_loss(tr, x, u, m):
        per = window_losses(model, integrator, lay, model.combine(tr, frozen), spec, t0, h, u, x, inv)
        return jnp.sum(per * m) / jnp.sum(m)

    def body(carry, batch):
        tr, st = carry
        idx, m = batch
        loss, g = jax.value_and_grad(batch_loss)(tr, x_all[idx], u_all[idx], m)
        ok = jnp.isfinite(loss) & jnp.all(jnp.asarray([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(g)]))
        # NOTE: optax mixes Python floats with its int32 step count (adam's b1 ** count), which strict promotion (the
        # tests' setting) rejects: standard promotion for optax's own arithmetic only, as the extragradient does.
        with jax.numpy_dtype_promotion("standard"):
            upd, st = optimizer.update(g, st, tr)
            return (optax.apply_updates(tr, upd), st), (loss, ok)

    (train, opt_state), (losses, oks) = jax.lax.scan(body, (train, opt_state), (order, mask))
    return train, opt_state, key, jnp.sum(losses * jnp.sum(mask, axis=1)) / n_train, jnp.all(oks)
