"""Figures as PNG files: a solution's state and control trajectories, labelled from the spec, and the helpers every
learner's figures share (the Agg backend, atomic writes, the loss-curve finish)."""

from __future__ import annotations

import math
import os

import numpy as np

__all__ = ["finish_loss_figure", "plot_solution", "pyplot", "save_png"]


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only)."""
    import matplotlib

    matplotlib.use("Agg", force=True)  # files only: never needs a display
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path) -> None:
    """Write the PNG atomically (a reader never sees half a file) and free the figure."""
    from .atomic import atomic_open

    try:
        with atomic_open(path) as f:
            fig.savefig(f, format="png", dpi=110)
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def finish_loss_figure(fig, ax, title: str, path) -> str:
    """Title, log grid and legend of a loss curve; written atomically; the path written."""
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(frameon=False)
    fig.tight_layout()
    save_png(fig, path)
    return os.fspath(path)


def _label(name: str, description: str, units: str) -> str:
    text = name if not description else f"{name}: {description}"
    text = text if len(text) <= 48 else text[:45] + "..."
    return f"{text} [{units}]" if units else text


def plot_solution(solution, path: str | os.PathLike, system=None) -> str:
    """Write one panel per state and per control (controls drawn as the piecewise-linear signal they are); the path
    written.

    Args:
        solution: a :class:`~myriad.runtime.solve.Solution` (anything with ``times``, ``states``, ``controls``,
            ``system``, ``cost``, ``transcription``, ``solver`` and ``converged``).
        path: the PNG to write.
        system: the system; looked up by ``solution.system`` when omitted.
    """
    plt = pyplot()
    if system is None:
        from .loader import load

        system = load(solution.system)
    n, m = system.n_states, system.n_controls
    panels = n + m
    cols = 2 if panels > 3 else 1
    rows = math.ceil(panels / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 2.1 * rows + 0.8), squeeze=False, sharex=True)
    t = np.asarray(solution.times)
    xs, us = np.asarray(solution.states), np.asarray(solution.controls)
    tu = t if us.shape[0] == t.shape[0] else np.linspace(t[0], t[-1], us.shape[0])
    for i in range(panels):
        ax = axes[i // cols][i % cols]
        if i < n:
            ax.plot(t, xs[:, i], color="C0", lw=1.6)
            lo, hi = system.x_lower[i], system.x_upper[i]
            target = system.x_final[i]
            if target is not None:
                ax.plot([t[-1]], [target], "o", mfc="none", color="C3",
                        label=f"required {system.state_names[i]}(T) = {target:g}")
                ax.legend(loc="best", fontsize=7, frameon=False)
            ax.set_ylabel(_label(system.state_names[i], system.state_descriptions[i], system.state_units[i]),
                          fontsize=8)
        else:
            j = i - n
            ax.plot(tu, us[:, j], color="C1", lw=1.6)
            lo, hi = system.u_lower[j], system.u_upper[j]
            ax.set_ylabel(_label(system.control_names[j], system.control_descriptions[j], system.control_units[j]),
                          fontsize=8)
        for b in (lo, hi):
            if math.isfinite(b):
                ax.axhline(b, color="0.6", lw=0.8, ls="--")
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for i in range(panels, rows * cols):
        axes[i // cols][i % cols].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("t", fontsize=8)
    status = "converged" if solution.converged else "NOT converged"
    fig.suptitle(f"{system.title}: {solution.transcription} + {solution.solver}, cost {solution.cost:.6g} ({status})",
                 fontsize=10)
    fig.tight_layout()
    save_png(fig, path)
    return os.fspath(path)
