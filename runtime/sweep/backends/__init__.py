"""Where a sweep's tasks run: ``BACKENDS`` maps ``--backend NAME`` to its class (one file each, behind
:class:`AbstractBackend`; a test checks every concrete one is here)."""

from .base import AbstractBackend as AbstractBackend
from .process import ProcessBackend as ProcessBackend
from .ray import RayBackend as RayBackend
from .serial import SerialBackend as SerialBackend

BACKENDS: dict[str, type[AbstractBackend]] = {
    "serial": SerialBackend,
    "process": ProcessBackend,
    "ray": RayBackend,
}

__all__ = ["AbstractBackend", "BACKENDS", "ProcessBackend", "RayBackend", "SerialBackend"]
