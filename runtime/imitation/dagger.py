"""DAgger (Ross, Gordon and Bagnell 2011): roll out the current policy, have the expert label the states it visits,
aggregate, retrain.

    result = dagger(env, policy, net_bc, demos, held_out, expert, DaggerConfig(), key=key, checkpoint_dir="ck")

Iteration i (1-based) plays ``rollouts`` episodes from starts perturbed as the demonstrations' were (the env's
``start_noise``), all in lockstep: at every step k the expert (:class:`~.expert.Expert`) re-solves the problem left
from each episode's state at k, batched over the episodes and warm-started from that episode's previous plan; its
control at k is the label of the observation there. The control played is the expert's with probability
``beta_i`` and the policy's otherwise, drawn per episode and step, with the schedule
``beta_i = beta * beta_decay ** (i - 1)``. The default ``beta = 0`` is Ross et al.'s ``beta_i = I(i = 1)``, which
they found to work best in practice: their first iteration, the expert's own rollouts, is here the demonstrations
the behaviour-cloning start was fitted to, and every later rollout is the learner's alone. A label whose solve did
not converge gets weight 0 (it is never trained on).

The aggregate (the training demonstrations, then every iteration's labelled states) is kept in arrays of the final
size, unfilled rows weighted 0, so the fit compiles once. Each iteration refits from the current network with a
fresh optimiser (:func:`~.fit.fit`, early-stopped on the held-out demonstrations). Ross et al. return the best
iterate on validation; here that is the iterate (the behaviour-cloning start included) with the lowest cost in the
nominal env, the one deterministic episode the expert's optimum is measured on. One step of the learning kit's loop
is one iteration; a checkpoint holds the network, the aggregate and the best iterate, so a resumed run repeats no
labelled iteration before the last checkpoint.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

# A FieldError names the field, so `--set fit.x=...` / `--set dagger.x=...` is named by its dotted key.
from ..configs import FieldError
from ..learn.checkpoint import load_checkpoint, save_checkpoint
from ..learn.identity import arrays_id, describe, digest
from ..learn.loop import Step, Stop, check_run, checkpoint_path, train
from ..rl.env import Env
from .expert import Expert
from .fit import FitConfig, Pairs, fit, loss
from .policy import Policy
from .rollout import episode_return

__all__ = ["DaggerConfig", "DaggerResult", "dagger"]


@dataclasses.dataclass(frozen=True)
class DaggerConfig:
    """DAgger's schedule (module docstring).

    Attributes:
        iterations: labelled iterations after the behaviour-cloning start.
        rollouts: episodes the policy plays (and the expert labels) per iteration.
        beta, beta_decay: the probability of playing the expert's control at iteration i is
            beta * beta_decay ** (i - 1) (beta = 0: the learner alone, Ross et al.'s practical choice).
        start_noise: the rollouts' start perturbation (the env's start_noise: x0 + start_noise * s * U(-1, 1)).
        checkpoint_every: iterations between checkpoints (with a checkpoint folder).
    """

    iterations: int = 4
    rollouts: int = 4
    beta: float = 0.0
    beta_decay: float = 0.5
    start_noise: float = 0.1
    checkpoint_every: int = 1

    def __post_init__(self):
        for name in ("iterations", "rollouts", "checkpoint_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise FieldError(f"{name} must be a positive integer, got {value!r}", name)
        for name in ("beta", "beta_decay"):
            value = getattr(self, name)
            if isinstance(value, bool) or not 0.0 <= value <= 1.0:
                raise FieldError(f"{name} must be in [0, 1], got {value!r}", name)
        if isinstance(self.start_noise, bool) or not 0.0 <= self.start_noise < np.inf:
            raise FieldError(f"start_noise must be a finite number >= 0, got {self.start_noise!r}", "start_noise")


class DaggerResult(NamedTuple):
    net: Any  # the best iterate (nominal env cost)
    stop: Stop
    message: str
    history: list  # (iteration, held-out loss, nominal env cost); iteration 0 is the behaviour-cloning start
    best_cost: float
    labels: int  # expert solves
    failures: int  # of which did not converge


@eqx.filter_jit
def _controls(policy: Policy, net: Any, obs: Any) -> Any:
    return policy.control(net, obs)


class _Dagger:
    """The learner object of :func:`~myriad.runtime.learn.loop.train`: one step is one DAgger iteration."""

    unit = "iteration"

    def __init__(self, env, policy, net, demos, held_out, expert, config, fit_config, seed, path, identity):
        self.env, self.policy, self.expert, self.config, self.fit_config = env, policy, expert, config, fit_config
        self.held_out, self.seed, self.key = held_out, seed, jax.random.PRNGKey(seed)
        self.path, self.identity = path, identity
        self.desc = f"dagger {env.system.name}"
        n_steps = env.options.steps
        size = demos.obs.shape[0] + config.iterations * config.rollouts * n_steps
        pad = lambda a: np.concatenate([a, np.zeros((size - a.shape[0], *a.shape[1:]))])  # noqa: E731
        self.buffer = Pairs(pad(demos.obs), pad(demos.actions), pad(demos.weights))
        self.count = demos.obs.shape[0]
        self.net = self.best_net = net
        self.best = self._cost(net)
        self.history = [(0, float(loss(policy, net, held_out)), self.best)]
        self.rollout_env = Env(env.system, dataclasses.replace(env.options, start_noise=config.start_noise))
        self._step = jax.jit(jax.vmap(self.rollout_env.step_env, in_axes=(0, 0, None)))
        self._reset = jax.jit(jax.vmap(self.rollout_env.reset, in_axes=(0, None)))
        self.plan0 = expert.optimal_plan(env.default_params().x0)

    def _cost(self, net) -> float:
        return -episode_return(self.env, self.policy, net)

    def _label(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Iteration ``index + 1``'s rollouts (module docstring): observations, labels (normalised), weights."""
        E, N = self.config.rollouts, self.env.options.steps
        beta = self.config.beta * self.config.beta_decay ** index
        key = jax.random.fold_in(self.key, index)
        data = self.env.default_params()
        obs, state = self._reset(jax.vmap(lambda e: jax.random.fold_in(key, e))(jnp.arange(E)), data)
        expert_plays = np.random.default_rng([self.seed, index]).random((N, E)) < beta
        prev = np.broadcast_to(self.plan0, (E, *self.plan0.shape)).copy()
        seen, labels, weights = [], [], []
        for k in range(N):
            plans, ok = self.expert.label(np.asarray(state.x), k, prev)
            prev = np.where(ok[:, None, None], plans, prev)
            label = plans[:, k]
            u = np.where((expert_plays[k] & ok)[:, None], label, np.asarray(_controls(self.policy, self.net, obs)))
            seen.append(np.asarray(obs))
            labels.append(np.asarray(self.policy.normalise(label)))
            weights.append(ok.astype(np.float64))
            obs, state, _, _, _, _ = self._step(state, jnp.asarray(u), data)
        return (np.stack(seen, 1).reshape(E * N, -1), np.stack(labels, 1).reshape(E * N, -1),
                np.stack(weights, 1).reshape(-1))

    def step(self, index: int) -> Step:
        obs, labels, weights = self._label(index)
        # A rollout can leave the region where the dynamics are finite (Bacteria from a start near 0: exp(-x) of a
        # negative state); its expert labels fail (weight 0), but 0 * a network's NaN output is NaN: such rows are
        # zeroed as well as weighted 0, or one of them makes the whole refit's loss non-finite.
        bad = ~(np.isfinite(obs).all(axis=1) & np.isfinite(labels).all(axis=1))
        obs[bad], labels[bad], weights[bad] = 0.0, 0.0, 0.0
        rows = slice(self.count, self.count + obs.shape[0])
        for array, new in zip(self.buffer, (obs, labels, weights)):
            array[rows] = new
        self.count = rows.stop
        result = fit(self.policy, self.net, self.buffer, self.held_out, self.fit_config)
        if not result.stop.success:
            return Step(result.stop, f"iteration {index + 1}: the refit stopped: {result.message}")
        self.net = result.net
        cost = self._cost(result.net)
        self.history.append((index + 1, result.best, cost))
        if cost < self.best:
            self.best_net, self.best = result.net, cost
        return Step(postfix=f"held-out {result.best:.2e}, cost {cost:.6g} (best {self.best:.6g})")

    def save(self, done: int) -> None:
        data_id, description = self.identity
        aggregate = {"obs": self.buffer.obs, "actions": self.buffer.actions, "weights": self.buffer.weights}
        # DAgger's state between iterations is its aggregate (each refit starts a fresh optimiser): it takes the
        # optimiser state's place in the checkpoint.
        save_checkpoint(self.path, theta=self.net, opt_state=aggregate, key=self.key, epoch=done,
                        best_theta=self.best_net, best_val=self.best, history=self.history, dataset_id=data_id,
                        config_id=digest(description), config=description,
                        extra={"count": self.count, "solves": self.expert.solves, "failures": self.expert.failures})

    def restore(self) -> int:
        data_id, description = self.identity
        aggregate = {"obs": self.buffer.obs, "actions": self.buffer.actions, "weights": self.buffer.weights}
        ck = load_checkpoint(self.path, {"theta": self.net, "opt_state": aggregate}, dataset_id=data_id,
                             config_id=digest(description), config=description)
        self.net, self.best_net, self.best, self.history = ck.theta, ck.best_theta, ck.best_val, ck.history
        self.buffer = Pairs(*(np.array(ck.opt_state[k]) for k in ("obs", "actions", "weights")))
        self.count = int(ck.extra["count"])
        self.expert.solves, self.expert.failures = int(ck.extra["solves"]), int(ck.extra["failures"])
        return ck.epoch


def dagger(env: Env, policy: Policy, net: Any, demos: Pairs, held_out: Pairs, expert: Expert,
           config: DaggerConfig, fit_config: FitConfig, *, seed: int, checkpoint_dir: Any = None,
           resume: bool = False, progress: bool | None = False) -> DaggerResult:
    """Run DAgger from ``net`` (the behaviour-cloning fit to ``demos``), the expert labelling in ``env``
    (module docstring), the rollouts' draws from ``seed``; checkpoints every ``config.checkpoint_every`` iterations
    in ``checkpoint_dir``. The aggregate's size depends on ``iterations``, so a resume keeps it."""
    check_run("dagger", resume=resume, checkpoint_dir=checkpoint_dir, progress=progress)
    description = {"dagger": {k: v for k, v in describe(config).items() if k != "checkpoint_every"},
                   "fit": describe(fit_config), "seed": int(seed),
                   "start": arrays_id("start", jax.tree.leaves(eqx.filter(net, eqx.is_array)))}
    data_id = arrays_id("dagger demonstrations", [*demos, *held_out])
    learner = _Dagger(env, policy, net, demos, held_out, expert, config, fit_config, int(seed),
                      checkpoint_path(checkpoint_dir), (data_id, description))
    start = learner.restore() if resume and learner.path.is_file() else 0
    stop, message = train(learner, start=start, end=config.iterations,
                          every=config.checkpoint_every if checkpoint_dir is not None else None,
                          progress=progress, exhausted=Stop.COMPLETED)
    return DaggerResult(learner.best_net, stop, message, learner.history, learner.best, expert.solves,
                        expert.failures)
