"""The end-to-end learner (Algorithm 2, ``runtime/e2e``) as the third imitation method, on the same demonstrations.

    learnt = learn_end_to_end(system, env, observations, controls, config.e2e, checkpoint_dir=..., resume=...)
    score(env, learnt.policy, learnt.plan)            # the learnt model's plan, scored like a BC or DAgger policy

Algorithm 2 imitates one expert plan from the spec's start through the planner, so the demonstrations must start
there (a perturbed start is refused: the planner cannot start anywhere else); their controls are averaged into the
expert (identical for the optimal policy; a noisy dataset's action noise averages out). The env holds each action
over a step; the planner's single shooting interpolates its node controls linearly, so the expert's node k is the
mean of the actions either side of it (u_{k-1} + u_k) / 2 (u_0 and u_{N-1} at the ends): the held action is the
interpolant's value at the step's midpoint to second order, where using u_k at node k would bias theta by O(h).

The learnt model then plans once, open loop, and the env plays that plan: Algorithm 2 learns a model whose *plan* is
the expert's, and this is how ``runtime/e2e`` judges it. A parametric model plans on the env's own problem (MPC's
planning NLP from step 0, ``runtime/datasets``' ``optimal_controls``: the env's grid, hold, integrator and terminal
penalty, so the true parameters give the reference optimum itself) with the learnt parameters and cost weights;
a Neural ODE, which that problem cannot hold, plays the plan ``runtime/e2e`` judged (``evaluate``'s plan on the
learnt model), each step the mean of its interval's two node controls (the linear interpolant's mean over the step).
Under observation noise an open-loop plan sees nothing, so its noise score is its nominal one; under mismatch it
plays the same plan in the mismatched env. (MPC on the learnt model would re-plan at every step: N solves an
episode, times the scored episodes.)
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..datasets.policies import optimal_controls
from ..e2e import E2EConfig, E2EReport, run_e2e
from ..learn.evaluate import apply_plan
from ..learn.models import Parametric
from ..rl.env import Env
from ..solution import Solution
from ..status import Status
from ..system import System
from ..transcriptions import SingleShooting
from ..transcriptions.nominal_scales import state_scale

__all__ = ["EndToEnd", "PlanPolicy", "check_starts", "expert_of", "learn_end_to_end", "learnt_plan",
           "require_learnable"]

START_TOLERANCE = 1e-9  # of each state's nominal scale: the demonstrations' starts must be the spec's x0


def require_learnable(system: System, config: E2EConfig) -> None:
    """ValueError naming the fix when a parametric model has nothing to learn in ``system`` (before any work)."""
    if config.model == "parametric" and config.learn_dynamics and not system.learnable:
        raise ValueError(f"{system.name} declares no learnable parameters, so --method e2e has no model to learn; "
                         f"mark parameters `learnable: true` (with a `guess`) in its spec, or learn a Neural ODE "
                         f"with --set e2e.model=node")


def check_starts(system: System, observations: np.ndarray, source: str = "the demonstrations") -> None:
    """ValueError naming the fix unless every episode of ``observations`` (E, N(+1), n + 1) starts at the spec's x0."""
    starts = np.asarray(observations)[:, 0, : system.n_states]
    off = float(np.max(np.abs(starts - np.asarray(system.x0)) / state_scale(system)))
    if off > START_TOLERANCE:
        raise ValueError(f"--method e2e: {source} start up to {off:.3g} of a state's scale away from the spec's x0; "
                         f"Algorithm 2 plans from the spec's start, so use demonstrations from it (--start-noise 0, "
                         f"or a dataset written without a start perturbation)")


@dataclasses.dataclass(frozen=True, eq=False)
class PlanPolicy:
    """An open-loop plan (N, m) as a policy of :mod:`.rollout`: the control of the step the observation's time to
    go names (the time to go is observed exactly: observation noise is on the state only)."""

    steps: int
    horizon: float

    def control(self, net: Any, obs: Any) -> Any:
        obs = jnp.asarray(obs)
        k = self.steps - jnp.round(obs[..., -1] * self.steps / self.horizon).astype(jnp.int32)
        return jnp.asarray(net)[jnp.clip(k, 0, self.steps - 1)]


@dataclasses.dataclass(frozen=True, eq=False)
class EndToEnd:
    """What :func:`learn_end_to_end` returns: the kit's report, the env's open-loop plan and its policy."""

    report: E2EReport
    plan: np.ndarray  # (N, m): the learnt model's plan held over each env step
    policy: PlanPolicy
    plan_status: str  # its solve's status word ("converged" where it did)


def expert_of(system: System, observations: np.ndarray, controls: np.ndarray, transcription: SingleShooting,
              source: str = "the demonstrations") -> Solution:
    """The expert Algorithm 2 imitates, on ``transcription``'s nodes, from demonstrations ``observations``
    (E, N + 1, n + 1) and held ``controls`` (E, N, m) in the control's units (module docstring)."""
    n, N = system.n_states, controls.shape[1]
    check_starts(system, observations, source)
    u = controls.mean(axis=0)
    nodes = np.concatenate([u[:1], 0.5 * (u[1:] + u[:-1]), u[-1:]])
    states = observations.mean(axis=0)[:, :n]
    cost, defect = apply_plan(system, nodes, transcription)
    T = float(system.horizon)
    return Solution(system=system.name, transcription=type(transcription).__name__, solver="demonstrations",
                    integrator=transcription.integrator.label, times=np.linspace(0.0, T, N + 1), states=states,
                    controls=nodes, cost=cost, defect=defect, converged=True, status=Status.CONVERGED,
                    message=f"the mean of {len(controls)} demonstrations from the spec's start", iterations=0,
                    constraint_violation=0.0, intervals=N, final_time=T)


def learn_end_to_end(system: System, env: Env, observations: np.ndarray, controls: np.ndarray, config: E2EConfig, *,
                     checkpoint_dir: str | os.PathLike | None = None, resume: bool = False,
                     progress: bool | None = None, source: str = "the demonstrations") -> EndToEnd:
    """Learn the model by :func:`~myriad.runtime.e2e.run_e2e` against the demonstrations' expert on the env's grid
    (single shooting of N intervals with the env's integrator), then the learnt model's open-loop plan."""
    require_learnable(system, config)
    if controls.shape[1] != env.options.steps:
        raise ValueError(f"--method e2e: {source} have {controls.shape[1]} steps an episode, the scoring env "
                         f"{env.options.steps}; use demonstrations on the env's own grid")
    transcription = SingleShooting(intervals=controls.shape[1], integrator=env.options.integrator)
    expert = expert_of(system, observations, controls, transcription, source)
    report = run_e2e(system, config, transcription=transcription, expert=expert, checkpoint_dir=checkpoint_dir,
                     resume=resume, progress=progress)
    plan, status = learnt_plan(env, report)
    return EndToEnd(report, plan, PlanPolicy(plan.shape[0], float(system.horizon)), status)


def learnt_plan(env: Env, report: E2EReport) -> tuple[np.ndarray, str]:
    """The learnt model's open-loop plan on the env's grid, (N, m) in the control's units, and its solve's status
    word (module docstring)."""
    if isinstance(report.model, Parametric):
        params = {k.removeprefix("cost."): float(v) for k, v in report.learned.items()}
        data = jax.tree.map(lambda a: jnp.asarray(a)[None], env.default_params(params))
        controls, record = optimal_controls(env, data)  # one episode: the batch of one
        return np.asarray(controls[0], np.float64), record["plan_status"][0]
    nodes = np.asarray(report.evaluation.plan.controls, np.float64)
    return 0.5 * (nodes[:-1] + nodes[1:]), report.evaluation.plan.status.name.lower()
