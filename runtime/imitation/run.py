"""One imitation experiment: demonstrations, a behaviour-cloning fit (and DAgger after it) or the end-to-end learner,
the score in the env.

    report = run_imitation("van_der_pol", ImitateConfig(method="dagger", demos=20, seed=0))
    report.record()["normalized_score"]

The demonstrations are the optimal policy's episodes from ``runtime/datasets`` (:func:`~myriad.runtime.datasets.collect`
with ``policy="optimal"``: the certified plan from each episode's start, the starts perturbed by ``start_noise`` so
that the demonstrations are more than one trajectory repeated), or a dataset that ``myriad dataset`` wrote. The last
``held_out`` fraction of them (at least one; with a single demonstration, every fifth step of it) is held out for
early stopping. Everything is drawn from ``seed``: the same seed, the same record. The end-to-end method
(``method="e2e"``, :mod:`.e2e`) learns the model's parameters from the same demonstrations through the planner
(``runtime/e2e``'s ``run_e2e``, configured by ``e2e``) and scores the learnt model's open-loop plan.
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any, Literal

import jax
import numpy as np

from ..configs import to_json
from ..e2e import E2EConfig, E2EReport, Implicit
from ..learn.loop import Stop
from ..loader import load
from ..rl.env import EnvOptions
from ..rl.reference import reference_env
from ..solvers.interior_point import InteriorPoint
from ..system import System
from .dagger import DaggerConfig, dagger
from .e2e import PlanPolicy, learn_end_to_end, require_learnable
from .expert import Expert
from .fit import FitConfig, Pairs, fit
from .policy import Policy
from .rollout import score

__all__ = ["E2E_DEFAULT", "ImitateConfig", "ImitationReport", "METHODS", "demonstrations", "run_imitation"]

METHODS = ("bc", "dagger", "e2e")
# The end-to-end method's default: implicit gradients at interior-point solves (converged plans: the expert is one),
# 300 iterations, where Cancer Treatment's r and delta come within 1 % (README.md, measurements).
E2E_DEFAULT = E2EConfig(adjoint=Implicit(), implicit_solver=InteriorPoint(), iterations=300)


@dataclasses.dataclass(frozen=True)
class ImitateConfig:
    """An imitation experiment (module docstring).

    Attributes:
        method: ``bc`` (behaviour cloning), ``dagger`` (behaviour cloning, then DAgger with the optimiser as
            expert) or ``e2e`` (the end-to-end learner: the model's parameters through the planner, then its plan).
        demos: the number of optimal demonstrations (episodes).
        seed: every draw's: the demonstrations' starts, the network's initialisation, DAgger's rollouts.
        start_noise: the demonstrations' start perturbation: x0 + start_noise * s * U(-1, 1); None: the method's
            default (:attr:`starts`: 0.1, and 0 for ``e2e``: Algorithm 2 plans from the spec's start). Kept None
            until used, so ``dataclasses.replace(config, method=...)`` gets the new method's default.
        held_out: the fraction of the demonstrations held out for early stopping.
        fit: the fit's settings (learning rate, epochs, patience, network; ``--set fit.epochs=...``).
        dagger: DAgger's schedule (iterations, rollouts, beta, beta_decay; ``--set dagger.iterations=...``).
        mismatch: the score under mismatch: the env's uncertain parameters off by +-this fraction.
        noise: the score under observation noise: noise * s * N(0, 1) added to the observed state.
        score_episodes: seeded episodes of each of the mismatch and noise scores.
        e2e: the end-to-end learner's settings (``runtime/e2e``'s ``E2EConfig``; ``--set e2e.iterations=...``).
    """

    method: Literal["bc", "dagger", "e2e"] = "bc"
    demos: int = 20
    seed: int = 0
    start_noise: float | None = None
    held_out: float = 0.2
    fit: FitConfig = FitConfig()
    dagger: DaggerConfig = DaggerConfig()
    mismatch: float = 0.1
    noise: float = 0.02
    score_episodes: int = 3
    e2e: E2EConfig = E2E_DEFAULT

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if not isinstance(self.e2e, E2EConfig):
            raise ValueError(f"e2e must be an E2EConfig, got {type(self.e2e).__name__}")
        for name in ("demos", "score_episodes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        if isinstance(self.held_out, bool) or not 0.0 < self.held_out < 1.0:
            raise ValueError(f"held_out must be a fraction in (0, 1), got {self.held_out!r}")
        for name in ("start_noise", "mismatch", "noise"):
            value = getattr(self, name)
            if name == "start_noise" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < np.inf:
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

    @property
    def starts(self) -> float:
        """The start perturbation used: ``start_noise``, or the method's default where it is None."""
        if self.start_noise is not None:
            return float(self.start_noise)
        return 0.0 if self.method == "e2e" else 0.1


@dataclasses.dataclass(frozen=True, eq=False)
class ImitationReport:
    """What :func:`run_imitation` returns; :meth:`record` is the command's JSON."""

    system: System
    config: ImitateConfig
    policy: Policy | PlanPolicy  # e2e: the learnt model's open-loop plan as a policy, ``net`` the plan (N, m)
    net: Any
    status: Stop
    message: str
    scores: dict
    fit_history: list  # the behaviour-cloning fit's (epoch, training loss, held-out loss)
    history: list  # DAgger's (iteration, held-out loss, nominal env cost), iteration 0 the behaviour-cloning start
    seconds: dict
    counts: dict
    e2e: E2EReport | None = None  # the end-to-end learner's report (method e2e)

    @property
    def failed(self) -> bool:
        return not self.status.success

    def record(self) -> dict[str, Any]:
        """The JSON record (a non-finite number as null: strict JSON has none)."""
        config = self.config
        return _finite({"system": self.system.name, "spec_sha256": self.system.spec_sha256, "method": config.method,
                        "demos": config.demos, "seed": config.seed, "status": self.status.value,
                        "message": self.message, **self.scores, "seconds": self.seconds, **self.counts,
                        "fit_epochs": len(self.fit_history), "dagger_history": [list(r) for r in self.history],
                        "config": {**to_json(config), "start_noise": config.starts}})  # the value used


def _finite(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return None if isinstance(value, float) and not np.isfinite(value) else value


def demonstrations(system: System, config: ImitateConfig, dataset: str | os.PathLike | None = None, *,
                   final: bool = False):
    """The demonstrations' observations (E, N, d) and controls (E, N, m), in the env's units (module docstring);
    ``final``: the observations with the episodes' last node too, (E, N + 1, d)."""
    obs, actions, _ = _demonstrations(system, config, dataset, final=final)
    return obs, actions


def usable(episodes) -> np.ndarray:
    """(E,) whether each episode demonstrates the optimal policy: its plan converged (where the dataset records
    the plans' status) and its observations, actions and return are finite. A plan that did not converge is no
    demonstration: on Bacteria, starts near 0 (x0 = 1 +- 0.1 * its scale 10) leave the interior point's solve from
    the default guess non-finite, and its controls drive the state below 0, where exp(-x) overflows: inf
    observations, and a non-finite loss for any fit that sees them."""
    ok = np.ones(len(episodes), bool)
    status = episodes.info.get("plan_status")
    if status is not None:
        ok &= np.asarray([s == "converged" for s in status], bool)
    for array in (episodes.observations, episodes.actions):
        ok &= np.isfinite(array).reshape(len(episodes), -1).all(axis=1)
    return ok & np.isfinite(episodes.returns)


def _demonstrations(system: System, config: ImitateConfig, dataset: str | os.PathLike | None, *, final: bool):
    """:func:`demonstrations`, and how many episodes were skipped as not :func:`usable` (drawn again past them:
    the first ``demos`` usable episodes of the seed's sequence, so the same seed gives the same demonstrations)."""
    if dataset is not None:
        from ..datasets.storage import load_dataset

        episodes, _ = load_dataset(dataset, system)
        good = np.flatnonzero(usable(episodes))
        if good.size < config.demos:
            raise ValueError(f"--dataset {dataset}: {good.size} usable episodes (converged, finite) of "
                             f"{len(episodes)}, fewer than --demos {config.demos}")
    else:
        from ..datasets import Perturbation, collect

        n = config.demos
        for _ in range(4):  # episode e's start does not depend on how many are drawn: more episodes extend the sequence
            episodes = collect(system, "optimal", episodes=n, seed=config.seed,
                               options=EnvOptions(normalize_actions=False), perturb=Perturbation(start=config.starts))
            good = np.flatnonzero(usable(episodes))
            if good.size >= config.demos:
                break
            n += 2 * (config.demos - good.size) + 2
        else:
            raise ValueError(f"{system.name}: only {good.size} of {len(episodes)} optimal plans from starts "
                             f"perturbed by start_noise {config.starts} converged, fewer than demos {config.demos}; "
                             "lower --start-noise")
    pick = good[: config.demos]
    skipped = int(pick[-1] + 1 - config.demos)
    obs, actions = episodes.observations[pick, : None if final else -1], episodes.actions[pick]
    if episodes.info["options"].get("normalize_actions", True):  # actions in [-1, 1]: the env's map onto the controls
        lo, hi = reference_env(system).control_bounds
        actions = lo + 0.5 * (np.clip(actions, -1.0, 1.0) + 1.0) * (hi - lo)
    return np.asarray(obs, np.float64), np.asarray(actions, np.float64), skipped


def _split(policy: Policy, obs: np.ndarray, controls: np.ndarray, fraction: float) -> tuple[Pairs, Pairs]:
    """Training and held-out pairs: the last ``fraction`` of the episodes (at least one), or of one episode's
    steps (every fifth)."""
    actions = np.asarray(policy.normalise(controls))
    E = obs.shape[0]
    flat = lambda a: a.reshape(-1, a.shape[-1])  # noqa: E731
    if E == 1:
        held = np.arange(obs.shape[1]) % 5 == 4
        return Pairs.of(obs[0][~held], actions[0][~held]), Pairs.of(obs[0][held], actions[0][held])
    n = min(E - 1, max(1, round(fraction * E)))
    return Pairs.of(flat(obs[:-n]), flat(actions[:-n])), Pairs.of(flat(obs[-n:]), flat(actions[-n:]))


def run_imitation(target: System | str | os.PathLike, config: ImitateConfig = ImitateConfig(), *,
                  dataset: str | os.PathLike | None = None, checkpoint_dir: str | os.PathLike | None = None,
                  resume: bool = False, progress: bool | None = None) -> ImitationReport:
    """Imitate the optimal policy of ``target`` as ``config`` says and score the result (module docstring).

    Checkpoints go to ``checkpoint_dir/bc``, ``checkpoint_dir/dagger`` and ``checkpoint_dir/e2e``; ``resume``
    continues from them. A spec without learnable parameters is refused for ``e2e`` (ValueError) before any work."""
    if not isinstance(config, ImitateConfig):
        raise TypeError(f"run_imitation: config must be an ImitateConfig, got {type(config).__name__}")
    system = target if isinstance(target, System) else load(target)
    if config.method == "e2e":
        require_learnable(system, config.e2e)
    env = reference_env(system)
    sub = (lambda name: None) if checkpoint_dir is None else (lambda name: os.path.join(checkpoint_dir, name))
    seconds = {}
    t = time.perf_counter()
    obs, controls, skipped = _demonstrations(system, config, dataset, final=config.method == "e2e")
    seconds["demonstrations"] = time.perf_counter() - t
    learn = _end_to_end if config.method == "e2e" else _cloned
    t = time.perf_counter()
    out = learn(system, env, config, obs, controls, sub, resume=resume, progress=progress, dataset=dataset)
    seconds.update(out.pop("seconds", {config.method: time.perf_counter() - t}))
    t = time.perf_counter()
    scores = score(env, out["policy"], out["net"], mismatch=config.mismatch, noise=config.noise,
                   episodes=config.score_episodes)
    seconds["score"] = time.perf_counter() - t
    status, message = out.pop("status"), out.pop("message")
    out["counts"] = {**out["counts"], "demonstrations_skipped": skipped}
    if status.success and not np.isfinite(scores["episode_return"]):  # finite losses, yet the policy overflows
        status, message = Stop.NON_FINITE, f"the policy's episode return is {scores['episode_return']}"
    return ImitationReport(system, config, status=status, message=message, scores=scores, seconds=seconds, **out)


def _cloned(system: System, env, config: ImitateConfig, obs, controls, sub, *, resume, progress, dataset) -> dict:
    """Behaviour cloning, and DAgger after it (``method="dagger"``): the report's fields."""
    policy = Policy.of(env, config.fit.width, config.fit.depth)
    train_pairs, held_out = _split(policy, obs, controls, config.held_out)
    seconds, counts = {}, {}
    t = time.perf_counter()
    bc = fit(policy, policy.init(jax.random.PRNGKey(config.seed)), train_pairs, held_out, config.fit,
             checkpoint_dir=sub("bc"), resume=resume, progress=progress, desc=f"bc {system.name}")
    seconds["bc"] = time.perf_counter() - t
    net, status, message, history = bc.net, bc.stop, bc.message, []
    if config.method == "dagger" and bc.stop.success:
        t = time.perf_counter()
        run = dagger(env, policy, bc.net, train_pairs, held_out, Expert(env), config.dagger, config.fit,
                     seed=config.seed, checkpoint_dir=sub("dagger"), resume=resume, progress=progress)
        seconds["dagger"] = time.perf_counter() - t
        net, status, message = run.net, run.stop, run.message
        history = run.history
        counts = {"expert_labels": run.labels, "expert_failures": run.failures}
    return {"policy": policy, "net": net, "status": status, "message": message, "fit_history": bc.history,
            "history": history, "seconds": seconds, "counts": counts}


def _end_to_end(system: System, env, config: ImitateConfig, obs, controls, sub, *, resume, progress,
                dataset) -> dict:
    """The end-to-end learner on the demonstrations (:mod:`.e2e`): the report's fields; the record's ``e2e`` holds
    the learnt parameters beside the true ones, the iterations, the final imitation loss and the plan's status."""
    source = "the demonstrations" if dataset is None else f"--dataset {dataset}"
    learnt = learn_end_to_end(system, env, obs, controls, config.e2e, checkpoint_dir=sub("e2e"), resume=resume,
                              progress=progress, source=source)
    rec = learnt.report.record()
    keys = ("learned", "true", "iterations", "imitation_loss", "relative_gap", "status", "counts")
    summary = {**{k: rec[k] for k in keys}, "plan_status": learnt.plan_status}
    message = learnt.report.message
    if learnt.plan_status != "converged":  # scored all the same: the record says what was played
        message = f"{message}; the learnt model's plan on the env's grid: {learnt.plan_status}"
    return {"policy": learnt.policy, "net": learnt.plan, "status": learnt.report.status, "message": message,
            "fit_history": [], "history": [], "counts": {"e2e": summary}, "e2e": learnt.report}
