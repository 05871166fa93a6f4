"""Judge what was learned end to end: plan on the learned model (and learned costs) to convergence with IPOPT, apply
the plan to the true system, compare with the expert (the true optimum in the same setting)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..integrators import Heun
from ..learn.dataset import Sampling
from ..learn.evaluate import apply_plan
from ..learn.reaim import reaim as re_aim
from ..solution import Solution, json_number
from ..solve import solve
from ..solvers import Ipopt

__all__ = ["E2EEvaluation", "evaluate_learned"]


@dataclasses.dataclass(frozen=True)
class E2EEvaluation:
    """The converged plan on the learned model, applied to the true system (see :func:`evaluate_learned`)."""

    plan: Solution
    expert: Solution
    achieved_cost: float
    achieved_defect: list[float]
    plan_imitation_loss: float
    converged: bool
    message: str
    reaim: Any = None

    @property
    def relative_gap(self) -> float:
        return (self.achieved_cost - self.expert.cost) / max(abs(self.expert.cost), 1e-300)

    def record(self) -> dict[str, Any]:
        num = json_number
        return {"achieved_cost": num(self.achieved_cost), "achieved_defect": [num(d) for d in self.achieved_defect],
                "optimal_cost": num(self.expert.cost), "optimal_defect": [num(d) for d in self.expert.defect],
                "relative_gap": num(self.relative_gap), "plan_imitation_loss": num(self.plan_imitation_loss),
                "planned_cost": num(self.plan.cost), "plan_status": str(self.plan.status),
                "reaim": None if self.reaim is None else self.reaim.record()}


def evaluate_learned(model: Any, theta: Any, spec_params: dict, expert: Solution, transcription: Any,
                     solver: Any = None, reaim: int = 0) -> E2EEvaluation:
    """Plan on ``model.as_system(theta)`` with the spec parameters ``spec_params`` (learned cost weights in), apply
    the planned controls to the true system (the transcription's integrator on its grid; Heun for collocation, as
    the published measure) at the spec's own parameters, and compare with ``expert``.

    ``plan_imitation_loss`` is the published imitation loss of the converged plan, mean over nodes of
    ||u - u*||^2, when the plan is on the expert's grid (NaN otherwise). ``reaim`` > 0: the converged plan is
    re-aimed at the required final values from that many observed runs of the true system at most
    (:mod:`~myriad.runtime.learn.reaim`; noise-free, on the plan's grid), and the kept plan is judged."""
    true = model.system
    learned = model.as_system(theta)
    params = {"spec": spec_params, "model": theta}
    plan = solve(learned, transcription, solver or Ipopt(), params=params, resimulate=False)
    integrator = getattr(transcription, "integrator", None) or Heun()
    aimed = None
    if reaim and plan.converged:
        sampling = Sampling(intervals=plan.controls.shape[0] - 1, integrator=integrator)
        aimed = re_aim(model, theta, plan, sampling, iterations=reaim, seed=0, transcription=transcription,
                       solver=solver or Ipopt(), params=params)
        plan = aimed.plan
    achieved_cost, defect = apply_plan(true, plan.controls, transcription)
    same_grid = plan.controls.shape == expert.controls.shape
    loss = float(np.mean(np.sum((plan.controls - expert.controls) ** 2, axis=-1))) if same_grid else float("nan")
    message = ("planned on the learned model and applied to the true system" if plan.converged else
               f"planning on the learned model failed ({plan.status}): {plan.message}")
    return E2EEvaluation(plan=plan, expert=expert, achieved_cost=achieved_cost, achieved_defect=defect,
                         plan_imitation_loss=loss, converged=bool(plan.converged), message=message, reaim=aimed)
