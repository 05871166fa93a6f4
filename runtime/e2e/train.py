"""Algorithm 2 end to end: the expert, the compiled iteration on the learning kit's loop, then the learned model
judged on the true system (contracts: README.md in this folder).

Checkpoints store the planner's warm state with the optimiser state, and the expert's identity as the dataset's. The
stored plans of the training figure are not checkpointed: after a resume it shows the iterations since.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.caches import on_clear
from ..learn import loop
from ..learn.checkpoint import load_checkpoint, save_checkpoint
from ..learn.evaluate import Evaluation, evaluate
from ..learn.identity import arrays_id, tree_id
from ..learn.loop import Step, Stop, check_run, checkpoint_path
from ..learn.models import Parametric, make_model
from ..learn.models.base import as_float
from ..loader import load
from ..solution import Solution, json_number
from ..solve import solve
from ..solvers import Ipopt
from ..sysid.run import failed, run_sysid
from ..system import System
from ..transcriptions import SingleShooting
from ..transcriptions.base import transcribe
from .config import E2EConfig
from .expert import expert_from_dataset
from .step import MIN_STEP_SCALE, TRACES, USED, Program, loss_weights

__all__ = ["E2EReport", "run_e2e", "expert_id"]


@dataclasses.dataclass(frozen=True)
class E2EReport:
    """The outcome of :func:`run_e2e`.

    Attributes:
        learned, true: the parametric model's values by name (and the learned cost weights, ``cost.<name>``).
        history: ``[(iteration, imitation_loss, planner_kkt), ...]`` (the loss of the plan before the update).
        snapshots: ``[(iteration, controls, states), ...]``, plans kept for the training figure.
        counts: iterations per gradient source (``step.USED``).
        status: ``Stop.COMPLETED``, ``NON_FINITE`` or ``STALLED`` (the planner could not solve any nearby model).
        compile_count: traces of the iteration in this call (1 on a fresh configuration, 0 when cached).
    """

    system: str
    config: E2EConfig
    model: Any
    theta: Any
    learned: dict
    true: dict
    history: list
    snapshots: list
    counts: dict
    status: Stop
    message: str
    iterations: int
    train_seconds: float
    compile_count: int
    evaluation: Evaluation
    init_seconds: float = 0.0

    @property
    def converged(self) -> bool:
        return self.status is Stop.COMPLETED and self.evaluation.converged

    def record(self) -> dict[str, Any]:
        ev = self.evaluation.record()
        last = self.history[-1][1] if self.history else math.nan
        return {"system": self.system, "model": self.config.model, "gradient": self.config.adjoint.name,
                "unroll": self.config.adjoint.unroll, "learned": self.learned, "true": self.true,
                "imitation_loss": json_number(last), **{k: ev[k] for k in _RECORDED},
                "train_seconds": round(self.train_seconds, 3),
                "init": "theta0" if self.init_seconds < 0 else (
                    self.config.init if isinstance(self.config.init, str) else "sysid"),
                "init_seconds": round(max(self.init_seconds, 0.0), 3),
                "iterations": self.iterations, "seed": self.config.seed, "counts": self.counts,
                "compile_count": self.compile_count, "status": str(self.status), "converged": bool(self.converged),
                "message": self.message}


# The evaluation's fields in an end-to-end record (the plan's own message and the adaptive re-simulation are not).
_RECORDED = ("achieved_cost", "achieved_defect", "optimal_cost", "optimal_defect", "relative_gap",
             "plan_imitation_loss", "planned_cost", "plan_status", "reaim")


def expert_id(expert: Solution, system: System) -> str:
    """A SHA-256 of the expert trajectory and the spec: what a checkpoint's run imitated."""
    return arrays_id(f"{system.name}\0{system.spec_sha256}\0", (expert.controls, expert.states))


def _learnables(system: System, model: Any, config: E2EConfig, theta0: Any = None) -> tuple[Any, Any, dict, dict]:
    """``(train, frozen, consts, true)``: the learned leaves, the rest of theta, the spec's other parameters and x0,
    and the true values of the learned parameters (parametric and cost) by name."""
    theta = model.init_params(jax.random.key(config.seed), None)
    if theta0 is not None:
        try:
            model.check_params(theta0)
        except ValueError as exc:
            raise ValueError(f"{system.name}: theta0 does not fit the {config.model} model configured here (hidden "
                             f"{config.hidden}, activation {config.activation!r}): {exc}") from None
        theta = as_float(theta0)
    true = {}
    if isinstance(model, Parametric):
        true = {k: float(v) for k, v in model.true_params().items()}
        if not config.learn_dynamics:
            theta = model.true_params()
    mask = model.trainable(theta) if config.learn_dynamics else jax.tree.map(lambda _: False, theta)
    train_m, frozen_m = eqx.partition(theta, mask)
    spec = system.default_params(jnp.float64)
    unknown = [n for n in config.learn_cost if n not in spec]
    if unknown:
        raise ValueError(f"{system.name}: learn_cost names {unknown}, not parameters of the spec ({list(spec)})")
    structural = [n for n in config.learn_cost if n in system.structural_params]
    if structural:
        raise ValueError(f"{system.name}: {structural} set initial values, bounds or the horizon; they cannot be "
                         f"learned as cost weights")
    guess = dict(config.cost_guess)
    cost = {n: jnp.asarray(guess.get(n, 0.5 * float(spec[n])), jnp.float64) for n in config.learn_cost}
    true.update({f"cost.{n}": float(spec[n]) for n in config.learn_cost})
    consts = {"spec": {k: v for k, v in spec.items() if k not in cost}, "x0": jnp.asarray(system.x0, jnp.float64),
              "loss": loss_weights(config.loss)}
    return {"model": train_m, "cost": cost}, {"model": frozen_m}, consts, true


class _Imitation:
    """One run's state and iteration: the learner that :func:`~myriad.runtime.learn.loop.train` drives."""

    unit = "it"

    def __init__(self, program: Program, state: tuple, consts: dict, config: E2EConfig, desc: str):
        self.program, self.consts, self.config, self.desc = program, consts, config, desc
        self.train, self.opt_state, self.carry, self.frozen = state
        self.history, self.counts, self.snapshots = [], dict.fromkeys(USED, 0), []
        self.snap_every = config.snapshot_every or max(1, config.iterations // 40)
        self.checkpoint = None  # (path, expert id, configuration id and description) with a checkpoint folder

    def restore(self) -> int:
        """Continue from the checkpoint; returns its iteration. The frozen part of theta (a Neural ODE's
        normalisation) travels with the optimiser and planner states, so a resume needs no refit."""
        path, eid, config_id, desc = self.checkpoint
        ck = load_checkpoint(path, {"theta": self.train, "opt_state": (self.opt_state, self.carry, self.frozen)},
                             dataset_id=eid, config_id=config_id, config=desc)
        self.train, (self.opt_state, self.carry, self.frozen), self.history = ck.theta, ck.opt_state, ck.history
        self.counts.update({k: int(ck.extra.get(k, 0)) for k in USED})
        return ck.epoch

    def step(self, it: int) -> Step:
        cfg = self.config
        reset = jnp.asarray(it > 0 and cfg.reset_every is not None and it % cfg.reset_every == 0)
        new_train, new_opt, new_carry, m = self.program.iteration(self.train, self.opt_state, self.carry,
                                                                  self.frozen, self.consts, reset)
        m = jax.device_get(m)
        if not bool(m.finite):
            return Step(Stop.NON_FINITE, f"iteration {it}: the imitation loss or its gradient is not finite (loss "
                                         f"{float(m.loss)}); stopped with the parameters before it")
        self.train, self.opt_state, self.carry = new_train, new_opt, new_carry
        self.history.append((it, float(m.loss), float(m.kkt)))
        self.counts[USED[int(m.used)]] += 1
        if it % self.snap_every == 0 or it == cfg.iterations - 1:
            self.snapshots.append((it, np.asarray(m.controls), np.asarray(m.states)))
        postfix = (f"loss {float(m.loss):.3e}, solve {int(m.iterations)} it"
                   + (f", step x{float(m.step_scale):.2g}" if float(m.step_scale) < 1.0 else ""))
        if float(self.carry.scale) < MIN_STEP_SCALE:  # only backtracking (implicit) cuts the step
            return Step(Stop.STALLED, f"iteration {it}: the model's planning problem could not be solved after any "
                                      f"step down to {MIN_STEP_SCALE:g} of the optimiser's (backtracking); stopped "
                                      f"with the last parameters whose plan converged", postfix)
        return Step(postfix=postfix)

    def save(self, done: int) -> None:
        path, eid, config_id, desc = self.checkpoint
        best = min((h[1] for h in self.history), default=math.inf)
        save_checkpoint(path, theta=self.train, opt_state=(self.opt_state, self.carry, self.frozen),
                        key=jax.random.key_data(jax.random.key(self.config.seed)), epoch=done, best_theta=self.train,
                        best_val=best, history=self.history, dataset_id=eid, config_id=config_id, config=desc,
                        extra=self.counts)


def run_e2e(system: System | str | os.PathLike, config: E2EConfig = E2EConfig(), *, transcription: Any = None,
            checkpoint_dir: str | os.PathLike | None = None, resume: bool = False, progress: bool | None = None,
            expert: Solution | str | os.PathLike | None = None, theta0: Any = None) -> E2EReport:
    """Learn a model (and cost weights) by imitating the expert through the planner (Algorithm 2), then judge it.

    Args:
        system: the true system (or its name or spec path).
        transcription: the planning transcription (default ``SingleShooting()``, the published setting).
        checkpoint_dir, resume: a folder for checkpoints, and whether to continue from the one there.
        progress: True: a tqdm bar on stderr; False: nothing; None: a bar on a terminal, else a line every 10 s.
        expert: the expert's solution on the transcription's grid (default: the true optimum, IPOPT), or a
            system-identification dataset file whose first training trajectory is the expert.
        theta0: the model's starting parameters (e.g. a system-identification report's ``theta``); default: as
            ``config.init`` says (a resumed run takes them from its checkpoint and fits nothing).

    Bad arguments raise TypeError or ValueError before any work; a foreign checkpoint ``CheckpointMismatch``.
    """
    if not isinstance(config, E2EConfig):
        raise TypeError(f"run_e2e: config must be an E2EConfig, got {type(config).__name__}")
    check_run("run_e2e", resume=resume, checkpoint_dir=checkpoint_dir, progress=progress)
    system = system if isinstance(system, System) else load(system)
    transcription = SingleShooting() if transcription is None else transcription
    if config.soft_state_bounds is not None and not isinstance(transcription, SingleShooting):
        raise ValueError(f"run_e2e: soft_state_bounds needs a SingleShooting transcription, got "
                         f"{type(transcription).__name__}")
    # A parametric model refuses a spec without learnable parameters, before any work.
    model = make_model(config.model, system, hidden=config.hidden, activation=config.activation)
    path = checkpoint_path(checkpoint_dir)
    resuming = resume and path.is_file()
    learned = _learnables(system, model, config, theta0)  # checks theta0 before any work
    expert = _expert(system, transcription, expert)
    # Elastic final-state bounds (on request) for the plans solved to tolerance: the implicit solve and the judged
    # plan. The fit and the unrolled planner keep the spec's bounds (its K steps never fail; docs/notes/e2e-node.md).
    solved = transcription
    if config.soft_state_bounds is not None:
        rho = config.soft_state_bounds * max(1.0, abs(float(expert.cost)))
        solved = dataclasses.replace(transcription, soft_state_bounds=rho)
    (train, frozen, consts, true), start_id, init_seconds = _start(system, model, config, learned, theta0,
                                                                    transcription, progress, resuming)
    nlp = transcribe(model.as_system(model.combine(train["model"], frozen["model"])),
                     solved if config.adjoint.name == "implicit" else transcription)
    program = _program(model, nlp, config, expert)
    data0 = program.data(train, frozen, consts)
    grid = jax.eval_shape(lambda: nlp.unravel(nlp.initial_guess(data0), data0))[2].shape
    if expert.controls.shape != grid:
        raise ValueError(f"{system.name}: the expert's controls {expert.controls.shape} are not on the "
                         f"transcription's grid {grid}")
    opt_state, carry = program.init_opt(train), program.init_carry(train, frozen, consts)
    config_id, desc = config.identity(system.name)
    if start_id is not None:  # a given start is part of what fixes the iterates
        desc = {**desc, "theta0": start_id}
        config_id = hashlib.sha256(f"{config_id}\0{start_id}".encode()).hexdigest()
    run = _Imitation(program, (train, opt_state, carry, frozen), consts, config,
                     f"{system.name} e2e ({config.model}, {config.adjoint.name})")
    run.checkpoint = None if path is None else (path, expert_id(expert, system), config_id, desc)
    start = run.restore() if resuming else 0
    every = None if path is None else config.checkpoint_every or max(1, config.iterations // 10)
    traces, t0 = TRACES["iteration"], time.perf_counter()
    status, message = loop.train(run, start=start, end=config.iterations, every=every, progress=progress,
                                 exhausted=Stop.COMPLETED)
    seconds = time.perf_counter() - t0
    return _report(system, model, config, run, true, expert, solved, status, message, seconds,
                   TRACES["iteration"] - traces, init_seconds)


def _expert(system: System, transcription: Any, expert: Any) -> Solution:
    """The expert: given, read from a dataset file, or the true optimum (IPOPT); it must have converged."""
    if isinstance(expert, (str, os.PathLike)):
        expert = expert_from_dataset(expert, system, transcription)
    if expert is None:
        expert = solve(system, transcription, Ipopt(), resimulate=False)
    if not expert.converged:
        raise ValueError(f"{system.name}: the expert (true-model optimum) did not converge: {expert.message}")
    return expert


def _start(system: System, model: Any, config: E2EConfig, learned: tuple, theta0: Any, transcription: Any,
           progress: bool | None, resuming: bool) -> tuple[tuple, str | None, float]:
    """``(learnables, the given start's identity or None, init seconds)``: a given ``theta0`` (seconds -1), else a
    fit when ``config.init`` asks for one (not on a resume: the checkpoint holds the start), else ``learned``."""
    if theta0 is not None:
        return learned, tree_id(theta0), -1.0
    if config.sysid_config() is None or resuming:
        return learned, None, 0.0
    t_init = time.perf_counter()
    fitted = run_sysid(system, config.sysid_config(), transcription=transcription, progress=progress)
    init_seconds = time.perf_counter() - t_init
    if not fitted.converged:
        raise ValueError(f"{system.name}: the system-identification fit that starts the run failed: "
                         f"{failed(fitted)}")
    return _learnables(system, model, config, fitted.theta), None, init_seconds


def _report(system: System, model: Any, config: E2EConfig, run: _Imitation, true: dict, expert: Solution,
            solved: Any, status: Stop, message: str, seconds: float, compiles: int,
            init_seconds: float) -> E2EReport:
    """Judge the learned model on the true system (:func:`~myriad.runtime.learn.evaluate.evaluate`: plan on it
    with IPOPT, apply the plan, compare with the expert) and write the report."""
    counts, train, frozen, consts = run.counts, run.train, run.frozen, run.consts
    unsolved = counts["skipped"] + counts["fallback_unrolled"] + counts["backtracked"]
    if unsolved:
        message = (message + "; " if message else "") + (
            f"implicit solve not converged on {unsolved} iterations ({counts['skipped']} skipped, "
            f"{counts['fallback_unrolled']} unrolled instead, {counts['backtracked']} backtracked)")
    theta = model.combine(train["model"], frozen["model"])
    spec_params = {**consts["spec"], **train["cost"]}
    evaluation = evaluate(model, theta, transcription=solved, optimum=expert,
                          params={"spec": spec_params, "model": theta}, reaim=config.reaim)
    learned = {k: float(v) for k, v in theta.items()} if isinstance(model, Parametric) else {}
    learned.update({f"cost.{k}": float(v) for k, v in train["cost"].items()})
    if not evaluation.converged:
        message = (message + "; " if message else "") + evaluation.message
    return E2EReport(system=system.name, config=config, model=model, theta=theta,
                     learned=learned, true=true, history=run.history, snapshots=run.snapshots, counts=counts,
                     status=status, message=message or evaluation.message, iterations=len(run.history),
                     train_seconds=seconds, compile_count=compiles, evaluation=evaluation,
                     init_seconds=init_seconds)


_PROGRAMS: dict = {}
on_clear(_PROGRAMS.clear)


def _program(model, nlp, config, expert) -> Program:
    """One compiled program per (model, NLP, configuration, expert): a second run of the same reuses it."""
    # iterations, checkpoint_every, snapshot_every, where theta started and the loss's mode (its weights are an
    # input) do not enter the compiled iteration.
    same = dataclasses.replace(config, iterations=1, checkpoint_every=None, snapshot_every=None, init="guess",
                               loss="controls")
    key = (model, id(nlp), same, expert_id(expert, model.system))
    if key not in _PROGRAMS:
        _PROGRAMS.clear()  # keep one: each holds compiled code
        _PROGRAMS[key] = Program(model, nlp, config, expert.controls, expert.states)
    return _PROGRAMS[key]
