r"""``Extragradient``: a first-order augmented-Lagrangian extragradient NLP solver, entirely in JAX.

The pieces, each a small function or NamedTuple whose docstring states its mathematics and contract:

* :mod:`.solver`: the frozen configuration ``Extragradient`` (validation, the :class:`AbstractPureSolver` hooks and the
  ``NLPResult`` report);
* :mod:`.loop`: the iteration as a stepper (begin, step, running, end); the pure ``(data, z0) ->
  ExtragradientSolution`` is its ``lax.while_loop``, the end-to-end planner a ``lax.scan`` of its ``iterate``;
* :mod:`.lagrangian`: the augmented Lagrangian's derivatives, the multiplier estimates and the KKT test at one point;
* :mod:`.scaling`: the objective, column and row scales measured at the start;
* :mod:`.box`: the variable bounds, by projection or by a sigmoid reparametrisation;
* :mod:`.penalty`: the penalty schedule (growth when the violation stalls) and the dual steps' units.

Measurements behind the defaults: docs/notes/extragradient-tuning.md.
"""

from .loop import ExtragradientSolution as ExtragradientSolution
from .loop import ExtragradientState as ExtragradientState
from .loop import ExtragradientStepper as ExtragradientStepper
from .loop import optax_promotion as optax_promotion
from .solver import Extragradient as Extragradient

__all__ = ["Extragradient", "ExtragradientSolution", "ExtragradientState", "ExtragradientStepper", "optax_promotion"]
