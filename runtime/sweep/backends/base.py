"""The backend interface: run a list of tasks, hand back their records as they finish."""

from __future__ import annotations

import abc
from typing import Any, ClassVar, Iterator, Sequence

__all__ = ["AbstractBackend", "BackendUnavailable"]


class BackendUnavailable(RuntimeError):
    """The backend could not start where it was told to (no cluster at the address): the user's setting to fix, so
    the CLI reports it as a usage error, not as a failed task or an internal error."""


class AbstractBackend(abc.ABC):
    """Where the tasks of a sweep run; ``name`` is its registry name (``--backend NAME``)."""

    name: ClassVar[str]

    def check(self) -> None:
        """Raise ``ValueError`` if this backend cannot start here (a missing optional dependency): called by the CLI
        before any work. The default accepts."""

    @abc.abstractmethod
    def map(self, tasks: Sequence[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        """Run every task with :func:`myriad.runtime.sweep.tasks.run`, yielding one record per task as each finishes
        (in any order). A task that fails, or whose worker dies, yields an error record; it never stops the others.
        """
