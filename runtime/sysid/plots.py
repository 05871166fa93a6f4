"""What a person looks at after a fit besides the loss curve (:mod:`~myriad.runtime.learn.plots`): learned against
true trajectories on held-out controls, and (for two-state systems) the learned against the true vector field. PNG
files, labelled with the spec's names."""

from __future__ import annotations

import math
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..plotting import pyplot, save_png

__all__ = ["plot_trajectories", "plot_vector_field"]


def _save(fig, title: str, path: str | os.PathLike) -> str:
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_png(fig, path)
    return os.fspath(path)


def plot_trajectories(system, times: Any, observed: Any, predicted: Any, path: str | os.PathLike, title: str,
                      max_trajectories: int = 3) -> str:
    """Observed (true system) against predicted (learned model, rolled out from the same start with the same
    controls) states, one panel per state, for a few held-out trajectories."""
    plt = pyplot()
    t = np.asarray(times)
    obs, pred = np.asarray(observed), np.asarray(predicted)
    n = system.n_states
    cols = 2 if n > 2 else 1
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 2.2 * rows + 0.8), squeeze=False, sharex=True)
    for i in range(n):
        ax = axes[i // cols][i % cols]
        for b in range(min(max_trajectories, obs.shape[0])):
            ax.plot(t, obs[b, :, i], color=f"C{b}", lw=1.6, label="true" if b == 0 else None)
            ax.plot(t, pred[b, :, i], color=f"C{b}", lw=1.2, ls="--", label="learned" if b == 0 else None)
        name, desc = system.state_names[i], system.state_descriptions[i]
        ax.set_ylabel(f"{name}: {desc}"[:48] if desc else name, fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        if i == 0:
            ax.legend(frameon=False, fontsize=7)
    for i in range(n, rows * cols):
        axes[i // cols][i % cols].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("t", fontsize=8)
    return _save(fig, title, path)


def plot_vector_field(system, learned, times: Any, states: Any, controls: Any, path: str | os.PathLike,
                      title: str, grid: int = 15) -> str:
    """For a two-state system: the true and the ``learned`` vector fields over the neighbourhood of a trajectory
    (``times`` (K,), ``states`` (K, 2), ``controls`` (K, m); the optimal one), each point under the control of the
    trajectory's point nearest to it (the published figure)."""
    if system.n_states != 2:
        raise ValueError(f"{system.name}: a vector-field plot needs two states, it has {system.n_states}")
    plt = pyplot()
    t, xs, us = np.asarray(times), np.asarray(states), np.asarray(controls)
    lo, hi = xs.min(axis=0), xs.max(axis=0)
    pad = 0.15 * np.maximum(hi - lo, 1e-3)
    g0, g1 = np.meshgrid(np.linspace(lo[0] - pad[0], hi[0] + pad[0], grid),
                         np.linspace(lo[1] - pad[1], hi[1] + pad[1], grid))
    points = np.stack([g0.ravel(), g1.ravel()], axis=1)
    # Each grid point takes the control (and time) of the trajectory point nearest to it in state space.
    nearest = np.argmin(((points[:, None, :] - xs[None, :, :]) ** 2).sum(-1), axis=1)
    u_at, t_at = us[nearest], t[nearest]

    def field(sys):
        params = sys.default_params()
        f = jax.vmap(lambda x, u, s: sys.dynamics(x, u, s, params))
        return np.asarray(f(jnp.asarray(points), jnp.asarray(u_at), jnp.asarray(t_at)))

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharex=True, sharey=True)
    for ax, sys, name in ((axes[0], system, "true"), (axes[1], learned, "learned")):
        v = field(sys)
        ax.quiver(points[:, 0], points[:, 1], v[:, 0], v[:, 1], color="0.35", angles="xy")
        ax.plot(xs[:, 0], xs[:, 1], color="C3", lw=1.8, label="optimal trajectory")
        ax.set_title(f"{name} dynamics", fontsize=9)
        ax.set_xlabel(system.state_names[0])
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(system.state_names[1])
    axes[0].legend(frameon=False, fontsize=7)
    return _save(fig, title, path)
