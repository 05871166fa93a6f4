"""What a kind of sweep method is: checked settings, an optional check against a system, and one run (adding one:
the sweep README)."""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar, Mapping

from ...configs import build, defaults, to_json
from ...system import System, UnsupportedFeature

__all__ = ["AbstractKind", "Outcome", "RESERVED", "refuse_unsupported"]

# The task's own fields: a kind's ``Outcome.fields`` may not use these names (the run fails loudly if it does).
RESERVED = frozenset({"index", "system", "system_name", "method", "kind", "seed", "settings", "status", "message",
                      "error_type", "traceback", "wall_seconds", "host", "pid"})


@dataclasses.dataclass(frozen=True)
class Outcome:
    """One run's result: ``success`` (False for anything that did not converge or missed its goal), a one-line
    ``message`` (the reason, when not a success), and the kind's JSON-ready ``fields`` of the record."""

    success: bool
    message: str
    fields: dict[str, Any]


class AbstractKind(abc.ABC):
    """A way to run one (system, settings, seed) task.

    Class attributes:
        name: the registry name (the ``KIND`` of ``--method KIND:...``).
        Settings: the kind's config, a frozen dataclass with a default for every field whose ``__post_init__``
            raises ``ValueError`` without loading any system (a sweep is checked before any work); a field ``seed``
            is the task's.
        columns: the record fields the printed table shows for this kind (the JSON and CSV have them all).
    """

    name: ClassVar[str]
    Settings: ClassVar[type]
    columns: ClassVar[tuple[str, ...]]

    def check(self, settings: Mapping[str, Any]) -> dict[str, Any]:
        """The settings completed with the defaults, as JSON-native values; ``ValueError`` for an unknown name (the
        known ones listed) or a bad value."""
        known = [f.name for f in dataclasses.fields(self.Settings) if f.name != "seed"]
        unknown = sorted(set(settings) - set(known))
        if unknown:
            raise ValueError(f"{self.name}: unknown settings {unknown}; known: {', '.join(known)}")
        self.config(settings, seed=0)
        # The given settings completed with the defaults, not the config's resolved values (a default that depends
        # on another setting stays None), as JSON: the same objects on every backend and in the written file.
        return to_json({**{k: v for k, v in defaults(self.Settings).items() if k != "seed"}, **settings})

    def config(self, settings: Mapping[str, Any], seed: int) -> Any:
        """The config of these settings, with the task's ``seed`` where the config has one (``ValueError``: a bad
        value, prefixed with the kind's name)."""
        given = dict(settings)
        if any(f.name == "seed" for f in dataclasses.fields(self.Settings)):
            given["seed"] = seed
        try:
            return build(self.Settings, given)
        except ValueError as exc:
            raise ValueError(f"{self.name}: {exc}") from None

    def check_system(self, system: System, settings: dict[str, Any]) -> None:
        """Raise ``ValueError`` if these (checked) settings cannot run on ``system`` (e.g. it has nothing to learn).
        Called on the driver before any work; the default accepts every system."""

    @abc.abstractmethod
    def run(self, system: System, settings: dict[str, Any], seed: int) -> Outcome:
        """Run once. ``settings`` are as :meth:`check` returned them; everything random derives from ``seed``.
        An exception is fine: the task records it as an error."""


def refuse_unsupported(system: System, what: str) -> None:
    """``ValueError`` (the sweep's word for a task that cannot run) if ``system`` has path constraints or a free final
    time that ``what`` would ignore (:meth:`~myriad.runtime.system.System.require_schema1_features`)."""
    try:
        system.require_schema1_features(what)
    except UnsupportedFeature as exc:
        raise ValueError(str(exc)) from None
