"""The learners' figures (PNG, atomic): the loss curve every learner draws (a history's two loss columns against its
steps, log scale), and the training figure of an imitation (the published Figure 3: plans over the course of training
drawn with low alpha, the expert on top)."""

from __future__ import annotations

import os
from typing import Any, Sequence

import numpy as np

from ..plotting import finish_loss_figure, pyplot, save_png

__all__ = ["plot_loss", "plot_training"]


def plot_loss(history: Sequence[tuple[int, float, float]], path: str | os.PathLike, title: str, *,
              labels: tuple[str, str] = ("training", "validation"), xlabel: str = "epoch",
              ylabel: str | None = "trajectory loss (mean squared error)", floor: float | None = None,
              second_alpha: float | None = None) -> str:
    """``history`` rows ``(step, first, second)``: ``first`` against ``step``, and ``second`` too when it has a
    positive finite value (a validation loss; a planner's residual, 0 when it has none), drawn ``second_alpha``
    lighter. ``floor``: draw values below it at it (an exact 0 stays on a log axis)."""
    plt = pyplot()
    h = np.asarray(history, dtype=float).reshape(-1, 3)
    first, second = (h[:, i] if floor is None else np.maximum(h[:, i], floor) for i in (1, 2))
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.semilogy(h[:, 0], first, label=labels[0], color="C0")
    if np.any(np.isfinite(h[:, 2]) & (h[:, 2] > 0)):
        ax.semilogy(h[:, 0], second, label=labels[1], color="C1", alpha=second_alpha)
    ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    return finish_loss_figure(fig, ax, title, path)


def plot_training(system: Any, times: Any, snapshots: Sequence[tuple[int, Any, Any]], expert_controls: Any,
                  expert_states: Any, path: str | os.PathLike, title: str) -> str:
    """One panel per control and per state: every stored plan (controls, and its states under the model) in a
    colour running from early (light) to late (dark) training at alpha 0.25, the expert in black on top."""
    plt = pyplot()
    t = np.asarray(times)
    names = [f"control {n}" for n in system.control_names] + [f"state {n}" for n in system.state_names]
    panels = len(names)
    fig, axes = plt.subplots(panels, 1, figsize=(7.0, 1.9 * panels + 0.9), squeeze=False, sharex=True)
    cmap = plt.get_cmap("viridis")
    last = max((s[0] for s in snapshots), default=1) or 1
    for it, controls, states in snapshots:
        series = np.concatenate([np.asarray(controls), np.asarray(states)], axis=1)
        for i in range(panels):
            axes[i][0].plot(t, series[:, i], color=cmap(0.9 * it / last), alpha=0.25, lw=1.0)
    expert = np.concatenate([np.asarray(expert_controls), np.asarray(expert_states)], axis=1)
    for i, name in enumerate(names):
        ax = axes[i][0]
        ax.plot(t, expert[:, i], color="black", lw=1.6, label="expert (true optimum)" if i == 0 else None)
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    axes[0][0].legend(frameon=False, fontsize=7, loc="best")
    axes[-1][0].set_xlabel("t", fontsize=8)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, last / 0.9))
    fig.colorbar(sm, ax=[a[0] for a in axes], label="iteration", fraction=0.03, pad=0.02)
    fig.suptitle(title, fontsize=10)
    save_png(fig, path)
    return os.fspath(path)
