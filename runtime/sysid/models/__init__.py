"""System-identification models: a learnable vector field behind one interface, and the learned system to plan on.

    model = Parametric(system)                  # or NeuralODE(system, hidden=(100, 100))
    theta = model.init_params(key, data)        # data: a Trajectories (states and controls) or None
    sol = solve(model.as_system(theta), SingleShooting(), Ipopt())
"""

from .base import AbstractModel as AbstractModel
from .learned_system import LearnedSystem as LearnedSystem
from .neural_ode import ACTIVATIONS as ACTIVATIONS
from .neural_ode import NeuralODE as NeuralODE
from .parametric import Parametric as Parametric

MODELS: dict[str, type[AbstractModel]] = {"parametric": Parametric, "neural_ode": NeuralODE}

__all__ = ["AbstractModel", "ACTIVATIONS", "LearnedSystem", "MODELS", "NeuralODE", "Parametric"]
