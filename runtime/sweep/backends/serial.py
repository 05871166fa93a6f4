"""``serial``: the tasks one after another in this process (the default; compiled programs are reused in-process)."""

from __future__ import annotations

from typing import Any, ClassVar, Iterator, Sequence

from ..tasks import run
from .base import AbstractBackend

__all__ = ["SerialBackend"]


class SerialBackend(AbstractBackend):
    name: ClassVar[str] = "serial"

    def map(self, tasks: Sequence[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        for task in tasks:
            yield run(task)
