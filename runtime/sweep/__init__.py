"""Sweeps: systems x methods x seeds as pure tasks ``run(config) -> record``, on a serial, process or Ray backend,
gathered into one table. See README.md in this folder.

    from myriad.runtime.sweep import SweepConfig, run_sweep, ProcessBackend
    records = run_sweep(SweepConfig(["simple_case"], ["solve", "trap=solve:transcription=trapezoidal"], seeds=[0, 1]),
                        ProcessBackend(workers=2))
"""

from .backends import BACKENDS, AbstractBackend, ProcessBackend, RayBackend, SerialBackend
from .config import DEFAULT_CACHE_DIR, Method, SweepConfig, parse_method
from .kinds import KINDS, AbstractKind, Outcome
from .run import run_sweep
from .table import markdown, write_tables
from .tasks import comparable

__all__ = [
    "AbstractBackend", "AbstractKind", "BACKENDS", "DEFAULT_CACHE_DIR", "KINDS", "Method", "Outcome",
    "ProcessBackend", "RayBackend", "SerialBackend", "SweepConfig", "comparable", "markdown", "parse_method",
    "run_sweep", "write_tables",
]
