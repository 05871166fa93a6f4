"""Stochastic integrators of Ito SDEs with diagonal additive noise on a fixed grid (schema 3's ``noise: process:``):

    dx = f(x, u, t) dt + diag(sigma) dW,        W a standard Wiener process, sigma constant.

One step maps (x_k, the Wiener increment dW_k ~ N(0, h I)) to x_{k+1}; the caller draws the increments, so a step is
a pure function of them (the tests couple grids through them) and the key handling is one place
(:func:`increments`). Orders, derivations and sources: README.md in this folder.

    scheme = SCHEMES["heun"]()                            # weak order 2 for additive noise
    x1 = scheme.step(f, x0, t, h, u, sigma, dw)
    xs = integrate(scheme, f, x0, 0.0, h, n, u, sigma, key)   # (n + 1, d) on the grid t_k = t0 + k h
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp

from ..integrators import AbstractIntegrator, Euler, Heun
from ..integrators.base import Dynamics

__all__ = ["SDEScheme", "EulerMaruyama", "StochasticHeun", "SCHEMES", "for_integrator", "increments", "integrate"]


@dataclasses.dataclass(frozen=True)
class SDEScheme(abc.ABC):
    """One step of a stochastic integrator over [t, t + h] with the control held at ``u`` (frozen and hashable:
    a static ``jit`` argument, like the ODE integrators)."""

    label: ClassVar[str]
    weak_order: ClassVar[int]  # |E g(X_N) - E g(X(T))| = O(h^weak_order) for smooth g, f
    strong_order: ClassVar[float]  # E |X_N - X(T)| = O(h^strong_order), additive noise
    deterministic: ClassVar[type[AbstractIntegrator]]  # the ODE method it is with sigma = 0

    @abc.abstractmethod
    def step(self, f: Dynamics, x: Any, t: Any, h: Any, u: Any, sigma: Any, dw: Any) -> Any:
        """x_{k+1} from x (d,) at t under dx = f(x, u, t) dt + sigma dW, ``dw`` the Wiener increment (d,) over
        the step (N(0, h) each), ``sigma`` (d,) or a scalar."""


@dataclasses.dataclass(frozen=True)
class EulerMaruyama(SDEScheme):
    """Euler-Maruyama: x_{k+1} = x_k + h f(x_k, u, t_k) + sigma dW_k. Weak order 1 (Kloeden & Platen 1992,
    Section 14.1, Theorem 14.5.2); strong order 1 for additive noise, where it is the Milstein scheme (0.5 in
    general)."""

    label: ClassVar[str] = "euler_maruyama"
    weak_order: ClassVar[int] = 1
    strong_order: ClassVar[float] = 1.0
    deterministic: ClassVar[type[AbstractIntegrator]] = Euler

    def step(self, f, x, t, h, u, sigma, dw):
        return x + h * f(x, u, t) + sigma * dw


@dataclasses.dataclass(frozen=True)
class StochasticHeun(SDEScheme):
    """The stochastic Heun scheme, Platen's explicit weak order 2.0 scheme for additive noise:

        y = x_k + h f(x_k, u, t_k) + sigma dW_k                          (the Euler-Maruyama predictor)
        x_{k+1} = x_k + h (f(x_k, u, t_k) + f(y, u, t_k + h)) / 2 + sigma dW_k.

    Kloeden & Platen (1992), Section 15.1, eq. (15.1.1) (the explicit order 2.0 weak scheme): with a constant
    diffusion b = sigma its two supporting values Y+- drop out and it is exactly this; with Gaussian dW_k (the scheme
    allows them, or three-point increments) it is weak order 2. With sigma = 0 it is Heun's method (the env's
    default ODE integrator) to the bit.
    """

    label: ClassVar[str] = "heun"
    weak_order: ClassVar[int] = 2
    strong_order: ClassVar[float] = 1.0
    deterministic: ClassVar[type[AbstractIntegrator]] = Heun

    def step(self, f, x, t, h, u, sigma, dw):
        noise = sigma * dw
        k1 = f(x, u, t)
        k2 = f(x + h * k1 + noise, u, t + h)
        return x + 0.5 * h * (k1 + k2) + noise


SCHEMES: dict[str, type[SDEScheme]] = {"euler_maruyama": EulerMaruyama, "heun": StochasticHeun}


def for_integrator(integrator: AbstractIntegrator) -> SDEScheme:
    """The stochastic scheme that reduces to ``integrator`` without noise: Euler -> Euler-Maruyama, Heun -> the
    stochastic Heun scheme; a ``ValueError`` for the others (no scheme here has them as its limit)."""
    for scheme in SCHEMES.values():
        if type(integrator) is scheme.deterministic:
            return scheme()
    raise ValueError(f"process noise needs a stochastic scheme whose noiseless limit is the env's integrator, and "
                     f"{integrator.label!r} has none: pass integrator='heun' (the stochastic Heun "
                     f"scheme, weak order 2) or 'euler' (Euler-Maruyama, weak order 1)")


def increments(key: Any, n: int, d: int, h: Any, dtype: Any) -> Any:
    """(n, d) independent Wiener increments over steps of length h: sqrt(h) N(0, 1)."""
    return jnp.sqrt(jnp.asarray(h, dtype)) * jax.random.normal(key, (n, d), dtype)


def integrate(scheme: SDEScheme, f: Dynamics, x0: Any, t0: Any, h: Any, n: int, u: Any, sigma: Any, key: Any = None,
              dw: Any = None) -> Any:
    """(n + 1, d): x on the grid t_k = t0 + k h under the control held at ``u``, the increments ``dw`` (n, d)
    given or drawn from ``key``."""
    x0 = jnp.asarray(x0)
    if dw is None:
        dw = increments(key, n, x0.shape[0], h, x0.dtype)

    def body(x, kw):
        k, w = kw
        x = scheme.step(f, x, t0 + k.astype(x.dtype) * h, h, u, sigma, w)
        return x, x

    _, xs = jax.lax.scan(body, x0, (jnp.arange(n), dw))
    return jnp.concatenate([x0[None], xs])
