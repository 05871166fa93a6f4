"""Sweeps: systems x methods x seeds as pure tasks ``run(config) -> record``, on a serial, process or Ray backend,
gathered into one table. See README.md in this folder.

    from myriad.runtime.sweep import SweepConfig, run_sweep, ProcessBackend
    records = run_sweep(SweepConfig(["simple_case"], ["solve", "trap=solve:transcription=trapezoidal"], seeds=[0, 1]),
                        ProcessBackend(workers=2))
"""

from .backends import BACKENDS as BACKENDS
from .backends import AbstractBackend as AbstractBackend
from .backends import ProcessBackend as ProcessBackend
from .backends import RayBackend as RayBackend
from .backends import SerialBackend as SerialBackend
from .config import DEFAULT_CACHE_DIR as DEFAULT_CACHE_DIR
from .config import Method as Method
from .config import SweepConfig as SweepConfig
from .config import parse_method as parse_method
from .kinds import KINDS as KINDS
from .kinds import AbstractKind as AbstractKind
from .kinds import Outcome as Outcome
from .run import run_sweep as run_sweep
from .table import markdown as markdown
from .table import write_tables as write_tables
from .tasks import comparable as comparable

__all__ = [
    "AbstractBackend", "AbstractKind", "BACKENDS", "DEFAULT_CACHE_DIR", "KINDS", "Method", "Outcome",
    "ProcessBackend", "RayBackend", "SerialBackend", "SweepConfig", "comparable", "markdown", "parse_method",
    "run_sweep", "write_tables",
]
