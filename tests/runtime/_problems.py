"""Small optimal-control problems with known solutions, written by hand as System subclasses.

They stand in for compiled specs in the runtime's tests, so every class attribute and compiled function that
:class:`~myriad.runtime.system.System` declares is set here.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from myriad.runtime.system import System

INF = math.inf


class _HandWritten(System):
    title = "hand-written test problem"
    source = "tests/runtime/_problems.py"
    spec_file = "tests/runtime/_problems.py"
    schema = 1
    sense = "minimize"
    state_descriptions = ()
    state_units = ()
    control_descriptions = ("control",)
    control_units = ("",)
    param_descriptions = ()
    learnable = ()
    learnable_guesses = ()
    has_terminal_cost = False
    time_dependent = False
    optimal_control_kind = "stationary"
    optimal_control_note = ""
    reference = {}


class ScalarLQ(_HandWritten):
    """x' = b u, L = q x^2 + u^2, x(0) = 1, T = 1, x(T) free.

    With q = b = 1: x = cosh(1 - t)/cosh(1), u = -sinh(1 - t)/cosh(1), lambda = -2u, J* = tanh(1).
    """

    name = "scalar_lq"
    description = "x' = b u with cost q x^2 + u^2"
    spec_sha256 = "scalar_lq"
    horizon = 1.0
    state_names = ("x",)
    state_descriptions = ("state",)
    state_units = ("",)
    control_names = ("u",)
    param_names = ("q", "b")
    param_values = (1.0, 1.0)
    param_descriptions = ("state weight", "control gain")
    x0 = (1.0,)
    x_lower = (-INF,)
    x_upper = (INF,)
    u_lower = (-INF,)
    u_upper = (INF,)
    x_final = (None,)

    @staticmethod
    def dynamics(x, u, t, p):
        return p["b"] * u

    @staticmethod
    def running_cost(x, u, t, p):
        return p["q"] * x[0] ** 2 + u[0] ** 2

    @staticmethod
    def terminal_cost(x, t, p):
        return jnp.zeros((), dtype=x.dtype)

    @staticmethod
    def dynamics_jac_x(x, u, t, p):
        return jnp.zeros((1, 1), dtype=x.dtype)

    @staticmethod
    def dynamics_jac_u(x, u, t, p):
        return jnp.reshape(p["b"], (1, 1))

    @staticmethod
    def running_cost_grad_x(x, u, t, p):
        return 2.0 * p["q"] * x

    @staticmethod
    def running_cost_grad_u(x, u, t, p):
        return 2.0 * u

    @staticmethod
    def terminal_cost_grad_x(x, t, p):
        return jnp.zeros_like(x)

    @staticmethod
    def hamiltonian(x, u, lam, t, p):
        return ScalarLQ.running_cost(x, u, t, p) + jnp.dot(lam, ScalarLQ.dynamics(x, u, t, p))

    @staticmethod
    def costate_dynamics(x, u, lam, t, p):
        return -2.0 * p["q"] * x

    @staticmethod
    def hamiltonian_grad_u(x, u, lam, t, p):
        return 2.0 * u + p["b"] * lam

    @staticmethod
    def terminal_costate(x, t, p):
        return jnp.zeros_like(x)

    @staticmethod
    def optimal_control(x, lam, t, p):
        return -0.5 * p["b"] * lam

    # ---- the analytic solution (q = b = 1) ----
    J_STAR = math.tanh(1.0)

    @staticmethod
    def x_exact(t):
        return (np.cosh(1.0 - np.asarray(t)) / np.cosh(1.0))[..., None]

    @staticmethod
    def u_exact(t):
        return (-np.sinh(1.0 - np.asarray(t)) / np.cosh(1.0))[..., None]


class DoubleIntegrator(_HandWritten):
    """Minimum energy: p'' = u from rest at 0 to rest at 1 in T = 1, L = u^2.

    J* = 12, u = 6 - 12 t, p = 3 t^2 - 2 t^3, v = 6 t - 6 t^2.
    """

    name = "double_integrator"
    description = "minimum-energy rest-to-rest double integrator"
    spec_sha256 = "double_integrator"
    horizon = 1.0
    state_names = ("p", "v")
    state_descriptions = ("position", "velocity")
    state_units = ("", "")
    control_names = ("u",)
    param_names = ()
    param_values = ()
    x0 = (0.0, 0.0)
    x_lower = (-INF, -INF)
    x_upper = (INF, INF)
    u_lower = (-INF,)
    u_upper = (INF,)
    x_final = (1.0, 0.0)

    @staticmethod
    def dynamics(x, u, t, p):
        return jnp.stack([x[1], u[0]])

    @staticmethod
    def running_cost(x, u, t, p):
        return u[0] ** 2

    @staticmethod
    def terminal_cost(x, t, p):
        return jnp.zeros((), dtype=x.dtype)

    @staticmethod
    def dynamics_jac_x(x, u, t, p):
        return jnp.array([[0.0, 1.0], [0.0, 0.0]], dtype=x.dtype)

    @staticmethod
    def dynamics_jac_u(x, u, t, p):
        return jnp.array([[0.0], [1.0]], dtype=x.dtype)

    @staticmethod
    def running_cost_grad_x(x, u, t, p):
        return jnp.zeros_like(x)

    @staticmethod
    def running_cost_grad_u(x, u, t, p):
        return 2.0 * u

    @staticmethod
    def terminal_cost_grad_x(x, t, p):
        return jnp.zeros_like(x)

    @staticmethod
    def hamiltonian(x, u, lam, t, p):
        return u[0] ** 2 + lam[0] * x[1] + lam[1] * u[0]

    @staticmethod
    def costate_dynamics(x, u, lam, t, p):
        return jnp.stack([jnp.zeros_like(lam[0]), -lam[0]])

    @staticmethod
    def hamiltonian_grad_u(x, u, lam, t, p):
        return 2.0 * u + lam[1]

    @staticmethod
    def terminal_costate(x, t, p):
        return jnp.zeros_like(x)

    @staticmethod
    def optimal_control(x, lam, t, p):
        return jnp.reshape(-0.5 * lam[1], (1,))

    J_STAR = 12.0

    @staticmethod
    def x_exact(t):
        t = np.asarray(t)
        return np.stack([3 * t**2 - 2 * t**3, 6 * t - 6 * t**2], axis=-1)

    @staticmethod
    def u_exact(t):
        return (6.0 - 12.0 * np.asarray(t))[..., None]


class BoundedReach(_HandWritten):
    """x' = u, L = u^2 / 2, phi = -x(T), x(0) = 0, x <= 0.5, u in [-2, 2], T = 1.

    Unconstrained, u = 1 and x(T) = 1; the state bound x <= 0.5 binds at T only, giving u = 0.5, J* = -0.375.
    """

    name = "bounded_reach"
    description = "reach as far as possible with a bound on the state"
    spec_sha256 = "bounded_reach"
    horizon = 1.0
    state_names = ("x",)
    state_descriptions = ("position",)
    state_units = ("",)
    control_names = ("u",)
    param_names = ()
    param_values = ()
    x0 = (0.0,)
    x_lower = (-INF,)
    x_upper = (0.5,)
    u_lower = (-2.0,)
    u_upper = (2.0,)
    x_final = (None,)
    has_terminal_cost = True

    @staticmethod
    def dynamics(x, u, t, p):
        return u

    @staticmethod
    def running_cost(x, u, t, p):
        return 0.5 * u[0] ** 2

    @staticmethod
    def terminal_cost(x, t, p):
        return -x[0]

    @staticmethod
    def dynamics_jac_x(x, u, t, p):
        return jnp.zeros((1, 1), dtype=x.dtype)

    @staticmethod
    def dynamics_jac_u(x, u, t, p):
        return jnp.ones((1, 1), dtype=x.dtype)

    @staticmethod
    def running_cost_grad_x(x, u, t, p):
        return jnp.zeros_like(x)

    @staticmethod
    def running_cost_grad_u(x, u, t, p):
        return u

    @staticmethod
    def terminal_cost_grad_x(x, t, p):
        return -jnp.ones_like(x)

    @staticmethod
    def hamiltonian(x, u, lam, t, p):
        return 0.5 * u[0] ** 2 + lam[0] * u[0]

    @staticmethod
    def costate_dynamics(x, u, lam, t, p):
        return jnp.zeros_like(lam)

    @staticmethod
    def hamiltonian_grad_u(x, u, lam, t, p):
        return u + lam

    @staticmethod
    def terminal_costate(x, t, p):
        return -jnp.ones_like(x)

    @staticmethod
    def optimal_control(x, lam, t, p):
        return jnp.clip(-lam, -2.0, 2.0)

    J_STAR = -0.375


class NoUStar(ScalarLQ):
    """ScalarLQ as if the compiler could not characterise u*."""

    name = "no_u_star"
    spec_sha256 = "no_u_star"
    optimal_control_kind = "none"
    optimal_control_note = "H is not strictly convex in u"


PROBLEMS = (ScalarLQ, DoubleIntegrator, BoundedReach)


class Decay(_HandWritten):
    """x' = -b x + u, x(0) = 1 on [0, 1]; unbounded, so the state scale is |x0| = 1."""

    name = "decay"
    description = "x' = -b x + u"
    spec_sha256 = "decay"
    horizon = 1.0
    state_names = ("x",)
    control_names = ("u",)
    param_names = ("b",)
    param_values = (2.0,)
    x0 = (1.0,)
    x_lower, x_upper, u_lower, u_upper = (-INF,), (INF,), (-INF,), (INF,)
    x_final = (None,)

    @staticmethod
    def dynamics(x, u, t, p):
        return -p["b"] * x + u

    @staticmethod
    def running_cost(x, u, t, p):
        return u[0] ** 2

    @staticmethod
    def terminal_cost(x, t, p):
        return jnp.zeros((), dtype=x.dtype)
