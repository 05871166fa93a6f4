"""Uncertainty declared in a spec (schema 3): the distributions of uncertain parameters, the scenarios of a robust
plan, and stochastic integrators for process noise. See README.md in this folder."""

from .distributions import draw as draw
from .distributions import sample as sample
from .distributions import uncertain_spec as uncertain_spec
from .distributions import with_values as with_values
from .scenarios import scenario_data as scenario_data
from .scenarios import scenario_params as scenario_params
from .scenarios import scenario_values as scenario_values
from .sde import SCHEMES as SCHEMES
from .sde import EulerMaruyama as EulerMaruyama
from .sde import StochasticHeun as StochasticHeun

__all__ = ["draw", "sample", "uncertain_spec", "with_values", "scenario_data", "scenario_params", "scenario_values",
           "SCHEMES", "EulerMaruyama", "StochasticHeun"]
