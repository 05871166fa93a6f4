"""One system-identification experiment end to end: sample data from the true system, fit a model, plan on it,
judge the plan on the true system; for Neural ODEs optionally the published *datasets in sequence* (train, plan,
sample new trajectories around the plan, retrain on the union).

    report = run_sysid("cancer_treatment", SysidConfig(model="parametric"))
    report.record()   # the JSON record of `myriad sysid`
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ..learn.dataset import Dataset, Sampling, Trajectories, make_dataset
from ..learn.evaluate import Evaluation, evaluate
from ..learn.loop import Stop
from ..learn.models import Parametric, make_model, model_class, network_error
from ..learn.progress import LineProgressMeter, NoProgressMeter, progress_meter
from ..learn.reaim import Reaim, observe, reaim
from ..loader import load
from ..solve import solve
from ..system import System
from ..uncertainty.sde import for_integrator
from .fit import FitConfig, fit
from .least_squares import least_squares
from .noise import DeclaredNoise, declared_noise, noisy_dataset
from .polish import PolishConfig, polish

__all__ = ["SysidConfig", "SysidReport", "data_noise", "node_fit_config", "run_sysid"]

_METHODS = ("least_squares", "adam")
# The fit's stops that are a success; least squares reports a solver status, whose success is the same word.
_FIT_OK = frozenset(str(s) for s in Stop if s.success)


@dataclasses.dataclass(frozen=True)
class SysidConfig:
    """What to learn and how.

    Attributes:
        model: a name in :data:`~myriad.runtime.learn.models.MODELS`: "parametric" (the spec's learnable
            parameters) or "node" (a Neural ODE). The fields left at None take the model's defaults (its
            ``default_*`` class attributes).
        method: "least_squares" (Levenberg-Marquardt, parametric only; the default there) or "adam" (the published
            trajectory loss with optax; the only choice for Neural ODEs).
        trajectories: training trajectories per dataset (validation and test: ``max(3, trajectories // 3)`` each).
        rounds: datasets in sequence (default: 6 for a Neural ODE, 1 for a parametric model).
        noise: observation noise as a fraction of the state range, at most 1 (``sampling.noise_scale="spread"``:
            of each state's spread in the data, for states without finite bounds).
        seed: everything random derives from it (same seed, same result on CPU).
        hidden, activation: the Neural ODE's network (default 2 x 100, tanh; the published "sigmoid" is available).
        fit: the optimiser settings for ``method="adam"``; None: :func:`node_fit_config` for a Neural ODE (the recipe
            in docs/notes/node-training.md), ``FitConfig()`` for a parametric model.
        refit: the optimiser settings of rounds after the first, which start from the last round's parameters
            (None: ``fit`` again, measured better in docs/notes/node-training.md).
        sampling: how trajectories are drawn (its ``noise`` is replaced by ``noise`` above).
        polish: an L-BFGS polish after every round's Adam fit, anchored on the true trajectories of the earlier
            rounds' plans (:mod:`.polish`); ``"default"``: ``PolishConfig()`` for a Neural ODE, None otherwise.
        reaim: after the last round, re-aim the plan at the required final values this many times from observed
            runs of the true system (:mod:`.reaim`); None: 6 for a Neural ODE, 0 for a parametric model (its plan
            is the true model's once the parameters are recovered).
        epochs: Adam's most epochs in the model's own recipe, the default ``fit`` (:func:`node_fit_config`
            for a Neural ODE, ``FitConfig`` otherwise); None: the recipe's (1000). With ``fit`` given, it must say
            the same.
        max_param_error: a parametric fit fails (exit 1) when a learned parameter is off the value the data were
            made with by more than this fraction and by more than 3 of its standard errors (what the data's noise
            explains; least squares only), unless the data cannot identify it; None (``--set
            max_param_error=null``): no check.
        max_gap: the experiment fails (exit 1) when the plan costs more than this fraction above the true optimum
            on the true system (the record's ``relative_gap``); None: no bound.
        declared_noise: on a spec that declares its noise (schema 3 ``noise:``), the data have that process and
            observation noise (:mod:`.noise`) and least squares' standard errors account for it (then ``noise``
            must be 0); false: noise-free data (or ``noise``'s). No effect on a spec without declared noise.
    """

    model: str = "parametric"
    method: str | None = None
    trajectories: int = 10
    rounds: int | None = None
    noise: float = 0.0
    seed: int = 0
    hidden: tuple[int, ...] = (100, 100)
    activation: str = "tanh"
    fit: FitConfig | None = None
    refit: FitConfig | None = None
    sampling: Sampling = Sampling()
    polish: PolishConfig | str | None = "default"
    reaim: int | None = None
    epochs: int | None = None
    max_param_error: float | None = 0.05
    max_gap: float | None = None
    declared_noise: bool = True

    def __post_init__(self):
        cls = model_class(self.model, "SysidConfig")
        method = self.method or cls.default_method
        if method not in _METHODS:
            raise ValueError(f"SysidConfig(method={self.method!r}): expected one of {_METHODS}")
        if not cls.spec_form and method == "least_squares":  # it fits named parameters of the spec's dynamics
            raise ValueError("SysidConfig: least squares fits parametric models only; a Neural ODE trains with adam")
        object.__setattr__(self, "method", method)
        if self.rounds is None:  # datasets in sequence fix a Neural ODE's plan (docs/notes/node-training.md)
            object.__setattr__(self, "rounds", cls.default_rounds)
        epochs = self.epochs
        if epochs is not None and (isinstance(epochs, bool) or not isinstance(epochs, int) or epochs < 1):
            raise ValueError(f"SysidConfig: epochs must be an integer >= 1, got {epochs!r}")
        if self.fit is None:  # a model that trains by Adam by default (a network) gets the recipe measured for it
            recipe = node_fit_config if cls.default_method == "adam" else FitConfig
            object.__setattr__(self, "fit", recipe() if epochs is None else recipe(epochs=epochs))
        elif epochs is not None and getattr(self.fit, "epochs", None) != epochs:
            raise ValueError(f"SysidConfig: epochs ({epochs}) sets the default fit's; the fit given says "
                             f"{getattr(self.fit, 'epochs', None)} (set fit.epochs instead)")
        if error := network_error(self.hidden, self.activation):
            raise ValueError(f"SysidConfig: {error}")
        object.__setattr__(self, "hidden", tuple(int(w) for w in self.hidden))
        if self.refit is not None and not isinstance(self.refit, FitConfig):
            raise ValueError(f"SysidConfig: refit must be a FitConfig or None, got {self.refit!r}")
        if isinstance(self.polish, str) and self.polish == "default":
            object.__setattr__(self, "polish", PolishConfig() if cls.default_polish else None)
        if self.polish is not None and (not isinstance(self.polish, PolishConfig) or method != "adam"):
            raise ValueError(f"SysidConfig: polish must be a PolishConfig (with method='adam') or None, got "
                             f"{self.polish!r}")
        if self.reaim is None:
            object.__setattr__(self, "reaim", cls.default_reaim)
        if isinstance(self.reaim, bool) or not isinstance(self.reaim, int) or self.reaim < 0:
            raise ValueError(f"SysidConfig: reaim must be an integer >= 0, got {self.reaim!r}")
        if self.trajectories < 1 or self.rounds < 1:
            raise ValueError("SysidConfig: trajectories and rounds must be at least 1")
        if not 0 <= self.noise <= 1:
            raise ValueError(f"SysidConfig: noise must be a fraction of the state range in [0, 1] (1: a standard "
                             f"deviation as wide as the range), got {self.noise}")
        for name in ("max_param_error", "max_gap"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < math.inf):
                raise ValueError(f"SysidConfig: {name} must be a finite fraction >= 0 or None, got {v!r}")
        if self.seed < 0:
            raise ValueError(f"SysidConfig: seed must be >= 0, got {self.seed}")
        if not isinstance(self.declared_noise, bool):
            raise ValueError(f"SysidConfig: declared_noise must be true or false, got {self.declared_noise!r}")


@dataclasses.dataclass(frozen=True)
class SysidReport:
    """The outcome: the learned parameters, how they were learned, and the plan judged on the true system."""

    system: str
    config: SysidConfig
    model: Any
    theta: Any
    learned: dict[str, float]
    true: dict[str, float]
    standard_errors: dict[str, float]
    unidentifiable: tuple[str, ...]
    fit_status: str
    fit_message: str
    train_seconds: float
    evaluation: Evaluation
    history: list
    dataset: Dataset
    rounds: int
    polish: tuple = ()
    reaim: Reaim | None = None
    noise: DeclaredNoise | None = None

    @property
    def converged(self) -> bool:
        return self.fit_status in _FIT_OK and self.evaluation.converged

    def record(self) -> dict[str, Any]:
        ev = self.evaluation.record()
        return {
            "system": self.system, "model": self.config.model, "method": self.config.method,
            "learned": self.learned, "true": self.true, "standard_errors": self.standard_errors,
            "unidentifiable": list(self.unidentifiable),
            **{k: ev[k] for k in ("achieved_cost", "achieved_defect", "optimal_cost", "optimal_defect",
                                  "achieved_simulated_cost", "relative_gap", "plan_status")},
            "train_seconds": round(self.train_seconds, 3),
            "seed": self.config.seed, "noise": self.config.noise, "trajectories": self.config.trajectories,
            "rounds": self.rounds, "fit_status": self.fit_status, "fit_message": self.fit_message,
            "converged": bool(self.converged), "failure": failed(self), "message": failed(self) or ev["message"],
            "max_param_error": self.config.max_param_error, "max_gap": self.config.max_gap,
            "polish": [p.record() for p in self.polish],
            "reaim": None if self.reaim is None else self.reaim.record(),
            # only where a spec's declared noise made the data: the records of other specs keep their keys
            **({} if self.noise is None else {"declared_noise": self.noise.record()}),
        }


def node_fit_config(epochs: int = 1000) -> FitConfig:
    """The Neural ODE training recipe (measured in docs/notes/node-training.md): multiple-shooting windows of 10 steps
    on states scaled by their spread in the data, Adam with a warm-up to 1e-2 and a cosine decay over ``epochs``,
    gradients clipped to norm 1."""
    import optax

    schedule = optax.warmup_cosine_decay_schedule(0.0, 1e-2, warmup_steps=min(50, max(1, epochs // 20)),
                                                  decay_steps=max(epochs, 2), end_value=1e-4)
    optimizer = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(schedule))
    return FitConfig(optimizer=optimizer, epochs=epochs, method="multiple_shooting", window=10, scale="data")


def _cat(x: Trajectories, y: Trajectories) -> Trajectories:
    return Trajectories(*(np.concatenate([p, q]) for p, q in zip(x, y)))


def _merge(a: Dataset, b: Dataset) -> Dataset:
    """The union of two datasets on the same grid (each split concatenated)."""
    return dataclasses.replace(a, train=_cat(a.train, b.train), validation=_cat(a.validation, b.validation),
                               test=_cat(a.test, b.test))


def data_noise(system: System, config: SysidConfig) -> DeclaredNoise | None:
    """The declared noise the experiment's data get (None: the kit's, ``config.noise``); ``ValueError`` naming the
    fixes when both are asked for."""
    declared = declared_noise(system) if config.declared_noise else None
    if declared is not None and config.noise > 0:
        raise ValueError(f"{system.name} declares its noise (schema 3 `noise:`), which its data get; noise="
                         f"{config.noise} would add the kit's on top: leave noise at 0, or use the kit's instead of "
                         f"the declared one with --set declared_noise=false")
    if declared is not None and np.any(declared.process > 0):
        try:
            for_integrator(config.sampling.integrator)
        except ValueError as exc:  # (its fix names the integrator; here it is the sampling's)
            raise ValueError(f"{system.name}: {exc} (--set sampling.integrator=...)") from None
    return declared


def _sample(system: System, sampling: Sampling, noise: DeclaredNoise | None, **kwargs) -> Dataset:
    return make_dataset(system, sampling, **kwargs) if noise is None else noisy_dataset(system, sampling, noise,
                                                                                         **kwargs)


def _observe(system: System, sampling: Sampling, noise: DeclaredNoise | None, controls, seed: int) -> Trajectories:
    """The true system's trajectory under ``controls`` from its x0 (the kit's :func:`observe`), under the declared
    noise when there is one."""
    if noise is None:
        return observe(system, sampling, controls, seed)
    exact = dataclasses.replace(sampling, controls="around", spread=0.0, x0_std=0.0, smooth=False)
    return noisy_dataset(system, exact, noise, trajectories=(1, 0, 0), seed=seed, around=np.asarray(controls)).train


def _least_squares_fit(model, dataset: Dataset, theta, noise: float, declared: DeclaredNoise | None = None):
    """Multiple shooting first (each window from an observed state: no blow-up from the guesses, no local minimum
    like Mountain Car's), then single shooting from there (honest standard errors on noisy data, declared noise's
    included)."""
    ms = least_squares(model, dataset, theta0=theta, method="multiple_shooting", noise=declared)
    start = ms.theta if all(math.isfinite(v) for v in ms.theta.values()) else theta
    ls = least_squares(model, dataset, theta0=start, noise=declared)
    # Noise-free, the multiple-shooting fit is exact and may stand in for a refinement that did not converge; on noisy
    # data its standard errors are overconfident (each window starts at a noisy observation), so the refinement's
    # failure stands.
    if not ls.converged and ms.converged and noise == 0 and declared is None:
        ls = dataclasses.replace(ms, message=f"{ms.message} (multiple shooting; the single-shooting refinement did "
                                             f"not converge: {ls.message})")
    return ls


def _phase_meter(progress: bool | None, name: str, config: SysidConfig) -> NoProgressMeter:
    """A progress line as each phase of the experiment begins (sampling, the true optimum, each round's fit and plan,
    the re-aim), so that a run without a terminal says what it is doing before the fit's first epoch line: sampling
    compiles the adaptive integrator and the first epoch the training step, minutes of silence otherwise. A line per
    phase, not per 10 s as the epochs' meter: the phases are few and long. On a terminal a bar of phases; False:
    nothing."""
    total, desc = 2 + config.rounds + (config.reaim > 0), f"sysid {name}"
    if progress is None and not sys.stderr.isatty():
        return LineProgressMeter(total, 0, desc, "phase", seconds=0.0)
    return progress_meter(progress, total, desc=desc, unit="phase")


def _fit_words(config: SysidConfig, r: int) -> str:
    """What round ``r`` does, for its progress line."""
    settings = config.fit if r == 0 or config.refit is None else config.refit
    epochs = f"{settings.epochs} epoch{'s' * (settings.epochs != 1)}"
    how = ("by least squares" if config.method == "least_squares" else
           f"by Adam, {epochs}" + (" (the first compiles the training step)" if r == 0 else ""))
    again = "sampling around the plan, " if r else ""
    return f"round {r + 1}/{config.rounds}: {again}fitting {how}, then planning on the model"


def run_sysid(system: System | str | os.PathLike, config: SysidConfig = SysidConfig(), *,
              checkpoint_dir: str | os.PathLike | None = None, resume: bool = False, progress: bool | None = None,
              transcription=None, solver=None) -> SysidReport:
    """Sample, fit, plan and judge (see the module docstring); ``transcription`` and ``solver`` set the planning
    setting (default: the published one); ``progress`` as :func:`~myriad.runtime.learn.progress.progress_meter`, for
    the phases (:func:`_phase_meter`) and each fit's epochs."""
    system = system if isinstance(system, System) else load(system)
    # A parametric model refuses a system without learnable parameters, before any work.
    model = make_model(config.model, system, hidden=tuple(config.hidden), activation=config.activation)
    with _phase_meter(progress, system.name, config) as phases:
        return _experiment(system, model, config, phases, checkpoint_dir=checkpoint_dir, resume=resume,
                           progress=progress, transcription=transcription, solver=solver)


def _experiment(system: System, model, config: SysidConfig, phases: NoProgressMeter, *, checkpoint_dir, resume,
                progress, transcription, solver) -> SysidReport:
    """:func:`run_sysid`'s work, each phase announced on ``phases``."""
    sampling = dataclasses.replace(config.sampling, noise=config.noise)
    noise = data_noise(system, config)
    held = max(3, config.trajectories // 3)
    sizes = (config.trajectories, held, held)
    phases.update(f"sampling {config.trajectories} + {held} + {held} trajectories (train, validation, test)")
    dataset = _sample(system, sampling, noise, trajectories=sizes, seed=config.seed)
    phases.update("solving the true optimum (the plan's yardstick)")
    optimum = solve(system, transcription, solver, resimulate=False)
    theta, history, seconds = None, [], 0.0
    standard_errors, unidentifiable, status, message = {}, (), "converged", ""
    evaluation, anchors, polishes = None, None, []
    for r in range(config.rounds):
        phases.update(_fit_words(config, r))
        if r:
            around = np.asarray(evaluation.plan.controls)
            if around.shape[0] != dataset.intervals + 1:
                raise ValueError("datasets in sequence need a planning grid equal to the data grid "
                                 f"({dataset.intervals} intervals); the plan has {around.shape[0] - 1}")
            more = _sample(system, dataclasses.replace(sampling, controls="around"), noise, trajectories=sizes,
                           seed=config.seed + r, around=around)
            dataset = _merge(dataset, more)
            if config.polish is not None:  # the plan's own true trajectory, observed like the rest of the data
                anchor = _observe(system, sampling, noise, around, seed=config.seed + r + 10**6)  # (own noise)
                anchors = anchor if anchors is None else _cat(anchors, anchor)
        t0 = time.perf_counter()
        if config.method == "least_squares":
            ls = _least_squares_fit(model, dataset, theta, config.noise, noise)
            theta = {k: jax.numpy.asarray(v) for k, v in ls.theta.items()}
            standard_errors = {k: float(v) for k, v in ls.standard_errors.items()}
            unidentifiable, status = tuple(ls.unidentifiable), "converged" if ls.converged else str(ls.status)
            message = ls.message
        else:
            where = None if checkpoint_dir is None else Path(checkpoint_dir) / f"round{r}"
            settings = config.fit if r == 0 or config.refit is None else config.refit
            fr = fit(model, dataset, settings, theta0=theta, checkpoint_dir=where, resume=resume, progress=progress)
            theta, status, message = fr.theta, str(fr.stopped), fr.message
            history += [(e + (r and history[-1][0]), tl, vl) for e, tl, vl in fr.history]
            if config.polish is not None and fr.success:
                polished = polish(model, dataset, theta, config.polish, anchors=anchors)
                theta = polished.theta
                polishes.append(polished)
                if polished.status is not Stop.CONVERGED:
                    message += f"; round {r}: {polished.message}"
        seconds += time.perf_counter() - t0
        evaluation = evaluate(model, theta, transcription=transcription, solver=solver, optimum=optimum)
    aimed = None
    if config.reaim and evaluation.plan.converged:
        phases.update(f"re-aiming the plan at the required final values ({config.reaim} runs of the true system)")
        t0 = time.perf_counter()
        aimed = reaim(model, theta, evaluation.plan, sampling, iterations=config.reaim, seed=config.seed + 2 * 10**6,
                      transcription=transcription, solver=solver)
        seconds += time.perf_counter() - t0
        if aimed.kept:
            evaluation = evaluate(model, theta, transcription=transcription, solver=solver, optimum=optimum,
                                  plan=aimed.plan)
    learned, true = {}, {}
    if isinstance(model, Parametric):
        learned = {k: float(v) for k, v in theta.items()}
        true = {k: float(v) for k, v in model.true_params().items()}
    return SysidReport(system=system.name, config=config, model=model, theta=theta, learned=learned, true=true,
                       standard_errors=standard_errors, unidentifiable=unidentifiable, fit_status=status,
                       fit_message=message, train_seconds=seconds, evaluation=evaluation, history=history,
                       dataset=dataset, rounds=config.rounds, polish=tuple(polishes), reaim=aimed, noise=noise)


def failed(report: SysidReport) -> str | None:
    """Why the experiment failed, or None: the fit stopped on a failure, the plan did not converge, a learned
    parameter is further from the truth than ``max_param_error`` and 3 standard errors, or the plan's gap exceeds
    ``max_gap`` (see :class:`SysidConfig`)."""
    config, ev = report.config, report.evaluation
    if report.fit_status not in _FIT_OK:
        return f"the fit stopped: {report.fit_status} ({report.fit_message})"
    if not ev.converged:
        return ev.message
    off = []
    for k, v in report.learned.items():
        err, se, true = abs(v - report.true[k]), report.standard_errors.get(k, math.nan), report.true[k]
        if (config.max_param_error is not None and k not in report.unidentifiable and not err <= 3 * se
                and not err <= config.max_param_error * abs(true)):
            off.append(f"{k} {v:.6g} (true {true:.6g}, {err / max(abs(true), 1e-300):.1%} off, standard error "
                       f"{se:.2g})")
    if off:
        return (f"the fit did not find the parameters the data were made with: {'; '.join(off)} (more than "
                f"max_param_error {config.max_param_error:g} and 3 standard errors off): fit longer (epochs), by least "
                f"squares, or allow more (max_param_error)")
    if config.max_gap is not None and not ev.relative_gap <= config.max_gap:
        return (f"the plan costs {ev.achieved_cost:.6g} on the true system, {ev.relative_gap:.1%} above the optimum "
                f"{ev.optimum.cost:.6g}: more than max_gap {config.max_gap:g}")
    return None
