"""Behaviour cloning's fit: the policy's network regressed onto expert actions, through the learning kit's loop.

    result = fit(policy, net, train, validation, FitConfig(), checkpoint_dir="ck", resume=True)
    result.net, result.stop, result.history      # the best network on the held-out pairs, why it stopped, the losses

The loss is the mean squared error of the normalised actions (``Policy.action`` against ``Policy.normalise`` of the
expert's controls), weighted per pair (a DAgger aggregate pads its arrays to a fixed size with weight 0, so one
compiled step serves every iteration). One epoch is ``steps`` Adam steps on the whole training set (a few thousand
pairs: a minibatch would only add noise), in one compiled scan, then the loss on the held-out pairs; the network
with the lowest held-out loss is kept, and ``patience`` epochs without a new best stop the fit
(``Stop.EARLY_STOPPING``). Checkpoints, resume, progress and the non-finite stop are
:func:`~myriad.runtime.learn.loop.train`'s.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

# A FieldError names the field, so `--set fit.x=...` / `--set dagger.x=...` is named by its dotted key.
from ..configs import FieldError
from ..learn.checkpoint import load_checkpoint, save_checkpoint
from ..learn.identity import arrays_id, describe, digest
from ..learn.loop import Step, Stop, check_run, checkpoint_path, train
from .policy import Policy

__all__ = ["FitConfig", "FitResult", "Pairs", "fit", "loss"]


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """How the policy is fitted to (observation, action) pairs.

    Attributes:
        learning_rate: Adam's step size.
        epochs: the most epochs.
        steps: full-batch Adam steps per epoch (one compiled call: the loop's overhead is per epoch).
        patience: stop after this many epochs without a lower held-out loss.
        width, depth: the policy network's hidden width and number of hidden layers.
        checkpoint_every: epochs between checkpoints (with a checkpoint folder).
    """

    learning_rate: float = 3e-3
    epochs: int = 400
    steps: int = 10
    patience: int = 40
    width: int = 64
    depth: int = 2
    checkpoint_every: int = 20

    def __post_init__(self):
        if isinstance(self.learning_rate, bool) or not 0 < self.learning_rate < np.inf:
            raise FieldError(f"learning_rate must be a positive number, got {self.learning_rate!r}", "learning_rate")
        for name in ("epochs", "steps", "patience", "width", "depth", "checkpoint_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise FieldError(f"{name} must be a positive integer, got {value!r}", name)


class Pairs(NamedTuple):
    """Observations (M, d), normalised expert actions (M, m) in [-1, 1] and weights (M,) (0: padding)."""

    obs: Any
    actions: Any
    weights: Any

    @classmethod
    def of(cls, obs: Any, actions: Any, weights: Any = None) -> Pairs:
        obs, actions = np.asarray(obs, np.float64), np.asarray(actions, np.float64)
        weights = np.ones(obs.shape[0]) if weights is None else np.asarray(weights, np.float64)
        return cls(obs, actions, weights)


class FitResult(NamedTuple):
    net: Any  # the best network on the held-out pairs
    stop: Stop
    message: str
    history: list  # (epoch, training loss, held-out loss)
    best: float  # its held-out loss


def loss(policy: Policy, net: Any, pairs: Pairs) -> Any:
    """The weighted mean squared error of the normalised actions."""
    err = policy.action(net, pairs.obs) - pairs.actions
    return jnp.sum(pairs.weights[:, None] * err * err) / (jnp.sum(pairs.weights) * policy.action_size)


@eqx.filter_jit
def _epoch(policy: Policy, optimizer: Any, steps: int, net: Any, opt_state: Any, train_pairs: Pairs,
           held_out: Pairs):
    params, static = eqx.partition(net, eqx.is_array)

    def one(carry, _):
        params, opt_state = carry
        value, grads = jax.value_and_grad(lambda p: loss(policy, eqx.combine(p, static), train_pairs))(params)
        with jax.numpy_dtype_promotion("standard"):  # optax's own arithmetic mixes its int32 count with floats
            updates, opt_state = optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), value

    (params, opt_state), values = jax.lax.scan(one, (params, opt_state), None, length=steps)
    net = eqx.combine(params, static)
    return net, opt_state, values[-1], loss(policy, net, held_out)


# One transformation object per learning rate: it is a static argument of the compiled epoch, so a new object per fit
# (each DAgger iteration refits) would compile the epoch again.
_adam = functools.lru_cache(maxsize=32)(optax.adam)


class _Fit:
    """The learner object of :func:`~myriad.runtime.learn.loop.train` (README.md of ``runtime/learn``)."""

    unit = "epoch"

    def __init__(self, policy, net, train_pairs, held_out, config, desc, path, identity):
        self.policy, self.config, self.desc, self.path = policy, config, desc, path
        self.train_pairs, self.held_out = train_pairs, held_out
        self.optimizer = _adam(config.learning_rate)
        self.net, self.opt_state = net, self.optimizer.init(eqx.filter(net, eqx.is_array))
        self.best_net, self.best, self.since, self.history = net, np.inf, 0, []
        self.stopped = ""  # the stop a checkpoint was written at ("": none), so a resume does not go on past it
        self.identity = identity  # (data id, config description)

    def step(self, index: int) -> Step:
        net, opt_state, value, held = _epoch(self.policy, self.optimizer, self.config.steps, self.net,
                                             self.opt_state, self.train_pairs, self.held_out)
        value, held = float(value), float(held)
        if not (np.isfinite(value) and np.isfinite(held)):
            return Step(Stop.NON_FINITE, f"epoch {index + 1}: the loss is not finite ({value}, {held})")
        self.net, self.opt_state = net, opt_state
        self.history.append((index + 1, value, held))
        if held < self.best:
            self.best_net, self.best, self.since = net, held, 0
        else:
            self.since += 1
        postfix = f"train {value:.2e}, held-out {held:.2e}"
        if self.since >= self.config.patience:
            self.stopped = Stop.EARLY_STOPPING.value
            return Step(Stop.EARLY_STOPPING, f"no lower held-out loss in {self.since} epochs", postfix)
        return Step(postfix=postfix)

    def save(self, done: int) -> None:
        data_id, description = self.identity
        save_checkpoint(self.path, theta=self.net, opt_state=self.opt_state, key=jnp.zeros(2, jnp.uint32),
                        epoch=done, best_theta=self.best_net, best_val=self.best, history=self.history,
                        dataset_id=data_id, config_id=digest(description), config=description,
                        extra={"since_best": self.since, "stopped": self.stopped})

    def restore(self) -> int:
        data_id, description = self.identity
        ck = load_checkpoint(self.path, {"theta": self.net, "opt_state": self.opt_state}, dataset_id=data_id,
                             config_id=digest(description), config=description)
        self.net, self.opt_state, self.best_net, self.best = ck.theta, ck.opt_state, ck.best_theta, ck.best_val
        self.history, self.since, self.stopped = ck.history, int(ck.extra["since_best"]), ck.extra["stopped"]
        return ck.epoch


def fit(policy: Policy, net: Any, train_pairs: Pairs, held_out: Pairs, config: FitConfig, *,
        checkpoint_dir: Any = None, resume: bool = False, progress: bool | None = False,
        desc: str = "imitate") -> FitResult:
    """Fit ``net`` (a start: fresh, or the last DAgger iterate) to ``train_pairs``, early-stopped on ``held_out``.

    Args:
        checkpoint_dir: where to keep the checkpoint (every ``config.checkpoint_every`` epochs; None: none).
        resume: continue from the checkpoint there (its data and configuration must be this fit's).
        progress: the meter (:func:`~myriad.runtime.learn.progress.progress_meter`; False: none).
    """
    check_run("imitation fit", resume=resume, checkpoint_dir=checkpoint_dir, progress=progress)
    # What fixes the iterates: not the budget, the patience or the checkpoint period, which a resume may change.
    kept = {k: v for k, v in describe(config).items() if k not in ("epochs", "patience", "checkpoint_every")}
    description = {"fit": kept,
                   "start": arrays_id("start", jax.tree.leaves(eqx.filter(net, eqx.is_array)))}
    data_id = arrays_id("imitation pairs", [*train_pairs, *held_out])
    learner = _Fit(policy, net, train_pairs, held_out, config, desc, checkpoint_path(checkpoint_dir),
                   (data_id, description))
    start = learner.restore() if resume and learner.path.is_file() else 0
    if learner.stopped:  # the checkpoint is of a finished fit: its result, without a step past the stop
        return FitResult(learner.best_net, Stop(learner.stopped), "resumed a finished fit", learner.history,
                         learner.best)
    stop, message = train(learner, start=start, end=config.epochs,
                          every=config.checkpoint_every if checkpoint_dir is not None else None,
                          progress=progress, exhausted=Stop.MAX_EPOCHS)
    return FitResult(learner.best_net, stop, message, learner.history, learner.best)
