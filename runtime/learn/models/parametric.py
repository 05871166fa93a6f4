"""The parametric model: the spec's own dynamics with some of its parameters free.

For the spec's dynamics ``f(x, u, t, p)`` and a set ``S`` of learnable parameter names (by default the spec's
``learnable`` list), the model is

    f_theta(x, u, t) = f(x, u, t, p[S <- theta]),        theta = {name: value for name in S},

starting from the spec's ``guess`` values. A :class:`LearnedSystem` of this model reuses the compiler's derivative
artefacts (Jacobians, costates, u*) at ``p[S <- theta]``, so the forward-backward sweep works on it; the compiled
specs' costs never use a learnable parameter (a test checks all of them), so the artefacts agree with the costs.

A learnable parameter may be *structural* (Tumour's ``b``, ``d``, ``mu`` set its x0 and bounds): the learned system
keeps the true system's x0, bounds and horizon, which is what identification wants (the world's constraints are
not learned), so nothing is refused.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax.numpy as jnp

from .base import AbstractModel, float_dtype

__all__ = ["Parametric"]


@dataclasses.dataclass(frozen=True)
class Parametric(AbstractModel):
    """The spec's dynamics with the parameters ``learnable`` free: a subset of ``system.learnable`` (None: all),
    a tuple in the spec's order, so ``Parametric(s, ["delta", "r"])`` equals ``Parametric(s, ("r", "delta"))``."""

    learnable: tuple[str, ...] | None = None

    label: ClassVar[str] = "parametric"
    spec_form: ClassVar[bool] = True
    # Levenberg-Marquardt recovers the parameters (with standard errors) and the plan is then the true model's: one
    # round, no re-aim; the published unrolled planner takes 10 steps.
    default_method: ClassVar[str] = "least_squares"
    # The unrolled learner creeps along a valley where r and delta trade off (Cancer Treatment, K = 10, Adam 1e-2):
    # 1.3 % off after 600 iterations, 0.33 % after 1200, within the 1 % goal (docs/notes/e2e-cancer.md).
    default_iterations: ClassVar[int] = 1200

    def __post_init__(self):
        super().__post_init__()
        known = tuple(self.system.learnable)
        if not known:
            raise ValueError(f"{self.system.name}: the spec declares no learnable parameters, so there is nothing for "
                             f"a parametric model to identify (use a NeuralODE)")
        if self.learnable is None:
            names = known
        else:
            given = (self.learnable,) if isinstance(self.learnable, str) else tuple(self.learnable)
            unknown = [n for n in given if n not in known]
            if unknown:
                raise ValueError(f"{self.system.name}: {unknown} not learnable; the spec's learnable parameters are "
                                 f"{list(known)}")
            if not given or len(set(given)) != len(given):
                raise ValueError(f"{self.system.name}: `learnable` must name each parameter once, got {list(given)}")
            names = tuple(n for n in known if n in given)
        object.__setattr__(self, "learnable", names)

    def init_params(self, key: Any = None, data: Any = None) -> dict:
        """``{name: guess}``: the spec's starting guesses, float64 scalars (``key`` and ``data`` are unused)."""
        del key, data
        guesses = dict(zip(self.system.learnable, self.system.learnable_guesses))
        return {n: jnp.asarray(guesses[n], dtype=float_dtype()) for n in self.learnable}

    def true_params(self) -> dict:
        """``{name: value}``: the spec's values of the free parameters (float64 scalars)."""
        values = dict(zip(self.system.param_names, self.system.param_values))
        return {n: jnp.asarray(values[n], dtype=float_dtype()) for n in self.learnable}

    def spec_form_params(self, theta: dict, spec_params: dict) -> dict:
        """``p[S <- theta]``: the spec's parameters with the free ones replaced."""
        return {**spec_params, **theta}

    def vector_field(self, x: Any, u: Any, t: Any, theta: dict, spec_params: dict) -> Any:
        """``system.dynamics(x, u, t, p[S <- theta])``."""
        return self.system.dynamics(x, u, t, self.spec_form_params(theta, spec_params))
