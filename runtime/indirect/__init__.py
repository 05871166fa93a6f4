"""Indirect methods: solve Pontryagin's conditions themselves, with no NLP and no NLP solver.

Look one up by name with ``INDIRECT["fbsm"](intervals=500)``; see README.md in this folder to add one.
"""

from .result import SweepCode as SweepCode
from .result import SweepResult as SweepResult
from .result import SweepState as SweepState
from .sweep import ForwardBackwardSweep as ForwardBackwardSweep

# Name -> class, for the CLI. Indirect methods solve the optimality conditions themselves and produce no NLP.
INDIRECT: dict[str, type] = {
    "fbsm": ForwardBackwardSweep,
}

__all__ = ["ForwardBackwardSweep", "INDIRECT", "SweepCode", "SweepResult", "SweepState"]
