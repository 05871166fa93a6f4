"""Transcriptions (optimal-control problem -> NLP); the indirect forward-backward sweep lives in ``runtime/indirect``
and is re-exported here.

Look one up by name with ``TRANSCRIPTIONS["hermite_simpson"](intervals=50)``; see README.md in this folder to add one.
"""

from ..data import default_data as default_data

# The sweep lives in runtime/indirect; re-exported (with its registry) so that old imports keep working.
from ..indirect import INDIRECT as INDIRECT
from ..indirect import ForwardBackwardSweep as ForwardBackwardSweep
from ..indirect import SweepResult as SweepResult
from ..indirect import SweepState as SweepState
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
