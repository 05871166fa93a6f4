"""Transcriptions (optimal-control problem -> NLP); the indirect forward-backward sweep lives in ``runtime/indirect``
and is re-exported here.

Look one up by name with ``TRANSCRIPTIONS["hermite_simpson"](intervals=50)``; see README.md in this folder to add one.
"""

import importlib

from ..data import default_data as default_data
from .base import AbstractTranscription as AbstractTranscription
from .hermite_simpson import HermiteSimpson as HermiteSimpson
from .multiple_shooting import MultipleShooting as MultipleShooting
from .nominal_scales import control_scale as control_scale
from .nominal_scales import state_scale as state_scale
from .single_shooting import SingleShooting as SingleShooting
from .trapezoidal import Trapezoidal as Trapezoidal

# Name -> class, for the CLI. Every concrete AbstractTranscription must be here (a test checks).
TRANSCRIPTIONS: dict[str, type[AbstractTranscription]] = {
    "single_shooting": SingleShooting,
    "multiple_shooting": MultipleShooting,
    "trapezoidal": Trapezoidal,
    "hermite_simpson": HermiteSimpson,
}

# The sweep lives in runtime/indirect; re-exported (with its registry) so that old imports keep working, on first use:
# runtime/indirect imports transcription modules, so an eager import here is a cycle when indirect is imported first.
_FROM_INDIRECT = ("INDIRECT", "ForwardBackwardSweep", "SweepResult", "SweepState")


def __getattr__(name: str):
    if name not in _FROM_INDIRECT:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module("..indirect", __name__), name)


__all__ = [
    "AbstractTranscription",
    "ForwardBackwardSweep",
    "HermiteSimpson",
    "INDIRECT",
    "MultipleShooting",
    "SingleShooting",
    "SweepResult",
    "SweepState",
    "TRANSCRIPTIONS",
    "Trapezoidal",
    "control_scale",
    "default_data",
    "state_scale",
]
