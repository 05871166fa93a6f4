"""The base class that every generated system subclasses.

A generated module ``myriad.runtime.systems.<name>`` defines one subclass of :class:`System` whose class
attributes are the spec's static metadata and whose static methods are the compiled JAX functions. Instances hold
no state, so a system is hashable and can be a static argument of ``jax.jit``; parameters travel separately as a
``dict[str, Array]`` pytree (see :meth:`System.default_params`), which is what makes them differentiable.

Schema 2 (path constraints, a free final time): the class attributes and methods for them have defaults here that
mean "none" (a fixed horizon, no path constraints), so schema 1 modules need not, and do not, mention them.
Schema 3 (uncertainty: distributions of parameters, scenarios, a robust objective, noise) likewise: its attributes
default to "nothing uncertain, no noise", and only schema 3 modules write them (specs/README.md says what each means).

Free final time (``free_horizon``): ``horizon`` holds the spec's *guess* of T, so code that reads it keeps working, but
T is a decision variable in ``[*horizon_bounds]``. A transcription maps physical time to ``t = T * tau`` with
``tau`` in [0, 1] (so ``x' = T f(x, u, T tau)`` on the fixed grid in tau) and treats T as one more variable; every
generated function still takes *physical* t, and ``terminal_cost(x, t, p)`` is called with t = T (a cost that uses
``t`` in its terminal term depends on the final time, e.g. ``terminal: t`` for a minimum-time problem).

Path constraints: ``path_lower <= path_constraints(x, u, t, p) <= path_upper`` at every time, elementwise; a
transcription enforces them at every node (and at collocation midpoints). Lower -inf or upper +inf means one-sided;
``path_lower[i] == path_upper[i]`` is an equality constraint. The Jacobians are generated like the dynamics'.

Sign convention: every cost function and every derived artefact (Hamiltonian, costates, u*) is in *minimisation
form*. A spec written with ``sense: maximize`` has its running and terminal payoff negated by the compiler; the
objective the runtime minimises, and reports, is ``J = phi(x(T)) + int L dt`` in that form.
"""

from __future__ import annotations

import math
from typing import Any, Callable, ClassVar, Mapping

import jax.numpy as jnp
import numpy as np

__all__ = ["System", "OptimalControlUnavailable", "UnsupportedFeature"]


class OptimalControlUnavailable(NotImplementedError):
    """Raised by :meth:`System.optimal_control` when the compiler could not characterise u*."""


class UnsupportedFeature(NotImplementedError):
    """Raised by :meth:`System.require_schema1_features`: a method that would silently ignore a spec's path
    constraints or free final time."""


class System:
    """A continuous-time optimal-control problem compiled from a spec.

    minimise   phi(x(T), T) + int_0^T L(x, u, t) dt
    subject to x' = f(x, u, t, p),  x(0) = x0,  x_lower <= x <= x_upper,  u_lower <= u <= u_upper,
               x_i(T) = final_i for every state with a required final value,
               path_lower <= g(x, u, t, p) <= path_upper for all t (schema 2),
    with T = horizon, or T free in horizon_bounds (schema 2, ``free_horizon``).
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

    # Schema 2. A free final time: T is a decision variable in horizon_bounds, and `horizon` is its guess.
    free_horizon: ClassVar[bool] = False
    horizon_bounds: ClassVar[tuple[float, float] | None] = None
    horizon_guess: ClassVar[float | None] = None  # == horizon when free_horizon, else None
    # Path constraints path_lower <= path_constraints(x, u, t, p) <= path_upper, one entry per constraint;
    # kinds: "state" (no control in it), "control" (no state) or "mixed".
    path_constraint_names: ClassVar[tuple[str, ...]] = ()
    path_constraint_descriptions: ClassVar[tuple[str, ...]] = ()
    path_constraint_kinds: ClassVar[tuple[str, ...]] = ()
    path_lower: ClassVar[tuple[float, ...]] = ()
    path_upper: ClassVar[tuple[float, ...]] = ()

    # Schema 3 (uncertainty, issue 30; specs/README.md says what each means). Written only into schema 3 modules;
    # these defaults mean "nothing uncertain, no noise".
    uncertain_params: ClassVar[tuple[str, ...]] = ()  # names, in the spec's parameter order
    uncertain_kinds: ClassVar[tuple[str, ...]] = ()  # "uniform" | "normal" | "lognormal" | "choice", one each
    uncertain_args: ClassVar[tuple[tuple[float, ...], ...]] = ()  # (lo, hi) | (mean, std) | (mu, sigma) | (v1, ...)
    # Explicit scenarios: each row the values of uncertain_params in that order.
    scenarios: ClassVar[tuple[tuple[float, ...], ...]] = ()
    robust_objective: ClassVar[str | None] = None  # None (no `robust:`), "mean", "worst" or "cvar"
    robust_alpha: ClassVar[float | None] = None  # cvar's alpha in (0, 1)
    robust_samples: ClassVar[int] = 16  # scenarios drawn when `scenarios` is absent
    robust_seed: ClassVar[int] = 0
    process_noise: ClassVar[tuple[float, ...]] = ()  # () or one sigma per state (0.0 where not listed)
    observation_noise: ClassVar[tuple[float, ...]] = ()  # () or one std per state (0.0 where not listed)

    # ---- identity: stateless, so equal iff same class (lets a system be a static jit argument) -------------
    def __eq__(self, other: object) -> bool:
        return type(self) is type(other)

    def __hash__(self) -> int:
        return hash((type(self).__module__, type(self).__qualname__, self.spec_sha256))

    def __repr__(self) -> str:
        T = f"T free in {list(self.horizon_bounds)}" if self.free_horizon else f"T={self.horizon}"
        path = f", {self.n_path} path constraints" if self.n_path else ""
        return f"<myriad system {self.name!r}: {self.n_states} states, {self.n_controls} controls{path}, {T}>"

    # ---- sizes and arrays -----------------------------------------------------------------------------------
    @property
    def n_states(self) -> int:
        return len(self.state_names)

    @property
    def n_controls(self) -> int:
        return len(self.control_names)

    @property
    def n_path(self) -> int:
        """The number of path constraints (0 for schema 1 systems)."""
        return len(self.path_constraint_names)

    @property
    def uncertain(self) -> bool:
        """True when the spec declares uncertain parameters, explicit scenarios or a robust objective (schema 3)."""
        return bool(self.uncertain_params or self.scenarios or self.robust_objective is not None)

    def require_schema1_features(self, method: str) -> None:
        """Refuse a system whose path constraints or free final time ``method`` would silently ignore.

        Args:
            method: what is about to solve, for the message (e.g. ``"multiple_shooting + ipopt"``).

        Raises:
            UnsupportedFeature: the system has path constraints or a free final time.
        """
        missing = []
        if self.n_path:
            missing.append(f"path constraints ({', '.join(self.path_constraint_names)})")
        if self.free_horizon:
            lo, hi = self.horizon_bounds
            missing.append(f"a free final time (T in [{lo:g}, {hi:g}])")
        if missing:
            raise UnsupportedFeature(
                f"system {self.name!r} has {' and '.join(missing)}, which {method} does not enforce yet; solving "
                "would ignore them and return the solution of another problem as if it were this one's")

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
        names = ("x0", "x_lower", "x_upper", "u_lower", "u_upper")
        return {k: np.asarray(getattr(self, k), dtype=np.float64) for k in names}

    # ---- parameters as a pytree ----------------------------------------------------------------------------
    def default_params(self, dtype: Any = None) -> dict[str, jnp.ndarray]:
        """The spec's parameter values as a dict of scalar arrays (a differentiable pytree)."""
        # Not cached: called inside a trace these are the trace's own values, and arrays kept from one trace would
        # be closed over by the next program as hidden arguments (which a stored program does not take).
        return {k: jnp.asarray(v, dtype=dtype) for k, v in zip(self.param_names, self.param_values)}

    # ---- compiled functions: every generated subclass defines each as a static method ---------------------------
    # (x, u, t, p) are a state (n_states,), a control (n_controls,), the time and the parameter pytree; every cost and
    # Hamiltonian is in minimisation form.
    dynamics: ClassVar[Callable]  # f(x, u, t, p): the state derivative, shape (n_states,)
    running_cost: ClassVar[Callable]  # L(x, u, t, p): a scalar
    terminal_cost: ClassVar[Callable]  # phi(x(T), T, p), called as (x, t, p): a scalar
    dynamics_jac_x: ClassVar[Callable]  # df/dx (x, u, t, p), shape (n_states, n_states)
    dynamics_jac_u: ClassVar[Callable]  # df/du (x, u, t, p), shape (n_states, n_controls)
    running_cost_grad_x: ClassVar[Callable]  # dL/dx (x, u, t, p)
    running_cost_grad_u: ClassVar[Callable]  # dL/du (x, u, t, p)
    terminal_cost_grad_x: ClassVar[Callable]  # dphi/dx (x, t, p)
    hamiltonian: ClassVar[Callable]  # H = L + lam . f, called as (x, u, lam, t, p)
    costate_dynamics: ClassVar[Callable]  # lam' = -dH/dx (x, u, lam, t, p), shape (n_states,)
    hamiltonian_grad_u: ClassVar[Callable]  # dH/du (x, u, lam, t, p), shape (n_controls,)
    terminal_costate: ClassVar[Callable]  # lam(T) = dphi/dx(x(T)) (x, t, p): transversality for free final states

    # ---- path constraints (schema 2): generated where a spec has any; these defaults mean "none" --------------
    @staticmethod
    def path_constraints(x, u, t, params):
        """g(x, u, t, p), shape (n_path,): here (0,), a system without path constraints."""
        return jnp.zeros((0,), dtype=jnp.result_type(x))

    @staticmethod
    def path_constraints_jac_x(x, u, t, params):
        """dg/dx, shape (n_path, n_states): here (0, n_states)."""
        return jnp.zeros((0, jnp.shape(x)[-1]), dtype=jnp.result_type(x))

    @staticmethod
    def path_constraints_jac_u(x, u, t, params):
        """dg/du, shape (n_path, n_controls): here (0, n_controls)."""
        return jnp.zeros((0, jnp.shape(u)[-1]), dtype=jnp.result_type(x))

    @staticmethod
    def optimal_control(x, lam, t, params):  # pragma: no cover - generated where optimal_control_kind is not "none"
        """u*(x, lam, t, p) minimising H within the control bounds (see ``optimal_control_kind``)."""
        raise NotImplementedError
