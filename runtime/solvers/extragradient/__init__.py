r"""``Extragradient``: a first-order augmented-Lagrangian extragradient NLP solver, entirely in JAX.

The pieces, each a small function or NamedTuple whose docstring states its mathematics and contract:

* :mod:`.solver`: the frozen configuration ``Extragradient`` (validation, the :class:`AbstractPureSolver` hooks and the
  ``NLPResult`` report);
* :mod:`.loop`: the pure ``(data, z0) -> ExtragradientSolution``, one ``lax.while_loop`` of extragradient steps;
* :mod:`.lagrangian`: the augmented Lagrangian's derivatives, the multiplier estimates and the KKT test at one point;
* :mod:`.scaling`: the objective, column and row scales measured at the start;
* :mod:`.box`: the variable bounds, by projection or by a sigmoid reparametrisation;
* :mod:`.penalty`: the penalty schedule (growth when the violation stalls) and the dual steps' units.

Measurements behind the defaults: docs/notes/extragradient-tuning.md.
"""

from .loop import ExtragradientSolution as ExtragradientSolution
from .solver import Extragradient as Extragradient

__all__ = ["Extragradient", "ExtragradientSolution"]
