r"""``Extragradient``: a first-order augmented-Lagrangian extragradient NLP solver, entirely in JAX. Its modules are
mapped in ``runtime/solvers/README.md``; the measurements behind the defaults are in docs/notes/extragradient-tuning.md.
"""

from .loop import ExtragradientSolution as ExtragradientSolution
from .loop import ExtragradientState as ExtragradientState
from .loop import ExtragradientStepper as ExtragradientStepper
from .loop import optax_promotion as optax_promotion
from .solver import Extragradient as Extragradient

__all__ = ["Extragradient", "ExtragradientSolution", "ExtragradientState", "ExtragradientStepper", "optax_promotion"]
