"""myriad.runtime: what consumes generated systems (no sympy is imported here, except to compile specs by path)."""

from .loader import load as load
from .system import OptimalControlUnavailable as OptimalControlUnavailable, System as System

__all__ = ["load", "System", "OptimalControlUnavailable"]
