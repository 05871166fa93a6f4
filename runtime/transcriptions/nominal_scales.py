"""Nominal magnitudes of a system's states, controls and path constraints, from its bounds.

Every transcription divides its variables and rows by these (``NLP.z_scale``, the defect and path rows), and so do
the indirect methods and the RL environments (observation and action scales), so the same system is scaled the
same way everywhere.
"""

from __future__ import annotations

import numpy as np

from ..system import System

__all__ = ["nominal_scale", "state_scale", "control_scale", "path_scale"]


def nominal_scale(lower: np.ndarray, upper: np.ndarray, fallback: np.ndarray | None = None) -> np.ndarray:
    """Nominal magnitudes: max(|lo|, |hi|) over the finite bounds, else |fallback|, else 1.

    A zero from the bounds (e.g. the single finite bound of [0, inf)) falls through to the fallback, so that a
    population with bounds [0, inf) and x0 = 1000 gets scale 1000, not 1.
    """
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    finite_abs = lambda b: np.where(np.isfinite(b), np.abs(b), 0.0)  # noqa: E731
    scale = np.maximum(finite_abs(lower), finite_abs(upper))
    if fallback is not None:
        fb = np.abs(np.asarray(fallback, dtype=np.float64))
        scale = np.where(scale > 0.0, scale, fb)
    return np.where(scale > 0.0, scale, 1.0)


def state_scale(system: System) -> np.ndarray:
    """Nominal state magnitudes (n_states,): from finite state bounds, else |x0|, else 1."""
    a = system.arrays()
    return nominal_scale(a["x_lower"], a["x_upper"], a["x0"])


def control_scale(system: System) -> np.ndarray:
    """Nominal control magnitudes (n_controls,): from finite control bounds, else 1."""
    a = system.arrays()
    return nominal_scale(a["u_lower"], a["u_upper"])


def path_scale(system: System) -> np.ndarray:
    """Nominal magnitudes of the path constraints (n_path,): max |finite bound|, else 1 (as the state bounds')."""
    return nominal_scale(np.asarray(system.path_lower, dtype=np.float64),
                         np.asarray(system.path_upper, dtype=np.float64))
