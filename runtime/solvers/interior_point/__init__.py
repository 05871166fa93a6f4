r"""``InteriorPoint``: a second-order primal-dual interior-point NLP solver (after IPOPT), entirely in JAX. Its modules
are mapped in this folder's README.md.
"""

from .loop import InteriorPointSolution as InteriorPointSolution
from .loop import WarmStart as WarmStart
from .solver import InteriorPoint as InteriorPoint

__all__ = ["InteriorPoint", "InteriorPointSolution", "WarmStart"]
