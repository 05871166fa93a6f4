"""Fit a model's parameters to trajectories: the loss of :mod:`.losses`, minimised by an optax optimiser in the
learning kit's loop (the README's "Fitting": the stops, checkpoints and what a resume may change).

An epoch is one compiled ``lax.scan`` over minibatches of a fixed shape (a permutation from ``FitConfig.seed``, padded
with repeats of weight 0), reused by every epoch of a curriculum stage; only the trainable part of theta gets
gradients. The validation loss (full horizon, single shooting, gamma = 1, whatever the training layout, so it
compares across stages) selects the parameters returned. A resumed fit is bit for bit the uninterrupted one on CPU
(a shorter run's closing validation, off schedule, comes after its last checkpoint, so a resume never replays it).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..learn.checkpoint import load_checkpoint, save_checkpoint
from ..learn.dataset import _count, check_source, dataset_id
from ..learn.identity import describe, digest, optimizer_identity
from ..learn.loop import Step, Stop, check_run, checkpoint_path, train
from ..learn.models import AbstractModel
from .losses import SCALES, TRACES, fit_integrator, state_scale, train_epoch, validation_loss

__all__ = ["FitConfig", "FitResult", "fit", "METHODS"]

METHODS = ("single_shooting", "multiple_shooting")


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """How to fit (frozen; every field is checked on construction).

    Attributes:
        optimizer: a learning rate for ``optax.adam`` (default 1e-3, the published setting), or an
            ``optax.GradientTransformation`` (pass the same object again to reuse the compiled epoch).
        epochs, validate_every: the most epochs (passes over the training set), and the epochs between validations.
        batch_size: trajectories per minibatch (clipped to the training set's); None: all (the published setting).
        patience: validations without improvement before stopping early; None never stops early.
        method, window: ``"single_shooting"`` (the published loss) or ``"multiple_shooting"`` in windows of W
            (1..N) steps without a curriculum (see :mod:`.losses`).
        curriculum: a horizon curriculum: ``((W1, E1), ..., (WK, EK))`` trains E_i epochs with window W_i (the last
            E may be None: up to ``epochs``), or plain ``(W1, ..., WK)`` for equal shares of ``epochs``. Windows tile
            the trajectory under multiple shooting; under single shooting a stage fits the first W_i steps only.
        gamma: per-step weight gamma^l within each window, in (0, 1] (the published crude curriculum; 1: none).
        scale: the loss's state scale, ``"none"`` (the published loss), ``"range"`` or ``"data"`` (:mod:`.losses`).
        checkpoint_every: epochs between checkpoints (with ``checkpoint_dir``); None: every validation.
        seed: seeds the initial parameters and the minibatch order.
        tol: stop as converged when the validation loss is <= tol (0: only an exact fit).
    """

    optimizer: Any = 1e-3
    epochs: int = 1000
    batch_size: int | None = None
    validate_every: int = 10
    patience: int | None = 30
    method: str = "single_shooting"
    window: int | None = None
    curriculum: Any = None
    gamma: float = 1.0
    scale: str = "none"
    checkpoint_every: int | None = None
    seed: int = 0
    tol: float = 0.0

    def __post_init__(self):
        opt = self.optimizer
        if isinstance(opt, (int, float, np.floating)) and not isinstance(opt, bool):
            if not (math.isfinite(opt) and opt > 0):
                raise ValueError(f"FitConfig: a learning rate must be finite and > 0, got {opt!r}")
            object.__setattr__(self, "optimizer", float(opt))
        elif not (callable(getattr(opt, "init", None)) and callable(getattr(opt, "update", None))):
            raise ValueError(f"FitConfig: optimizer must be an optax.GradientTransformation or a learning rate for "
                             f"Adam, got {opt!r}")
        for name, low, optional in (("epochs", 1, False), ("batch_size", 1, True), ("validate_every", 1, False),
                                    ("patience", 1, True), ("checkpoint_every", 1, True), ("seed", 0, False),
                                    ("window", 1, True)):
            v = getattr(self, name)
            if not ((optional and v is None) or _count(v) >= low):
                raise ValueError(f"FitConfig: {name} must be an integer >= {low}{' or None' if optional else ''}, "
                                 f"got {v!r}")
        if self.method not in METHODS:
            raise ValueError(f"FitConfig: unknown method {self.method!r}; expected one of {METHODS}")
        if self.window is not None and (self.method != "multiple_shooting" or self.curriculum is not None):
            raise ValueError("FitConfig: window is for method='multiple_shooting' without a curriculum (a "
                             "curriculum gives each stage's window)")
        if self.method == "multiple_shooting" and self.window is None and self.curriculum is None:
            raise ValueError("FitConfig: method='multiple_shooting' needs a window (steps per window) or a curriculum")
        if self.curriculum is not None:
            object.__setattr__(self, "curriculum", _curriculum(self.curriculum))
        if isinstance(self.gamma, bool) or not isinstance(self.gamma, (int, float)) or not 0 < self.gamma <= 1:
            raise ValueError(f"FitConfig: gamma must be in (0, 1], got {self.gamma!r}")
        object.__setattr__(self, "gamma", float(self.gamma))
        if self.scale not in SCALES:
            raise ValueError(f"FitConfig: unknown scale {self.scale!r}; expected one of {SCALES}")
        if isinstance(self.tol, bool) or not isinstance(self.tol, (int, float)) or not self.tol >= 0:
            raise ValueError(f"FitConfig: tol must be a number >= 0, got {self.tol!r}")

    def stages(self, n_steps: int) -> list[tuple[int, bool, int]]:
        """``[(window, tile, last_epoch), ...]`` on a grid of ``n_steps`` intervals (raises if a window exceeds it)."""
        tile = self.method == "multiple_shooting"
        if self.curriculum is None:
            spec = [(n_steps if self.window is None else self.window, None)]
        elif all(_count(c) >= 0 for c in self.curriculum):
            k = len(self.curriculum)
            spec = [(w, self.epochs // k) for w in self.curriculum[:-1]] + [(self.curriculum[-1], None)]
        else:
            spec = list(self.curriculum)
        out, end = [], 0
        for w, e in spec:
            if not 1 <= w <= n_steps:
                raise ValueError(f"window {w} does not fit the dataset's grid of N = {n_steps} steps (1 <= W <= N)")
            end = self.epochs if e is None else min(end + e, self.epochs)
            out.append((w, tile or w == n_steps, end))  # a prefix of all N steps is single shooting: share its code
        return out


def _curriculum(c: Any) -> tuple:
    try:
        c = tuple(tuple(s) if isinstance(s, (list, tuple)) else s for s in c)
    except TypeError:
        c = ()
    last = len(c) - 1
    if c and all(_count(s) >= 1 for s in c):
        return tuple(int(s) for s in c)
    if c and all(isinstance(s, tuple) and len(s) == 2 and _count(s[0]) >= 1
                 and (_count(s[1]) >= 1 or (i == last and s[1] is None)) for i, s in enumerate(c)):
        return tuple((int(w), None if e is None else int(e)) for w, e in c)
    raise ValueError(f"FitConfig: curriculum must be (W1, ..., WK) or ((W1, E1), ..., (WK, EK or None)) with "
                     f"windows and epochs >= 1, got {c!r}")


@dataclasses.dataclass(frozen=True)
class FitResult:
    """The outcome of :func:`fit`.

    Attributes:
        theta: the best parameters on validation (those of epoch 0, the start, if nothing improved on them).
        history: ``[(epoch, train_loss, val_loss), ...]`` at each validation; train_loss is the epoch's mean
            training objective at the minibatches' pre-update parameters.
        best_validation_loss, best_epoch: the best validation loss and its epoch (0: the start).
        epochs: the epochs completed (a resumed fit counts the earlier ones); ``seconds``: this call's wall time.
        stopped: a :class:`~myriad.runtime.learn.loop.Stop`; ``message`` says more.
        compile_count: traces of the compiled functions in this call (at most one per curriculum stage plus one; 0
            when an earlier fit of the same configuration and shapes compiled them).
        integrator: the label of the integrator the model was rolled out with.
    """

    theta: Any
    history: list
    best_validation_loss: float
    epochs: int
    seconds: float
    stopped: Stop
    best_epoch: int = 0
    compile_count: int = 0
    integrator: str = ""
    message: str = ""

    @property
    def success(self) -> bool:
        return self.stopped.success


def _check(model, dataset, config, theta0, checkpoint_dir, resume, progress) -> tuple[int, list]:
    """Every argument error, before any work; returns N and the curriculum stages."""
    if not isinstance(model, AbstractModel):
        raise TypeError(f"fit: model must be a sysid model (Parametric, NeuralODE, ...), got {type(model).__name__}")
    if not isinstance(config, FitConfig):
        raise TypeError(f"fit: config must be a FitConfig, got {type(config).__name__}")
    if not all(hasattr(dataset, k) for k in ("times", "train", "validation", "system", "spec_sha256", "sampling")):
        raise TypeError(f"fit: dataset must be a sysid Dataset (make_dataset), got {type(dataset).__name__}")
    check_source(dataset, model.system, "fit")
    times = np.asarray(dataset.times, dtype=np.float64)
    n_steps = times.shape[0] - 1
    if n_steps < 1 or not np.allclose(np.diff(times), (times[-1] - times[0]) / n_steps, rtol=1e-9, atol=0):
        raise ValueError("fit: the dataset's times must be a uniform grid of at least 2 nodes")
    stages = config.stages(n_steps)
    if theta0 is not None:
        model.check_params(theta0)
    check_run("fit", resume=resume, checkpoint_dir=checkpoint_dir, progress=progress)
    return n_steps, stages


def config_identity(model: Any, config: FitConfig, integrator: Any, stages: list, theta: Any) -> tuple[str, dict]:
    """``(sha256, description)`` of what fixes a fit's sequence of iterates (all but what a resumed fit may change:
    ``epochs``, ``patience``, ``tol``, ``checkpoint_every`` and the last stage's end). A custom optax transformation
    is known only by its ``init`` function's qualified name (and its state's leaves, checked on load)."""
    desc = {
        "model": type(model).__name__, "system": model.system.name,
        "model_fields": {f.name: describe(getattr(model, f.name)) for f in dataclasses.fields(model)
                         if f.name != "system"},
        "optimizer": optimizer_identity(config.optimizer),
        "batch_size": config.batch_size, "validate_every": config.validate_every, "method": config.method,
        "stages": [list(s) for s in stages[:-1]] + [list(stages[-1][:2])], "gamma": config.gamma,
        "scale": config.scale, "seed": config.seed, "integrator": repr(integrator),
        "theta": [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(theta)[0]],
    }
    return digest(desc), desc


# One object per learning rate: the optimiser is a static argument of the compiled epoch, so equal configs reuse it.
_adam = functools.lru_cache(maxsize=32)(optax.adam)


class _FitRun:
    """One fit's data, state and epoch: the learner that :func:`~myriad.runtime.learn.loop.train` drives."""

    unit = "epoch"

    def __init__(self, model: AbstractModel, dataset: Any, config: FitConfig, theta0: Any, n_steps: int,
                 stages: list):
        self.model, self.config, self.n_steps, self.stages = model, config, n_steps, stages
        self.end = stages[-1][2]
        self.stage_of = np.searchsorted([s[2] for s in stages], np.arange(self.end + 1))  # epoch e's stage
        self.last = int(self.stage_of[self.end])  # the stage that runs to the end (a later one may have no epochs)
        self.integrator = fit_integrator(dataset.sampling)
        self.desc = f"fit {model.system.name}"
        times = np.asarray(dataset.times, dtype=np.float64)
        self.common = (model.system.default_params(jnp.float64),  # spec, 1 / scale, t0, h: the loss's data
                       jnp.asarray(1.0 / state_scale(model.system, dataset.train.states, config.scale)),
                       jnp.asarray(times[0]), jnp.asarray((times[-1] - times[0]) / n_steps))
        val = dataset.validation if dataset.validation.states.shape[0] > 0 else dataset.train
        self.x_tr, self.u_tr, self.x_va, self.u_va = (jnp.asarray(a, dtype=jnp.float64) for a in (
            dataset.train.states, dataset.train.controls, val.states, val.controls))
        self.opt = _adam(config.optimizer) if isinstance(config.optimizer, float) else config.optimizer
        self.bs = self.x_tr.shape[0] if config.batch_size is None else min(config.batch_size, self.x_tr.shape[0])
        self.key, init_key = jax.random.split(jax.random.PRNGKey(config.seed))
        theta = model.init_params(init_key, dataset.train) if theta0 is None else theta0
        # Strongly typed float64 leaves: a weakly typed start would be retraced once the optimiser retypes it.
        self.train, self.frozen = model.partition(jax.tree.map(lambda a: jnp.asarray(np.asarray(a, np.float64)),
                                                               theta))
        with jax.numpy_dtype_promotion("standard"):  # optax's own arithmetic (see losses.train_epoch)
            self.opt_state = self.opt.init(self.train)
        self.epoch, self.history, self.stalls, self.loss = 0, [], 0, math.nan
        self.best_train, self.best_val, self.best_epoch, self.validated = self.train, math.inf, 0, 0
        self.ckpt, self.ids = None, None

    def validate(self, train: Any) -> float:
        return float(validation_loss(train, self.frozen, *self.common, self.x_va, self.u_va, model=self.model,
                                     integrator=self.integrator, n_steps=self.n_steps))

    def start(self, dataset: Any, checkpoint_dir: Any, resume: bool) -> tuple[Stop | None, str]:
        """Restore the checkpoint (``resume``) or validate the start; a stop already reached, if any."""
        config_id, ident = config_identity(self.model, self.config, self.integrator, self.stages, self.train)
        self.ckpt = checkpoint_path(checkpoint_dir)
        self.ids = ("" if self.ckpt is None else dataset_id(dataset), config_id, ident)
        if resume and self.ckpt.is_file():
            c = load_checkpoint(self.ckpt, {"theta": self.train, "opt_state": self.opt_state},
                                dataset_id=self.ids[0], config_id=config_id, config=ident)
            self.train, self.opt_state, self.key, self.epoch, self.best_train, self.best_val, self.history = c[:7]
            self.stalls, self.best_epoch = int(c.extra["stalls"]), int(c.extra["best_epoch"])
            self.validated = self.history[-1][0] if self.history else 0
        else:
            v0 = self.validate(self.train)
            self.best_val = v0 if math.isfinite(v0) else math.inf
        if self.best_val <= self.config.tol:
            return Stop.CONVERGED, f"validation loss {self.best_val:.3e} <= tol {self.config.tol:g}"
        if (self.config.patience and 0 < self.epoch <= self.end and self.stage_of[self.epoch] == self.last
                and self.stalls >= self.config.patience):
            return Stop.EARLY_STOPPING, f"{self.stalls} validations without improvement (as checkpointed)"
        return None, ""

    def step(self, index: int) -> Step:
        """Epoch ``index + 1``: train, then validate on schedule (best parameters, patience, tolerance)."""
        e, st, cfg = index + 1, int(self.stage_of[index + 1]), self.config
        new = train_epoch(self.train, self.frozen, self.opt_state, self.key, *self.common, self.x_tr, self.u_tr,
                          model=self.model, integrator=self.integrator, optimizer=self.opt,
                          shape=(self.n_steps, *self.stages[st][:2], cfg.gamma), batch_size=self.bs)
        loss = float(new[3])
        if not (bool(new[4]) and math.isfinite(loss)):
            return Step(Stop.NON_FINITE, f"the training loss or its gradient is not finite at epoch {e}")
        self.train, self.opt_state, self.key, self.epoch, self.loss = new[0], new[1], new[2], e, loss
        if e % cfg.validate_every:
            return Step()
        v, self.validated = self.validate(self.train), e
        self.history.append((e, loss, v))
        postfix = f"train {loss:.3e} val {v:.3e} best {min(v, self.best_val):.3e}"
        if not math.isfinite(v):
            return Step(Stop.NON_FINITE, f"the validation loss is not finite at epoch {e}", postfix)
        if v < self.best_val:
            self.best_train, self.best_val, self.best_epoch, self.stalls = self.train, v, e, 0
        elif st == self.last:  # earlier curriculum stages do not count towards patience
            self.stalls += 1
        if self.best_val <= cfg.tol:
            return Step(Stop.CONVERGED, f"validation loss {self.best_val:.3e} <= tol {cfg.tol:g}", postfix)
        if st == self.last and cfg.patience and self.stalls >= cfg.patience:
            return Step(Stop.EARLY_STOPPING, f"{self.stalls} validations without improvement", postfix)
        return Step(postfix=postfix)

    def save(self, done: int) -> None:
        save_checkpoint(self.ckpt, theta=self.train, opt_state=self.opt_state, key=self.key, epoch=done,
                        best_theta=self.best_train, best_val=self.best_val, history=self.history,
                        dataset_id=self.ids[0], config_id=self.ids[1], config=self.ids[2],
                        extra={"stalls": self.stalls, "best_epoch": self.best_epoch})

    def close(self) -> None:
        """A fit that ran all its epochs ends on a validation, after the checkpoint: a resume replays only the
        schedule."""
        if self.validated < self.epoch:
            v = self.validate(self.train)
            self.history.append((self.epoch, self.loss, v))
            if math.isfinite(v) and v < self.best_val:
                self.best_train, self.best_val, self.best_epoch = self.train, v, self.epoch


def fit(model: AbstractModel, dataset: Any, config: FitConfig = FitConfig(), *, theta0: Any = None,
        checkpoint_dir: str | Path | None = None, resume: bool = False, progress: bool | None = None) -> FitResult:
    """Fit ``model`` to ``dataset.train``, selecting on ``dataset.validation`` (the training set where that is empty),
    from ``theta0`` (default: ``model.init_params`` with a key from ``config.seed``); ``checkpoint_dir``: a folder for
    ``checkpoint.npz`` (+ ``.json``), overwritten unless resuming; ``progress``: True a tqdm bar on stderr, False
    nothing, None a bar when stderr is a terminal, else a plain line every 10 s ($MYRIAD_PROGRESS_SECONDS) and one at
    the end. TypeError or ValueError for a bad argument (all before any work); ``CheckpointMismatch`` when resuming
    from another dataset or configuration."""
    start, traces = time.perf_counter(), sum(TRACES.values())
    n_steps, stages = _check(model, dataset, config, theta0, checkpoint_dir, resume, progress)
    run = _FitRun(model, dataset, config, theta0, n_steps, stages)
    stopped, message = run.start(dataset, checkpoint_dir, resume)
    if stopped is None:
        every = None if run.ckpt is None else config.checkpoint_every or config.validate_every
        stopped, message = train(run, start=run.epoch, end=run.end, every=every, progress=progress,
                                 exhausted=Stop.MAX_EPOCHS)
    if stopped is Stop.MAX_EPOCHS:
        message = f"{run.end} epochs"
        run.close()
    if stopped is Stop.NON_FINITE:
        message += f"; returning the best parameters (epoch {run.best_epoch}, validation loss {run.best_val:.3e})"
    note = "" if run.integrator == dataset.sampling.integrator else " (on the data's grid; the data: adaptive)"
    return FitResult(theta=model.combine(run.best_train, run.frozen), history=run.history,
                     best_validation_loss=run.best_val, epochs=run.epoch, seconds=time.perf_counter() - start,
                     stopped=stopped, best_epoch=run.best_epoch, compile_count=sum(TRACES.values()) - traces,
                     integrator=run.integrator.label + note, message=message)
