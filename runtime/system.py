"""The base class that every generated system subclasses.

A generated module ``myriad.runtime.systems.<name>`` defines one subclass of :class:`System` whose class
attributes are the spec's static metadata and whose static methods are the compiled JAX functions. Instances hold
no state, so a system is hashable and can be a static argument of ``jax.jit``; parameters travel separately as a
``dict[str, Array]`` pytree (see :meth:`System.default_params`), which is what makes them differentiable.

Sign convention: every cost function and every derived artefact (Hamiltonian, costates, u*) is in *minimisation
form*. A spec written with ``sense: maximize`` has its running and terminal payoff negated by the compiler; the
objective the runtime minimises, and reports, is ``J = phi(x(T)) + int L dt`` in that form.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import jax.numpy as jnp
import numpy as np

__all__ = ["System", "OptimalControlUnavailable"]


class OptimalControlUnavailable(NotImplementedError):
    """Raised by :meth:`System.optimal_control` when the compiler could not characterise u*."""


class System:
    """A continuous-time optimal-control problem compiled from a spec.

    minimise   phi(x(T), T) + int_0^T L(x, u, t) dt
    subject to x' = f(x, u, t, p),  x(0) = x0,  x_lower <= x <= x_upper,  u_lower <= u <= u_upper,
               x_i(T) = final_i for every state with a required final value.
    """

    # Static metadata: generated subclasses set all of these.
    name: ClassVar[str]
    title: ClassVar[str]
    description: ClassVar[str]
    source: ClassVar[str]
    spec_file: ClassVar[str]
    spec_sha256: ClassVar[str]
    schema: ClassVar[int]
    sense: ClassVar[str]  # "minimize" or "maximize", as written in the spec
    horizon: ClassVar[float]
    state_names: ClassVar[tuple[str, ...]]
    state_descriptions: ClassVar[tuple[str, ...]]
    state_units: ClassVar[tuple[str, ...]]
    control_names: ClassVar[tuple[str, ...]]
    control_descriptions: ClassVar[tuple[str, ...]]
    control_units: ClassVar[tuple[str, ...]]
    param_names: ClassVar[tuple[str, ...]]
    param_values: ClassVar[tuple[float, ...]]
    param_descriptions: ClassVar[tuple[str, ...]]
    learnable: ClassVar[tuple[str, ...]]
    learnable_guesses: ClassVar[tuple[float, ...]]
    # Parameters that the constants below (x0, bounds, x_final, horizon) were evaluated with at compile time.
    structural_params: ClassVar[tuple[str, ...]] = ()
    x0: ClassVar[tuple[float, ...]]
    x_lower: ClassVar[tuple[float, ...]]
    x_upper: ClassVar[tuple[float, ...]]
    u_lower: ClassVar[tuple[float, ...]]
    u_upper: ClassVar[tuple[float, ...]]
    # Required final values; None where x_i(T) is free.
    x_final: ClassVar[tuple[float | None, ...]]
    has_terminal_cost: ClassVar[bool]
    time_dependent: ClassVar[bool]
    # "stationary" (u* from dH/du = 0, clipped), "bang_bang" (sign of the switching function) or "none".
    optimal_control_kind: ClassVar[str]
    optimal_control_note: ClassVar[str]
    # Published and target figures (minimisation form); may be empty.
    reference: ClassVar[Mapping[str, Any]]

    # ---- identity: stateless, so equal iff same class (lets a system be a static jit argument) -------------
    def __eq__(self, other: object) -> bool:
        return type(self) is type(other)

    def __hash__(self) -> int:
        return hash((type(self).__module__, type(self).__qualname__, self.spec_sha256))

    def __repr__(self) -> str:
        return f"<myriad system {self.name!r}: {self.n_states} states, {self.n_controls} controls, T={self.horizon}>"

    # ---- sizes and arrays -----------------------------------------------------------------------------------
    @property
    def n_states(self) -> int:
        return len(self.state_names)

    @property
    def n_controls(self) -> int:
        return len(self.control_names)

    @property
    def final_mask(self) -> np.ndarray:
        """Boolean mask of the states whose final value is required."""
        return np.array([v is not None for v in self.x_final], dtype=bool)

    @property
    def final_values(self) -> np.ndarray:
        """Required final values, NaN where the final state is free."""
        return np.array([math.nan if v is None else v for v in self.x_final], dtype=np.float64)

    def arrays(self) -> dict[str, np.ndarray]:
        """Initial state and bounds as float64 NumPy arrays (infinite bounds stay infinite)."""
        f = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
        return {
            "x0": f(self.x0),
            "x_lower": f(self.x_lower),
            "x_upper": f(self.x_upper),
            "u_lower": f(self.u_lower),
            "u_upper": f(self.u_upper),
        }

    # ---- parameters as a pytree ----------------------------------------------------------------------------
    def default_params(self, dtype: Any = None) -> dict[str, jnp.ndarray]:
        """The spec's parameter values as a dict of scalar arrays (a differentiable pytree)."""
        return {k: jnp.asarray(v, dtype=dtype) for k, v in zip(self.param_names, self.param_values)}

    def guess_params(self, dtype: Any = None) -> dict[str, jnp.ndarray]:
        """Parameters with every learnable one replaced by its starting guess (system identification)."""
        p = self.default_params(dtype)
        for k, g in zip(self.learnable, self.learnable_guesses):
            p[k] = jnp.asarray(g, dtype=dtype)
        return p

    # ---- compiled functions (generated subclasses override every one) -----------------------------------------
    @staticmethod
    def dynamics(x, u, t, params):  # pragma: no cover - overridden
        """f(x, u, t, p): the state derivative, shape (n_states,)."""
        raise NotImplementedError

    @staticmethod
    def running_cost(x, u, t, params):  # pragma: no cover
        """L(x, u, t, p) in minimisation form: a scalar."""
        raise NotImplementedError

    @staticmethod
    def terminal_cost(x, t, params):  # pragma: no cover
        """phi(x(T), T, p) in minimisation form: a scalar."""
        raise NotImplementedError

    @staticmethod
    def dynamics_jac_x(x, u, t, params):  # pragma: no cover
        """df/dx, shape (n_states, n_states)."""
        raise NotImplementedError

    @staticmethod
    def dynamics_jac_u(x, u, t, params):  # pragma: no cover
        """df/du, shape (n_states, n_controls)."""
        raise NotImplementedError

    @staticmethod
    def running_cost_grad_x(x, u, t, params):  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def running_cost_grad_u(x, u, t, params):  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def terminal_cost_grad_x(x, t, params):  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def hamiltonian(x, u, lam, t, params):  # pragma: no cover
        """H = L + lam . f (minimisation form)."""
        raise NotImplementedError

    @staticmethod
    def costate_dynamics(x, u, lam, t, params):  # pragma: no cover
        """lam' = -dH/dx, shape (n_states,)."""
        raise NotImplementedError

    @staticmethod
    def hamiltonian_grad_u(x, u, lam, t, params):  # pragma: no cover
        """dH/du, shape (n_controls,)."""
        raise NotImplementedError

    @staticmethod
    def terminal_costate(x, t, params):  # pragma: no cover
        """lam(T) = dphi/dx(x(T)): the transversality condition for free final states."""
        raise NotImplementedError

    @staticmethod
    def optimal_control(x, lam, t, params):  # pragma: no cover
        """u*(x, lam, t, p) minimising H within the control bounds (see ``optimal_control_kind``)."""
        raise NotImplementedError
