r"""``InteriorPoint``: a second-order primal-dual interior-point NLP solver (after IPOPT), entirely in JAX.

* :mod:`.solver`: the frozen configuration ``InteriorPoint`` (validation, the :class:`AbstractPureSolver` hooks and the
  ``NLPResult`` report);
* :mod:`.loop`: the iteration as a stepper (``InteriorPointStepper``: begin, step, running, end); the pure
  ``(data, z0 or WarmStart) -> InteriorPointSolution`` is its ``lax.while_loop`` of barrier Newton steps with a filter
  line search, and a batch queue drives the same stepper;
* :mod:`.restoration`: IPOPT's feasibility restoration phase, iterations of the same loop where the search fails;
* :mod:`.rules`: the barrier, fraction-to-the-boundary and filter rules both phases use;
* :mod:`.kkt`: the Newton system's inertia-corrected dense factorisation;
* :mod:`.riccati` (with :mod:`.blocks`): the same system stage by stage for single shooting (a Riccati recursion);
* :mod:`.problem`: slacks, bounds, scaling and the exact derivatives;
* :mod:`.implicit`: the solution's own active sets and multipliers, where the solvers' one implicit-function rule
  (:mod:`myriad.runtime.solvers.implicit`) makes the solve differentiable.
"""

from .loop import InteriorPointSolution as InteriorPointSolution
from .loop import WarmStart as WarmStart
from .solver import InteriorPoint as InteriorPoint

__all__ = ["InteriorPoint", "InteriorPointSolution", "WarmStart"]
