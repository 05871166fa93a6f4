"""The transcription interface: an optimal-control problem in, a finite-dimensional NLP out."""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, Callable

import numpy as np

from ..nlp import NLP
from ..system import System

__all__ = ["AbstractTranscription", "TrajectoryFn"]

# t (K,) -> values (K, d): a trajectory evaluated at an array of times.
TrajectoryFn = Callable[[np.ndarray], Any]


@dataclasses.dataclass(frozen=True)
class AbstractTranscription(abc.ABC):
    """Turns a :class:`~myriad.runtime.system.System` into an :class:`~myriad.runtime.nlp.NLP`.

    Conventions shared by every transcription (so solvers and the bench can treat them alike):

    - The decision vector ``z`` never contains the initial state: x(0) is read from ``data["x0"]`` in every
      function, so the initial state can change without recompiling (and bounds, which are static, never depend
      on it).
    - The objective is J = phi(x(T)) + int L dt in minimisation form, in the transcription's quadrature.
    - Constraints are ordered ``[dynamics defects (collocation / multiple shooting), required final values,
      final-state bounds (single shooting)]``. Equality rows are residuals with c_lower = c_upper = 0; required
      final values appear as x_i(T) - x_final,i. Defect rows are divided by the state's nominal scale; required
      final values are *not* scaled, so a solver's constraint tolerance is the absolute tolerance on x_i(T).
    - Control and state bounds are ``z_lower`` / ``z_upper`` (infinite where unbounded). A state with a required
      final value has no bound at the final node (the equality pins it; a duplicate active bound would make the
      constraint gradients linearly dependent). ``z_scale`` holds nominal magnitudes from
      :func:`~myriad.runtime.transcriptions.state_scale` and :func:`~myriad.runtime.transcriptions.control_scale`.
    - The functions are pure and not jitted: the solver jits them with ``data`` as a traced argument, so new
      parameters or a new x0 reuse the compiled code, and a batch of ``data`` is one ``jax.vmap``.
    - ``unravel(z, data)`` returns ``(times, states, controls)`` on the transcription's own grid, x(0) included.

    Concrete transcriptions are frozen, hashable dataclasses (static ``jax.jit`` arguments).
    """

    @abc.abstractmethod
    def transcribe(self, system: System) -> NLP:
        """Build the NLP for ``system``; every function of it takes ``(z, data)`` with
        ``data = {"params": dict, "x0": array}`` (see :func:`~myriad.runtime.transcriptions.default_data`)."""

    @abc.abstractmethod
    def sample(self, system: System, states: TrajectoryFn, controls: TrajectoryFn) -> np.ndarray:
        """The decision vector that samples given trajectories on this transcription's grid.

        Useful to warm-start from another solution (interpolate it) and to check a known solution.

        Args:
            system: the system the NLP was built for.
            states: times (K,) -> states (K, n_states).
            controls: times (K,) -> controls (K, n_controls).

        Returns:
            ``z``, a float64 array of shape (n_variables,).
        """
