"""Polish a fitted model with full-batch L-BFGS, optionally anchored on the true rollouts of earlier plans.

Why and how much (docs/notes/node-training.md, "L-BFGS polish and plan anchors"): full-batch L-BFGS
(``optax.lbfgs``, zoom line search) takes an Adam fit's training loss one to two orders of magnitude lower, and the
*anchors*, the true system's trajectories under the earlier rounds' plans, keep the next plan close to the last one,
so that round by round the plans converge as in iterative learning control.

The objective is ``loss(train, window) + anchor_weight * loss(anchors, full horizon)`` with the losses of
:mod:`.losses`; the whole run is one compiled ``lax.while_loop``, cached on its static configuration. The polished
parameters are returned only when the objective and the parameters are finite; otherwise the starting ones, with
``status=Stop.NON_FINITE``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import optax.tree_utils as otu

from ..learn.dataset import _count
from ..learn.loop import Stop
from .losses import SCALES, fit_integrator, layout, state_scale, window_losses

__all__ = ["PolishConfig", "PolishResult", "polish", "TRACES"]

TRACES = {"polish": 0}  # traces of the compiled run (the tests' "no recompiles" check)


@dataclasses.dataclass(frozen=True)
class PolishConfig:
    """L-BFGS polish settings.

    Attributes:
        iterations: the most L-BFGS iterations.
        window: multiple-shooting window on the dataset (1..N); None: single shooting over the whole horizon.
        anchor_weight: weight of the anchors' full-horizon loss (0: anchors ignored; docs/notes/node-training.md).
        scale: the loss's state scale, ``"range"``, ``"data"`` or ``"none"`` (see :mod:`.losses`).
        gtol: stop when the gradient norm falls below this (0: run all iterations).
    """

    iterations: int = 300
    window: int | None = 10
    anchor_weight: float = 10.0
    scale: str = "data"
    gtol: float = 0.0

    def __post_init__(self):
        if _count(self.iterations) < 1:
            raise ValueError(f"PolishConfig: iterations must be an integer >= 1, got {self.iterations!r}")
        if self.window is not None and _count(self.window) < 1:
            raise ValueError(f"PolishConfig: window must be an integer >= 1 or None, got {self.window!r}")
        for name in ("anchor_weight", "gtol"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise ValueError(f"PolishConfig: {name} must be a finite number >= 0, got {v!r}")
        if self.scale not in SCALES:
            raise ValueError(f"PolishConfig: unknown scale {self.scale!r}; expected one of {SCALES}")


@dataclasses.dataclass(frozen=True)
class PolishResult:
    """The outcome of :func:`polish`: ``(before, after)`` pairs of the objective, the full-horizon validation loss
    and the anchors' loss (NaN without anchors); ``status`` is ``Stop.CONVERGED`` (finite, returned) or
    ``Stop.NON_FINITE`` (the start returned)."""

    theta: Any
    objective: tuple[float, float]
    validation: tuple[float, float]
    anchor_loss: tuple[float, float]
    iterations: int
    seconds: float
    status: Stop
    message: str

    def record(self) -> dict[str, Any]:
        num = lambda v: v if math.isfinite(v) else None  # noqa: E731
        return {"objective": [num(v) for v in self.objective], "validation": [num(v) for v in self.validation],
                "anchor_loss": [num(v) for v in self.anchor_loss], "iterations": self.iterations,
                "seconds": round(self.seconds, 3), "status": str(self.status)}


@functools.partial(jax.jit, static_argnames=("model", "integrator", "n_steps", "window", "iterations"))
def _run(train, frozen, spec, inv, t0, h, x, u, xa, ua, xv, uv, weight, gtol, *, model, integrator, n_steps, window,
         iterations):
    TRACES["polish"] += 1
    full = layout(n_steps)

    def losses(tr):
        """The objective, the validation loss and the anchors' loss."""
        theta = model.combine(tr, frozen)

        def mean(lay, xs, us):
            return jnp.mean(window_losses(model, integrator, lay, theta, spec, t0, h, us, xs, inv))

        anchor = mean(full, xa, ua) if xa.shape[0] else jnp.zeros(())
        return mean(layout(n_steps, window), x, u) + weight * anchor, mean(full, xv, uv), anchor

    def objective(tr):
        return losses(tr)[0]

    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(objective)

    def step(carry):
        params, state = carry
        value, grad = value_and_grad(params, state=state)
        updates, state = opt.update(grad, state, params, value=value, grad=grad, value_fn=objective)
        return optax.apply_updates(params, updates), state

    def going(carry):
        _, state = carry
        k, value = otu.tree_get(state, "count"), otu.tree_get(state, "value")
        return (k == 0) | ((k < iterations) & (otu.tree_norm(otu.tree_get(state, "grad")) >= gtol)
                           & jnp.isfinite(value))

    # NOTE: optax mixes Python floats with int32 counters, which strict promotion (the tests' setting) rejects.
    with jax.numpy_dtype_promotion("standard"):
        before = losses(train)
        params, state = jax.lax.while_loop(going, step, (train, opt.init(train)))
        after = losses(params)
    return params, before, after, otu.tree_get(state, "count")


def polish(model: Any, dataset: Any, theta: Any, config: PolishConfig = PolishConfig(), *,
           anchors: Any = None) -> PolishResult:
    """Polish ``theta`` (usually an Adam fit of ``model``) on ``dataset.train`` and ``anchors`` (whole trajectories on
    the dataset's grid, a :class:`~myriad.runtime.learn.dataset.Trajectories`, or None) by L-BFGS."""
    if not isinstance(config, PolishConfig):
        raise TypeError(f"polish: config must be a PolishConfig, got {type(config).__name__}")
    model.check_params(theta)
    times = np.asarray(dataset.times, dtype=np.float64)
    n_steps = times.shape[0] - 1
    window = None if config.window is None else min(config.window, n_steps)
    integrator = fit_integrator(dataset.sampling)
    f64 = lambda a: jnp.asarray(np.asarray(a, dtype=np.float64))  # noqa: E731
    n, m = model.system.n_states, model.system.n_controls
    xa, ua = (f64(np.zeros((0, n_steps + 1, k))) for k in (n, m)) if anchors is None else (
        f64(anchors.states), f64(anchors.controls))
    val = dataset.validation if dataset.validation.states.shape[0] else dataset.train
    train, frozen = model.partition(jax.tree.map(f64, theta))
    inv = f64(1.0 / state_scale(model.system, dataset.train.states, config.scale))
    start = time.perf_counter()
    params, before, after, count = _run(
        train, frozen, model.system.default_params(jnp.float64), inv, f64(times[0]),
        f64((times[-1] - times[0]) / n_steps), f64(dataset.train.states), f64(dataset.train.controls), xa, ua,
        f64(val.states), f64(val.controls), f64(config.anchor_weight), f64(config.gtol), model=model,
        integrator=integrator, n_steps=n_steps, window=window, iterations=config.iterations)
    before, after = [tuple(float(v) for v in b) for b in (before, after)]
    if xa.shape[0] == 0:
        before, after = (*before[:2], math.nan), (*after[:2], math.nan)
    finite = math.isfinite(after[0]) and all(bool(jnp.all(jnp.isfinite(a))) for a in jax.tree.leaves(params))
    status = Stop.CONVERGED if finite else Stop.NON_FINITE
    message = (f"L-BFGS, {int(count)} iterations: objective {before[0]:.3e} -> {after[0]:.3e}, validation "
               f"{before[1]:.3e} -> {after[1]:.3e}" if finite else
               f"L-BFGS reached a non-finite objective or parameters after {int(count)} iterations; the starting "
               f"parameters are kept")
    return PolishResult(theta=model.combine(params, frozen) if finite else theta, objective=(before[0], after[0]),
                        validation=(before[1], after[1]), anchor_loss=(before[2], after[2]), iterations=int(count),
                        seconds=time.perf_counter() - start, status=status, message=message)
