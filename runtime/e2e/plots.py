"""The training figure (the published Figure 3: plans over the course of training drawn with low alpha, the expert
on top), a PNG written atomically."""

from __future__ import annotations

import os
from typing import Any, Sequence

import numpy as np

from ..plotting import pyplot, save_png

__all__ = ["plot_training"]


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
