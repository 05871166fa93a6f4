"""The expert Algorithm 2 imitates when it is not the true optimum: one recorded trajectory of a
system-identification dataset (:mod:`myriad.runtime.learn.dataset`).

A dataset made with ``Sampling(controls="around", spread=0.0, x0_std=0.0, noise=...)`` around a plan is the usual
source: the expert's controls replayed exactly, its states observed with noise. The expert's ``cost`` and ``defect``
are those of its controls applied to the true system by the transcription's integrator.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..learn.dataset import Dataset, load_dataset
from ..learn.evaluate import apply_plan
from ..loader import load
from ..solution import Solution
from ..status import Status
from ..system import System
from ..transcriptions import SingleShooting

__all__ = ["expert_from_dataset"]

SPLITS = ("train", "validation", "test")


def expert_from_dataset(dataset: Dataset | str | os.PathLike, system: System | str | os.PathLike,
                        transcription: Any = None, *, split: str = "train", index: int = 0) -> Solution:
    """Trajectory ``index`` of ``split`` as a converged :class:`Solution` on ``transcription``'s grid.

    ValueError, before any work: another spec's dataset, an unknown split or an index out of range, perturbed starts
    (the planner starts at the spec's x0), or a grid that is not the transcription's.
    """
    system = system if isinstance(system, System) else load(system)
    source = "the given dataset"
    if not isinstance(dataset, Dataset):
        source = str(dataset)
        dataset = load_dataset(dataset, system)  # checks the spec's hash against the sidecar's
    elif dataset.spec_sha256 != system.spec_sha256:
        raise ValueError(f"expert: the dataset was generated from {dataset.system!r} (spec sha256 "
                         f"{dataset.spec_sha256}), not from {system.name!r} (spec sha256 {system.spec_sha256})")
    if split not in SPLITS:
        raise ValueError(f"expert: split must be one of {SPLITS}, got {split!r}")
    trajectories = getattr(dataset, split)
    count = trajectories.controls.shape[0]
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < count:
        raise ValueError(f"expert: index must be an integer in [0, {count}) for the {count} {split} trajectories "
                         f"of {source}, got {index!r}")
    if dataset.sampling.x0_std > 0:
        raise ValueError(f"expert: {source} was sampled with perturbed starts (x0_std={dataset.sampling.x0_std:g}); "
                         f"the planner starts at the spec's x0, so make the expert's dataset with x0_std=0")
    transcription = SingleShooting() if transcription is None else transcription
    n_controls = transcription.intervals if isinstance(transcription, SingleShooting) else None
    if n_controls != dataset.intervals or getattr(transcription, "grid", None) is not None:
        raise ValueError(f"expert: {source} is on a uniform grid of {dataset.intervals} intervals; the transcription "
                         f"{type(transcription).__name__}(intervals={n_controls}) must be a uniform shooting grid of "
                         f"as many (e.g. SingleShooting(intervals={dataset.intervals}))")
    if not np.isclose(dataset.horizon, float(system.horizon), rtol=1e-12, atol=0.0):
        raise ValueError(f"expert: {source} covers [0, {dataset.horizon:g}], the spec's horizon is "
                         f"{float(system.horizon):g}")
    controls = np.array(trajectories.controls[index])
    states = np.array(trajectories.states[index])
    cost, defect = apply_plan(system, controls, transcription)
    return Solution(system=system.name, transcription=type(transcription).__name__, solver="dataset",
                    integrator=transcription.integrator.label, times=np.array(dataset.times), states=states,
                    controls=controls, cost=cost, defect=defect, converged=True, status=Status.CONVERGED,
                    message=f"recorded trajectory {split}[{index}] of {source} (seed {dataset.seed})", iterations=0,
                    constraint_violation=0.0, intervals=dataset.intervals, final_time=float(system.horizon))
