"""The loss curve every learner draws: a history's two loss columns against its steps, log scale (PNG, atomic)."""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from ..plotting import finish_loss_figure, pyplot

__all__ = ["plot_loss"]


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
