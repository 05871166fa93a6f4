"""``process``: local worker processes, fresh interpreters (the ``spawn`` context): JAX does not survive a ``fork``
once started. Each worker runs many tasks, reusing what it compiled.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, ClassVar, Iterator, Sequence

from ..tasks import error_record, run
from .base import AbstractBackend

__all__ = ["ProcessBackend"]


class ProcessBackend(AbstractBackend):
    """Args:
        workers: the number of processes (default: the CPU count), never more than the tasks.
    """

    name: ClassVar[str] = "process"

    def __init__(self, workers: int | None = None):
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ValueError(f"process backend: workers must be an integer >= 1, got {workers!r}")
        self.workers = workers

    def map(self, tasks: Sequence[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        if not tasks:
            return
        workers = min(self.workers or os.cpu_count() or 1, len(tasks))
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
        try:
            futures = {pool.submit(run, task): task for task in tasks}
            for future in as_completed(futures):
                try:
                    yield future.result()
                except Exception as exc:  # the worker died (BrokenProcessPool) or the result did not come back
                    yield error_record(futures[future], exc)
        finally:  # an interrupted sweep drops the tasks not yet started instead of waiting for them
            pool.shutdown(wait=True, cancel_futures=True)
