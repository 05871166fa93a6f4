"""The learners' models: a learnable vector field behind one interface, and the learned system to plan on.

    model = make_model("node", system, hidden=(100, 100))   # or Parametric(system), NeuralODE(system, ...)
    sol = solve(model.as_system(model.init_params(key, data)), SingleShooting(), Ipopt())

``MODELS`` is the only source of model names (each model's ``label``).
"""

import dataclasses
from typing import Any

from .base import AbstractModel as AbstractModel
from .learned_system import LearnedSystem as LearnedSystem
from .neural_ode import ACTIVATIONS as ACTIVATIONS
from .neural_ode import NeuralODE as NeuralODE
from .neural_ode import network_error as network_error
from .parametric import Parametric as Parametric

MODELS: dict[str, type[AbstractModel]] = {cls.label: cls for cls in (Parametric, NeuralODE)}

__all__ = ["AbstractModel", "ACTIVATIONS", "LearnedSystem", "MODELS", "NeuralODE", "Parametric", "make_model",
           "model_class", "network_error"]


def model_class(name: str, where: str = "model") -> type[AbstractModel]:
    """The model registered as ``name``; ``ValueError`` naming the choices (``where``: whose setting it is)."""
    if name not in MODELS:
        raise ValueError(f"{where}: unknown model {name!r}; expected one of {tuple(MODELS)}")
    return MODELS[name]


def make_model(name: str, system: Any, **options: Any) -> AbstractModel:
    """The model ``name`` of ``system`` with the ``options`` it takes (a parametric model takes no network widths:
    those are dropped, so a learner passes its whole configuration)."""
    cls = model_class(name)
    fields = {f.name for f in dataclasses.fields(cls)}
    return cls(system, **{k: v for k, v in options.items() if k in fields})
