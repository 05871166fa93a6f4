"""One table row in a fresh spawned process, for the bench scripts that learn one model per system.

A table of 13 Neural ODE rows in one process ran out of memory ("LLVM compilation error: Cannot allocate memory")
in its ninth row: every round compiles new programs, and XLA keeps them for the process's life.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import time
import traceback
from concurrent.futures import ProcessPoolExecutor


def isolated(fn, name: str, *args) -> dict:
    """``fn(name, *args)`` (a row dict) run in a fresh spawned process; a crashed child is that row's failure.
    ``total_seconds`` becomes the parent's wall time (the child's start and imports included); the child's own is
    kept as ``experiment_seconds``."""
    t0 = time.perf_counter()
    try:
        with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
            row = pool.submit(fn, name, *args).result()
    except Exception as exc:  # noqa: BLE001 -- e.g. the child killed for memory: never lose the table
        row = {"system": name, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    row["experiment_seconds"] = row.get("total_seconds")
    row["total_seconds"] = time.perf_counter() - t0
    return row


def write_json(path: str, payload: dict) -> None:
    """Write atomically: an interrupted table leaves the previous file whole, never half of a new one."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(payload, fh, indent=1, default=lambda o: None)
    os.replace(tmp, path)
