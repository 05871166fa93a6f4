"""Terminal re-aiming: correct an open-loop plan's final-state miss with a few observed runs of the true system.

A plan on a learned model meets the required final values *in the model*; in the true system it misses them by the
model's error along the plan. Re-aiming is iterative learning control on the target: observe the plan's final state
in the true system (with the dataset's observation noise), then plan again on the same model aimed at

    x_final - aim,   aim <- aim + (observed x(T) - x_final)       (required final states only),

so that the model's own error along the new plan, assumed close to the last one's, is cancelled. It does not converge
monotonically (and diverges on a model whose terminal sensitivities are wrong), so the plan with the smallest
observed miss is kept: never one worse than the start (docs/notes/node-training.md, "Re-aiming").
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..solution import Solution
from ..solve import solve
from .dataset import Sampling, Trajectories, make_dataset

__all__ = ["Reaim", "observe", "reaim"]


def observe(system: Any, sampling: Sampling, controls: Any, seed: int) -> Trajectories:
    """The true system's trajectory under ``controls`` (N + 1, m) from its own x0, observed with ``sampling.noise``
    (its own noise draws from ``seed``)."""
    exact = dataclasses.replace(sampling, controls="around", spread=0.0, x0_std=0.0, smooth=False)
    return make_dataset(system, exact, trajectories=(1, 0, 0), seed=seed, around=np.asarray(controls)).train


@dataclasses.dataclass(frozen=True)
class Reaim:
    """The outcome of :func:`reaim`: the kept ``plan`` (on the model aimed at ``aim``, zeros for the original), the
    observed max |x_i(T) - x_final,i| of every plan tried (``misses``, the original first), the index of the kept one
    and a ``message`` for the report."""

    plan: Solution
    aim: np.ndarray
    misses: tuple[float, ...]
    kept: int
    message: str

    def record(self) -> dict[str, Any]:
        return {"observed_misses": [float(m) for m in self.misses], "kept": self.kept,
                "aim": [float(a) for a in self.aim], "message": self.message}


def reaim(model: Any, theta: Any, plan: Solution, sampling: Sampling, *, iterations: int, seed: int,
          transcription=None, solver=None, params: Any = None, tolerance: float = 1e-6) -> Reaim:
    """Re-aim ``plan`` (a converged plan on ``model.as_system(theta)``) at most ``iterations`` times (each costs one
    planning solve with ``transcription``, ``solver`` and ``params`` and one observed run).

    Args:
        sampling: the dataset's sampling (its observation noise and integrator apply to the observed runs).
        seed: the observed runs' noise draws derive from it.
        tolerance: stop once a plan's observed miss is at most this (absolute; about the planner's own feasibility
            tolerance on the model).
    """
    true = model.system
    mask = true.final_mask
    plans, aims, misses = [plan], [np.zeros(true.n_states)], []
    message = "no required final values: nothing to re-aim"
    for k in range(iterations + 1 if mask.any() else 0):
        x_end = observe(true, sampling, plans[-1].controls, seed + k).states[0, -1]
        miss = np.where(mask, x_end - np.nan_to_num(true.final_values), 0.0)
        misses.append(float(np.max(np.abs(miss))))
        if misses[-1] <= tolerance or k == iterations:
            message = f"{k} re-aims, observed misses " + ", ".join(f"{m:.2e}" for m in misses)
            break
        aims.append(aims[-1] + miss)
        nxt = solve(model.as_system(theta, aims[-1]), transcription, solver, params=params, resimulate=False)
        if not nxt.converged:
            message = (f"re-aim {k + 1} did not converge ({nxt.status}: {nxt.message}); kept the best plan of "
                       f"{k + 1} observed")
            aims.pop()
            break
        plans.append(nxt)
    kept = int(np.argmin(misses)) if misses else 0
    if misses:
        message += f"; kept plan {kept} (observed miss {misses[kept]:.2e})"
    return Reaim(plan=plans[kept], aim=aims[kept], misses=tuple(misses), kept=kept, message=message)
