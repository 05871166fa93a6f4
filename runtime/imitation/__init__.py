"""Imitation baselines: behaviour cloning and DAgger with the trajectory optimiser as expert (README.md here)."""

from .dagger import DaggerConfig as DaggerConfig
from .expert import Expert as Expert
from .fit import FitConfig as FitConfig
from .policy import Policy as Policy
from .rollout import score as score
from .run import ImitateConfig as ImitateConfig
from .run import run_imitation as run_imitation

__all__ = ["DaggerConfig", "Expert", "FitConfig", "ImitateConfig", "Policy", "run_imitation", "score"]
