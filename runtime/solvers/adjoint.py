r"""How a learner differentiates through a solve (Optimistix's ``adjoint=``): adjoints are small frozen objects.

* :class:`Unrolled` (``steps`` = K): reverse mode through K iterations of the solver's own step (for the
  extragradient: a ``lax.scan`` of its stepper's ``iterate``, :class:`~myriad.runtime.e2e.planner.UnrolledPlanner`),
  warm-started from the last iterate; exact for the K-step map, whatever the convergence.
* :class:`Implicit`: the implicit function theorem at a converged solve (:mod:`myriad.runtime.solvers.implicit`, the
  one KKT rule every pure solver uses); ``fallback_steps`` is K of the unrolled gradient a learner may fall back to
  where the solve did not converge.

``steps=None`` leaves K to the learner's default (the end-to-end learner: 10 for a parametric model, 5 for a Neural
ODE, as published). :func:`adjoint` also reads an adjoint's name (``"unrolled"``, ``"implicit"``), the command
line's spelling.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

__all__ = ["ADJOINTS", "Implicit", "Unrolled", "adjoint"]


class _Adjoint:
    """What both adjoints share: K of the unrolled passes in the field named ``_field`` (None: the learner's default
    K)."""

    _field: ClassVar[str]

    def __post_init__(self):
        value = getattr(self, self._field)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ValueError(f"{type(self).__name__}({self._field}={value!r}): expected an integer >= 1 or None")

    @property
    def unroll(self) -> int | None:
        """K of the unrolled passes (an implicit adjoint's fallback's)."""
        return getattr(self, self._field)

    def with_unroll(self, steps: int):
        return dataclasses.replace(self, **{self._field: steps})


@dataclasses.dataclass(frozen=True)
class Unrolled(_Adjoint):
    """Reverse mode through ``steps`` (K) solver iterations (None: the learner's default K)."""

    name: ClassVar[str] = "unrolled"
    _field: ClassVar[str] = "steps"
    steps: int | None = None


@dataclasses.dataclass(frozen=True)
class Implicit(_Adjoint):
    """The implicit function theorem at a converged solve; ``fallback_steps``: K of the unrolled gradient a learner
    falls back to where the solve did not converge (None: the learner's default K)."""

    name: ClassVar[str] = "implicit"
    _field: ClassVar[str] = "fallback_steps"
    fallback_steps: int | None = None


ADJOINTS: dict[str, type] = {"unrolled": Unrolled, "implicit": Implicit}


def adjoint(value: Any, steps: int | None = None) -> Unrolled | Implicit:
    """An adjoint from an adjoint object (returned as it is) or a name in :data:`ADJOINTS` with K = ``steps``.

    Raises:
        ValueError: an unknown name, or ``steps`` given with an object.
    """
    if isinstance(value, (Unrolled, Implicit)):
        if steps is not None:
            raise ValueError(f"adjoint({value!r}, steps={steps!r}): the object already says its steps")
        return value
    if isinstance(value, str) and value in ADJOINTS:
        return ADJOINTS[value]().with_unroll(steps) if steps is not None else ADJOINTS[value]()
    raise ValueError(f"adjoint: expected Unrolled(...), Implicit(...) or one of {tuple(ADJOINTS)}, got {value!r}")
