"""The one training loop of every learner: steps, the non-finite stop, checkpoints on a schedule, a progress meter,
and why it ended as a :class:`Stop` (the contract: README.md in this folder, "The loop").

    stop, message = train(learner, start=epoch, end=epochs, every=10, progress=None, exhausted=Stop.MAX_EPOCHS)"""

from __future__ import annotations

import enum
import os
from pathlib import Path
from typing import NamedTuple, Protocol

from ..compilation.blas import one_blas_thread
from .progress import progress_meter

__all__ = ["Learner", "Step", "Stop", "check_run", "checkpoint_path", "train"]


class Stop(enum.Enum):
    """Why a learner stopped; the value is the word its record and its command print."""

    MAX_EPOCHS = "max_epochs"  # a fit ran all its epochs
    COMPLETED = "completed"  # an end-to-end run ran all its iterations
    CONVERGED = "converged"  # the validation loss reached the tolerance
    EARLY_STOPPING = "early_stopping"  # patience ran out: validations in a row without improvement
    NON_FINITE = "non_finite"  # a loss or gradient was NaN or inf; that step was not taken
    STALLED = "stalled"  # no step could be taken (backtracking went below its smallest step)

    def __str__(self) -> str:  # records and messages print the word, never "Stop.X"
        return self.value

    @property
    def success(self) -> bool:
        return self not in (Stop.NON_FINITE, Stop.STALLED)


class Step(NamedTuple):
    """What one step of a learner did: ``stop`` (None: go on) with its ``message``, and the meter's ``postfix``."""

    stop: Stop | None = None
    message: str = ""
    postfix: str | None = None


class Learner(Protocol):
    desc: str  # the meter's label
    unit: str  # what a step is ("epoch", "it")

    def step(self, index: int) -> Step: ...

    def save(self, done: int) -> None: ...


@one_blas_thread()  # a learner's step runs solves jitted into its own program, outside runtime.solve
def train(learner: Learner, *, start: int, end: int, every: int | None, progress: bool | None,
          exhausted: Stop) -> tuple[Stop, str]:
    """Run ``learner.step(index)`` for index = ``start`` (a resumed run's steps done), ..., ``end`` - 1 until one
    says stop; ``(stop, message)``, ``exhausted`` when the budget ran out. Checkpoint after every ``every`` steps (also
    after the last step and at a successful stop; None: never); ``progress`` as :func:`.progress.progress_meter`."""
    with progress_meter(progress, end, initial=start, desc=learner.desc, unit=learner.unit) as meter:
        for index in range(start, end):
            step = learner.step(index)
            if step.stop is Stop.NON_FINITE:
                return step.stop, step.message
            meter.update(step.postfix)
            done = index + 1
            last = done == end if step.stop is None else step.stop.success
            if every is not None and (done % every == 0 or last):
                learner.save(done)
            if step.stop is not None:
                return step.stop, step.message
    return exhausted, ""


def check_run(where: str, *, resume: bool, checkpoint_dir: str | os.PathLike | None, progress: object) -> None:
    """The learners' shared argument checks (before any work)."""
    if resume and checkpoint_dir is None:
        raise ValueError(f"{where}: resume=True needs a checkpoint_dir")
    if progress not in (None, True, False):
        raise ValueError(f"{where}: progress must be None (auto), True or False, got {progress!r}")


def checkpoint_path(checkpoint_dir: str | os.PathLike | None) -> Path | None:
    """Where a learner keeps its checkpoint in ``checkpoint_dir`` (None: no checkpoints)."""
    return None if checkpoint_dir is None else Path(checkpoint_dir) / "checkpoint.npz"
