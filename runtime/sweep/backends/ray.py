"""``ray``: the tasks on a Ray cluster, a private local one for the sweep or one at ``address`` (``auto``, or
``HOST:PORT`` of ``ray start --head``); each task asks for one CPU (the README's "Backends").
"""

from __future__ import annotations

import logging
from typing import Any, ClassVar, Iterator, Sequence

from ..tasks import error_record, run
from .base import AbstractBackend, BackendUnavailable

__all__ = ["RayBackend"]


class RayBackend(AbstractBackend):
    """Args:
        address: a cluster to connect to; None: start a local one for this sweep.
        workers: the most tasks in flight at once (default: all; the cluster's CPUs then decide).
    """

    name: ClassVar[str] = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None):
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ValueError(f"ray backend: workers must be an integer >= 1, got {workers!r}")
        self.address = address
        self.workers = workers

    def check(self) -> None:
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ValueError("the ray backend needs Ray: pip install 'myriad-control[ray]'") from None

    def map(self, tasks: Sequence[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        self.check()
        import ray

        owner = not ray.is_initialized()
        if owner:
            # Worker output stays in the cluster's logs: a task's failure is in its record, and the table is not
            # interleaved with solver chatter.
            options = {"logging_level": logging.WARNING, "log_to_driver": False}
            if self.address is None:
                options.update(include_dashboard=False, num_cpus=self.workers)
            try:
                ray.init(address=self.address, **options)
            except ConnectionError as exc:  # nobody listens at the address: the user's setting, not a bug
                where = "a local Ray cluster did not start" if self.address is None else (
                    f"--address {self.address}: no Ray cluster to connect to")
                raise BackendUnavailable(f"{where} ({exc}); start one with `ray start --head` (then --address "
                                         f"auto), or leave --address out for a local one") from exc
        try:
            remote = ray.remote(num_cpus=1)(run)
            queue, pending = list(tasks), {}
            while queue or pending:
                while queue and (self.workers is None or len(pending) < self.workers):
                    task = queue.pop(0)
                    pending[remote.remote(task)] = task
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    task = pending.pop(ref)
                    try:
                        yield ray.get(ref)
                    except Exception as exc:  # the worker or its node died (run itself never raises)
                        yield error_record(task, exc)
        finally:
            if owner:
                ray.shutdown()
