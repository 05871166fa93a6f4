"""Offline datasets: demonstrations of a policy in any system's environment, in Minari's format (or ``.npz``), with
reference scores and provenance. See README.md in this folder."""

from .collect import Episodes as Episodes
from .collect import Perturbation as Perturbation
from .collect import collect as collect
from .policies import POLICIES as POLICIES
from .policies import PolicySettings as PolicySettings

__all__ = ["Episodes", "Perturbation", "collect", "POLICIES", "PolicySettings"]
