"""One task of a sweep as a pure function, ``run(config) -> record``: JSON in, JSON out, the same on every backend.
The record's fields and statuses: the README's "Records"; :func:`comparable` drops what depends on where it ran.
"""

from __future__ import annotations

import math
import os
import socket
import time
import traceback
from typing import Any

from .kinds import KINDS
from .kinds.base import RESERVED

__all__ = ["comparable", "error_record", "run"]

VOLATILE = ("host", "pid")


def _setup(cache_dir: str | None) -> None:
    """float64 (every task needs it), and this machine's shared compilation cache (:mod:`..compilation.jax_cache`;
    a process that already has one keeps it: JAX reads it once, at its first compilation)."""
    import jax

    from ..compilation.jax_cache import enable_compilation_cache

    jax.config.update("jax_enable_x64", True)
    if cache_dir:
        enable_compilation_cache(cache_dir)


def _jsonable(value: Any) -> Any:
    """``value`` with NumPy scalars and arrays as Python numbers and lists, and non-finite floats as None."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return _jsonable(value.tolist())
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, bool):
        return bool(value)
    if isinstance(value, int):  # an IntEnum would otherwise reach JSON as its number, yet compare as itself
        return int(value)
    return value if value is None or type(value) is str else str(value)


def _head(config: dict[str, Any]) -> dict[str, Any]:
    method = config.get("method") or {}
    return {"index": config.get("index"), "system": config.get("system"), "method": method.get("name"),
            "kind": method.get("kind"), "seed": config.get("seed"), "settings": method.get("settings")}


def error_record(config: dict[str, Any], exc: BaseException, wall_seconds: float = math.nan) -> dict[str, Any]:
    """The record of a task that raised (or whose worker died: the backends call this with the backend's error)."""
    tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return _jsonable({**_head(config), "status": "error", "message": f"{type(exc).__name__}: {exc}",
                      "error_type": type(exc).__name__, "traceback": tb, "wall_seconds": wall_seconds,
                      "host": socket.gethostname(), "pid": os.getpid()})


def run(config: dict[str, Any]) -> dict[str, Any]:
    """Run one task (a dict from :meth:`SweepConfig.tasks`) and return its record; never raises for a failing task.

    Deterministic: the same config gives the same record up to :func:`comparable` on any backend and worker.
    """
    t0 = time.perf_counter()
    try:
        _setup(config.get("cache_dir"))
        from ..loader import load

        method = config["method"]
        kind = KINDS[method["kind"]]()
        settings = kind.check(method["settings"])  # a hand-written config is checked as the CLI's would be
        system = load(config["system"])
        outcome = kind.run(system, settings, int(config["seed"]))
        clash = sorted(RESERVED & set(outcome.fields))
        if clash:
            raise RuntimeError(f"the {method['kind']} kind returned the task's own fields {clash}")
        record = {**_head(config), "system_name": system.name, "settings": settings,
                  "status": "ok" if outcome.success else "failed",
                  "message": str(outcome.message), **outcome.fields}
    except Exception as exc:  # a failing task is a record, never a crash of the sweep
        return error_record(config, exc, time.perf_counter() - t0)
    record.update(wall_seconds=time.perf_counter() - t0, host=socket.gethostname(), pid=os.getpid())
    return _jsonable(record)


def comparable(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` without what depends on the run rather than the task (``host``, ``pid``, ``*_seconds``)."""
    return {k: v for k, v in record.items() if k not in VOLATILE and not k.endswith("_seconds")}
