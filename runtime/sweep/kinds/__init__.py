"""Kinds of sweep method: ``KINDS`` maps ``--method KIND:...`` to its class (a test checks every concrete
:class:`AbstractKind` under ``myriad.runtime`` is here). Adding one: a file beside these and one line below."""

from .base import AbstractKind as AbstractKind
from .base import Outcome as Outcome
from .mpc import Mpc as Mpc
from .solve import Solve as Solve
from .sysid import Sysid as Sysid

KINDS: dict[str, type[AbstractKind]] = {
    "solve": Solve,
    "sysid": Sysid,
    "mpc": Mpc,
}

__all__ = ["AbstractKind", "KINDS", "Mpc", "Outcome", "Solve", "Sysid"]
