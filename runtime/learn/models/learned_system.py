"""A model with its parameters as a :class:`~myriad.runtime.system.System`: plan on what was learned.

For a model ``M`` of the true system ``S`` and parameters ``theta``, ``LearnedSystem(M, theta)`` is the problem

    minimise   phi_S(x(T), T, p) + int_0^T L_S(x, u, t, p) dt
    subject to x' = M.vector_field(x, u, t, theta, p),  x(0) = x0_S,  S's bounds and required final values,

with ``p`` the spec's parameters. Its parameters are ``{"spec": p, "model": theta}``: ``theta`` travels as data, so
two learned systems of one model configuration are equal whatever their ``theta``, and a new ``theta`` reuses every
compiled NLP. A ``spec_form`` model's Jacobians, costates and u* are the true system's at its ``spec_form_params``;
any other model's come by autodiff of H = L + lambda . f, and its u* is not characterised.

Re-aiming (``aim``): the planner steers the *model* to ``x_final - aim``, so that a plan whose model misses the true
final state by ``aim`` lands on it in the true system (:mod:`..reaim`); a new aim compiles a new NLP.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ...system import OptimalControlUnavailable, System
from .base import AbstractModel, as_float

__all__ = ["LearnedSystem"]

_METADATA = tuple(System.__annotations__)  # every ClassVar of the base class


class LearnedSystem(System):
    """A learned model of a system, with its parameters, as a ``System`` (immutable; every class attribute of
    ``System`` is the true system's, ``name`` included, so reports line up).

    Args:
        model: the model (its ``system`` is the true system, kept as ``true_system``).
        theta: the model's parameters (structure and shapes of ``model.init_params``, else ValueError).
        aim: None, or an offset (n_states,) subtracted from the required final values when planning (entries of
            free final states are ignored).
    """

    def __init__(self, model: AbstractModel, theta: Any, aim: Any = None):
        if not isinstance(model, AbstractModel):
            raise TypeError(f"LearnedSystem: expected a model (runtime.learn.models), got {type(model).__name__}")
        model.check_params(theta)
        true = model.system
        put = super().__setattr__
        for name in _METADATA:  # not the compiled functions (annotated on System too): a learned system has its own
            if hasattr(true, name) and name not in vars(LearnedSystem):
                put(name, getattr(true, name))
        put("model", model)
        put("theta", as_float(theta))
        put("true_system", true)
        put("model_label", model.label)
        put("aim", None)
        if aim is not None:
            aim = np.asarray(aim, dtype=np.float64)
            if aim.shape != (true.n_states,) or not np.all(np.isfinite(aim)):
                raise ValueError(f"LearnedSystem: aim must be {true.n_states} finite numbers, got {aim!r}")
            put("aim", tuple(float(a) if v is not None else 0.0 for a, v in zip(aim, true.x_final)))
            put("x_final", tuple(None if v is None else float(v) - a for v, a in zip(true.x_final, self.aim)))
        put("time_dependent", bool(true.time_dependent or getattr(model, "time_input", False)))
        if not model.spec_form:
            put("optimal_control_kind", "none")
            put("optimal_control_note", f"the {model.label} model's u* = argmin_u H is not characterised "
                                        f"(no closed form); plan on it with a direct transcription")

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"LearnedSystem is immutable (tried to set {name!r}); build another with as_system")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"LearnedSystem is immutable (tried to delete {name!r})")

    # ---- identity: by (true system, model configuration, aim); theta is data ---------------------------------
    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other.model == self.model and other.aim == self.aim

    def __hash__(self) -> int:
        return hash(("LearnedSystem", self.model, self.aim))

    def __repr__(self) -> str:
        return (f"<myriad learned system {self.name!r} [{self.model_label}]: {self.n_states} states, "
                f"{self.n_controls} controls, T={self.horizon}>")

    # ---- parameters -----------------------------------------------------------------------------------------
    def default_params(self, dtype: Any = None) -> dict:
        """``{"spec": the true system's parameters, "model": theta}``, every leaf as ``dtype`` (when given)."""
        theta = self.theta if dtype is None else jax.tree.map(lambda a: jnp.asarray(a, dtype=dtype), self.theta)
        return {"spec": self.true_system.default_params(dtype), "model": theta}

    def _spec_form(self, params: dict) -> dict:
        return self.model.spec_form_params(params["model"], params["spec"])

    # ---- dynamics and costs ---------------------------------------------------------------------------------
    def dynamics(self, x, u, t, params):
        return self.model.vector_field(x, u, t, params["model"], params["spec"])

    def running_cost(self, x, u, t, params):
        return self.true_system.running_cost(x, u, t, params["spec"])

    def terminal_cost(self, x, t, params):
        return self.true_system.terminal_cost(x, t, params["spec"])

    def running_cost_grad_x(self, x, u, t, params):
        return self.true_system.running_cost_grad_x(x, u, t, params["spec"])

    def running_cost_grad_u(self, x, u, t, params):
        return self.true_system.running_cost_grad_u(x, u, t, params["spec"])

    def terminal_cost_grad_x(self, x, t, params):
        return self.true_system.terminal_cost_grad_x(x, t, params["spec"])

    def terminal_costate(self, x, t, params):
        return self.true_system.terminal_costate(x, t, params["spec"])

    # ---- derivative artefacts: the spec's at spec_form_params, or autodiff ---------------------------------
    def dynamics_jac_x(self, x, u, t, params):
        if self.model.spec_form:
            return self.true_system.dynamics_jac_x(x, u, t, self._spec_form(params))
        return jax.jacfwd(lambda x_: self.dynamics(x_, u, t, params))(jnp.asarray(x))

    def dynamics_jac_u(self, x, u, t, params):
        if self.model.spec_form:
            return self.true_system.dynamics_jac_u(x, u, t, self._spec_form(params))
        return jax.jacfwd(lambda u_: self.dynamics(x, u_, t, params))(jnp.asarray(u))

    def hamiltonian(self, x, u, lam, t, params):
        if self.model.spec_form:
            return self.true_system.hamiltonian(x, u, lam, t, self._spec_form(params))
        return self.running_cost(x, u, t, params) + jnp.dot(lam, self.dynamics(x, u, t, params))

    def costate_dynamics(self, x, u, lam, t, params):
        if self.model.spec_form:
            return self.true_system.costate_dynamics(x, u, lam, t, self._spec_form(params))
        return -jax.grad(lambda x_: self.hamiltonian(x_, u, lam, t, params))(jnp.asarray(x))

    def hamiltonian_grad_u(self, x, u, lam, t, params):
        if self.model.spec_form:
            return self.true_system.hamiltonian_grad_u(x, u, lam, t, self._spec_form(params))
        return jax.grad(lambda u_: self.hamiltonian(x, u_, lam, t, params))(jnp.asarray(u))

    def optimal_control(self, x, lam, t, params):
        if self.model.spec_form:
            return self.true_system.optimal_control(x, lam, t, self._spec_form(params))
        raise OptimalControlUnavailable(f"{self.name} [{self.model_label}]: {self.optimal_control_note}")


AbstractModel.system_class = LearnedSystem  # what every model's as_system builds (see base.py)
