"""Evaluate a learned model the way it is meant to be used: plan on it, then apply the plan to the true system (with
the planning grid's own integrator, the published measure, and adaptively). A plan that did not converge is reported
as such, with the solver's reason, never as a success."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..data import default_data
from ..integrators import Heun
from ..simulate import simulate
from ..solution import Solution, json_number, resimulate
from ..solve import solve
from ..system import System
from .dataset import Sampling
from .models.base import AbstractModel
from .reaim import Reaim
from .reaim import reaim as re_aim

__all__ = ["Evaluation", "apply_plan", "evaluate"]


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """A plan on the learned model, judged on the true system.

    Attributes:
        plan, optimum: the solution on the learned model (its cost is the model's own prediction) and the true
            model's in the same setting (end-to-end learning's expert).
        achieved_cost, achieved_defect: the planned controls simulated in the true dynamics on the planning grid
            with the setting's integrator: comparable with ``optimum.cost``; ``achieved_simulated_*`` adaptively.
        plan_imitation_loss: the published imitation loss of the plan, mean over nodes of ||u - u*||^2 against the
            optimum's controls, when both are on one grid (NaN otherwise).
        reaim: the :class:`~.reaim.Reaim` that chose ``plan`` (``evaluate(reaim=K)``), else None.
    """

    plan: Solution
    optimum: Solution
    achieved_cost: float
    achieved_defect: list[float]
    achieved_simulated_cost: float
    achieved_simulated_defect: list[float]
    converged: bool
    message: str
    plan_imitation_loss: float = float("nan")
    reaim: Reaim | None = None

    @property
    def relative_gap(self) -> float:
        """(achieved - optimal) / |optimal|: how much worse the plan is on the true system (0 at best)."""
        return (self.achieved_cost - self.optimum.cost) / max(abs(self.optimum.cost), 1e-300)

    @property
    def max_achieved_defect(self) -> float:
        return max((abs(d) for d in self.achieved_defect), default=0.0)

    def record(self) -> dict[str, Any]:
        num = json_number
        return {
            "achieved_cost": num(self.achieved_cost), "achieved_defect": [num(d) for d in self.achieved_defect],
            "achieved_simulated_cost": num(self.achieved_simulated_cost),
            "achieved_simulated_defect": [num(d) for d in self.achieved_simulated_defect],
            "optimal_cost": num(self.optimum.cost), "optimal_defect": [num(d) for d in self.optimum.defect],
            "planned_cost": num(self.plan.cost), "relative_gap": num(self.relative_gap),
            "plan_imitation_loss": num(self.plan_imitation_loss), "plan_status": str(self.plan.status),
            "plan_message": self.plan.message, "converged": bool(self.converged), "message": self.message,
            "reaim": None if self.reaim is None else self.reaim.record(),
        }


def apply_plan(system: System, controls: Any, transcription: Any) -> tuple[float, list[float]]:
    """``(cost, final-state defects)`` of ``controls`` applied to ``system`` at the spec's own parameters, simulated
    on the plan's grid with the transcription's integrator; collocation (no integrator of its own) with the
    published Heun."""
    data = default_data(system)
    integrator = getattr(transcription, "integrator", None) or Heun()
    sim = simulate(system, controls, data.params, data.x0, integrator=integrator)
    return float(sim.cost), [float(d) for d in np.asarray(sim.defect)[system.final_mask]]


def evaluate(model: AbstractModel, theta: Any, *, transcription=None, solver=None, optimum: Solution | None = None,
             plan: Solution | None = None, params: Any = None, reaim: int = 0) -> Evaluation:
    """Plan on ``model.as_system(theta)``, apply the plan to ``model.system``, and compare with the true optimum.

    Args:
        transcription, solver: the planning setting (default: the published one, single shooting with Heun on
            100 intervals and IPOPT), also the true optimum's unless ``optimum`` (or an expert) is given.
        plan: a plan on the model already made in this setting (e.g. re-aimed), judged instead of planning again.
        params: the learned system's parameters for planning (``{"spec": ..., "model": theta}``, e.g. with learned
            cost weights); None: the spec's and ``theta``.
        reaim: > 0: re-aim the converged plan at the required final values from that many observed runs of the true
            system at most (:mod:`.reaim`; noise-free, on the plan's grid, seed 0), and judge the kept plan.
    """
    true: System = model.system
    if plan is None:
        plan = solve(model.as_system(theta), transcription, solver, params=params, resimulate=False)
    if optimum is None:
        optimum = solve(true, transcription, solver, resimulate=False)
    aimed = None
    if reaim and plan.converged:
        sampling = Sampling(intervals=plan.controls.shape[0] - 1,
                            integrator=getattr(transcription, "integrator", None) or Heun())
        aimed = re_aim(model, theta, plan, sampling, iterations=reaim, seed=0, transcription=transcription,
                       solver=solver, params=params)
        plan = aimed.plan
    achieved_cost, achieved_defect = apply_plan(true, plan.controls, transcription)
    cost_a, defect_a, _ = resimulate(true, plan.times, plan.controls, default_data(true))
    same_grid = plan.controls.shape == optimum.controls.shape
    loss = np.mean(np.sum((plan.controls - optimum.controls) ** 2, axis=-1)) if same_grid else np.nan
    converged = plan.converged and optimum.converged
    if converged:
        message = "planned on the learned model and applied to the true system"
    elif not plan.converged:
        message = f"planning on the learned model failed ({plan.status}): {plan.message}"
    else:
        message = f"the true-model optimum did not converge ({optimum.status}): {optimum.message}"
    return Evaluation(plan=plan, optimum=optimum, achieved_cost=achieved_cost, achieved_defect=achieved_defect,
                      achieved_simulated_cost=cost_a, achieved_simulated_defect=defect_a, converged=converged,
                      message=message, plan_imitation_loss=float(loss), reaim=aimed)
