"""Run a sweep: every task of a :class:`~.config.SweepConfig` on a backend, the records in table order.

    records = run_sweep(SweepConfig(["simple_case", "van_der_pol"], ["solve", "sysid"], seeds=[0, 1]))
    records = run_sweep(config, RayBackend(address="auto"))
"""

from __future__ import annotations

from typing import Any

from ..learn.progress import progress_meter
from .backends import AbstractBackend, SerialBackend
from .config import SweepConfig
from .tasks import error_record

__all__ = ["run_sweep"]


def run_sweep(config: SweepConfig, backend: AbstractBackend | None = None, *,
              progress: bool | None = None) -> list[dict[str, Any]]:
    """Every task's record (see :mod:`.tasks`; a failed task's has ``status`` ``"failed"`` or ``"error"``, nothing is
    raised for it), sorted by ``index`` (systems, then methods, then seeds). ``backend``: default
    :class:`SerialBackend`, in this process; ``progress``: True a tqdm bar on stderr, False nothing, None a bar when
    stderr is a terminal, else a plain line every 10 s ($MYRIAD_PROGRESS_SECONDS) and one at the end."""
    backend = backend or SerialBackend()
    tasks = config.tasks()
    records, bad = [], 0
    with progress_meter(progress, len(tasks), desc="sweep", unit="task") as meter:  # the learners' meter
        for record in backend.map(tasks):
            records.append(record)
            bad += record["status"] != "ok"
            meter.update(f"{bad} not ok" if bad else "all ok")
    seen = {r["index"] for r in records}
    for task in tasks:  # a backend that lost a task must not make the table look complete
        if task["index"] not in seen:
            records.append(error_record(task, RuntimeError(f"the {backend.name} backend returned no record")))
    return sorted(records, key=lambda r: r["index"])
