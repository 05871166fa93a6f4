"""Datasets and standard errors under a schema 3 spec's declared noise (``noise: {process: ..., observation: ...}``).

The data: the kit's trajectories (:func:`~myriad.runtime.learn.dataset.make_dataset`: its controls and starts, from
the same seed) re-integrated as the Ito SDE ``dx = f(x, u, t) dt + diag(sigma) dW`` by the stochastic scheme whose
noiseless limit is the sampling's integrator (:func:`~myriad.runtime.uncertainty.sde.for_integrator`: Heun ->
stochastic Heun, weak order 2; Euler -> Euler-Maruyama), the control piecewise linear as in the kit (u_k at t_k,
u_{k+1} at t_k + h: the only times these schemes evaluate the drift), then observed as ``y_k = x_k + std * N(0, 1)``
at every node, the start included. Nothing is clipped to the state bounds: as in the env (runtime/rl/README.md), a
Gaussian increment or reading has no bound. The noise is drawn from its own stream of ``key(seed)``.

The standard errors (:func:`residual_covariance`): least squares fits by ordinary (weighted) least squares, whose
Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` assumes independent residuals of equal variance. Process noise makes
a trajectory's residuals correlated (a random force displaces every later node), so the fit reports the sandwich
covariance ``(J^T J)^+ (sum_b J_b^T Omega_b J_b) (J^T J)^+`` instead, with Omega_b the covariance of trajectory b's
weighted residuals under the declared noise, linearised about the fitted path:

    Omega_b = W (h G_b G_b^T + diag(std^2)) W,      G_b = d x_{0..N} / d dW at dW = 0 (the scheme's own steps),

W the residual weights. It is exact for a linear system and first-order in the noise otherwise; the fit itself is
consistent but not efficient (a Kalman-filter likelihood would be), so the errors are honest, not the smallest.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..learn.dataset import Dataset, Sampling, Trajectories, make_dataset
from ..system import System
from ..uncertainty.sde import SDEScheme, for_integrator

__all__ = ["DeclaredNoise", "declared_noise", "noisy_dataset", "residual_covariance", "sde_rollout"]

_STREAM = 0x5D  # folded into key(seed): the noise's stream, apart from the kit's draws of controls and starts


@dataclasses.dataclass(frozen=True, eq=False)
class DeclaredNoise:
    """A spec's declared noise: ``process`` the diffusion sigma per state, ``observation`` the readings' standard
    deviation per state ((n,) float64 arrays, 0 where a state has none)."""

    process: np.ndarray
    observation: np.ndarray

    def record(self) -> dict[str, list[float]]:
        return {"process": self.process.tolist(), "observation": self.observation.tolist()}


def declared_noise(system: System) -> DeclaredNoise | None:
    """The noise ``system``'s spec declares (schema 3 ``noise:``), or None when it declares none (every schema 1 and
    2 spec, and a schema 3 spec without ``noise:`` or with only zero levels)."""
    n = system.n_states
    levels = [np.asarray(getattr(system, name, ()) or np.zeros(n), np.float64)
              for name in ("process_noise", "observation_noise")]
    if not any(np.any(v > 0) for v in levels):
        return None
    for name, v in zip(("process_noise", "observation_noise"), levels):
        if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any(v < 0):
            raise ValueError(f"{system.name}: {name} must be {n} finite levels >= 0, got {v.tolist()}")
    return DeclaredNoise(*levels)


def sde_rollout(scheme: SDEScheme, f: Any, x0: Any, t0: Any, h: Any, controls: Any, sigma: Any, dw: Any) -> Any:
    """(N + 1, n): the SDE from ``x0`` on the grid t_k = t0 + k h, the control linear from controls[k] to
    controls[k + 1] on interval k, the Wiener increments ``dw`` (N, n) given."""

    def body(x, inputs):
        k, u0, u1, w = inputs
        tk = t0 + k * h
        f_k = lambda y, _, t: f(y, jnp.where(t == tk, u0, u1), t)  # noqa: E731  (u_k at t_k, u_{k+1} at t_k + h)
        x = scheme.step(f_k, x, tk, h, None, sigma, w)
        return x, x

    steps = jnp.arange(controls.shape[0] - 1, dtype=x0.dtype)
    _, xs = jax.lax.scan(body, x0, (steps, controls[:-1], controls[1:], dw))
    return jnp.concatenate([x0[None], xs])


@functools.partial(jax.jit, static_argnums=(0, 1, 5))  # the step a constant, as in the kit's program
def _noisy_states(system: System, scheme: SDEScheme, key, controls, starts, horizon, sigma, std):
    """(B, N + 1, n): the SDE's paths from ``starts`` under ``controls`` (B, N + 1, m), observed with noise."""
    n_batch, n_nodes, n = starts.shape[0], controls.shape[1], starts.shape[1]
    h = horizon / (n_nodes - 1)
    params = system.default_params(jnp.float64)
    f = lambda x, u, t: system.dynamics(x, u, t, params)  # noqa: E731
    k_dw, k_obs = jax.random.split(key)
    dw = jnp.sqrt(h) * jax.random.normal(k_dw, (n_batch, n_nodes - 1, n), jnp.float64)
    xs = jax.vmap(lambda x0, us, w: sde_rollout(scheme, f, x0, 0.0, h, us, sigma, w))(starts, controls, dw)
    return xs + std * jax.random.normal(k_obs, xs.shape, jnp.float64)


def noisy_dataset(system: System, sampling: Sampling, noise: DeclaredNoise, *,
                  trajectories: tuple[int, int, int] = (10, 3, 3), seed: int = 0, around: Any = None) -> Dataset:
    """:func:`~myriad.runtime.learn.dataset.make_dataset`'s trajectories (same controls and starts) under the
    declared ``noise`` (the module docstring). ``sampling.noise`` must be 0: the declared observation noise replaces
    the kit's fraction of the range. ``ValueError``: a sampling integrator with no stochastic scheme (process noise
    needs Euler or Heun), non-finite paths."""
    if sampling.noise:
        raise ValueError(f"{system.name}: the spec declares its noise (schema 3 `noise:`), so the kit's observation "
                         f"noise (noise={sampling.noise}) would come on top: leave it at 0")
    scheme = for_integrator(sampling.integrator)  # refuses midpoint, RK4, adaptive with the fix
    clean = make_dataset(system, sampling, trajectories=trajectories, seed=seed, around=around)
    splits = ("train", "validation", "test")
    us = np.concatenate([getattr(clean, s).controls for s in splits])
    x0 = np.concatenate([getattr(clean, s).states[:, 0] for s in splits])
    key = jax.random.fold_in(jax.random.key(seed), _STREAM)
    xs = np.asarray(_noisy_states(system, scheme, key, jnp.asarray(us), jnp.asarray(x0), float(system.horizon),
                                  jnp.asarray(noise.process), jnp.asarray(noise.observation)))
    if not np.all(np.isfinite(xs)):
        bad = int(np.sum(~np.all(np.isfinite(xs), axis=(1, 2))))
        raise ValueError(f"{system.name}: {bad} of {xs.shape[0]} trajectories under the declared process noise are "
                         f"not finite: the noise drove the dynamics to blow up; try another seed or more intervals")
    edges = np.cumsum([getattr(clean, s).states.shape[0] for s in splits])[:-1]
    parts = [Trajectories(u, x) for u, x in zip(np.split(us, edges), np.split(xs, edges))]
    return dataclasses.replace(clean, **dict(zip(splits, parts)))


@functools.partial(jax.jit, static_argnames=("model", "scheme"))
def residual_covariance(theta, spec, times, starts, controls, weights, sigma, std, *, model, scheme):
    """(B, M, M), M = (N + 1) n: the covariance of each trajectory's weighted residuals w (x~ - y) under the
    declared noise, linearised about the model's paths from ``starts`` at ``theta`` (the module docstring)."""
    f = lambda x, u, t: model.vector_field(x, u, t, theta, spec)  # noqa: E731
    t0, h = times[0], times[1] - times[0]
    n_steps, n = controls.shape[1] - 1, starts.shape[1]

    def one(x0, us, w):
        path = lambda dw: sde_rollout(scheme, f, x0, t0, h, us, sigma, dw).ravel()  # noqa: E731
        g = jax.jacfwd(path)(jnp.zeros((n_steps, n), x0.dtype)).reshape(-1, n_steps * n)
        omega = h * g @ g.T + jnp.diag(jnp.tile(std * std, n_steps + 1))
        wv = w.ravel()
        return wv[:, None] * omega * wv[None, :]

    return jax.vmap(one)(starts, controls, weights)
