"""The ``rgb_array`` frame of an episode: state and control traces drawn with matplotlib's Agg canvas.

A ``Figure`` on its own ``FigureCanvasAgg`` (not pyplot): no global figure state, no display, safe to call from any
thread or process, and the figure is freed when the function returns.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["draw_traces"]


def draw_traces(system, times, states, controls, size: tuple[int, int] = (640, 480)) -> np.ndarray:
    """An (height, width, 3) uint8 frame: one panel per state and per control over [0, T], with the spec's bounds and
    required final values; ``times`` (K + 1,) and ``states`` (K + 1, n) reached so far, ``controls`` (K, m) applied
    on [t_k, t_{k+1}] (drawn as the steps they are), ``size`` (width, height) in pixels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    width, height = size
    dpi = 80
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    n, m = system.n_states, system.n_controls
    cols = 2 if n + m > 3 else 1
    rows = math.ceil((n + m) / cols)
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True).ravel()
    t, xs, us = np.asarray(times), np.asarray(states), np.asarray(controls)
    a = system.arrays()
    T = float(system.horizon)
    for i, ax in enumerate(axes[: n + m]):
        if i < n:
            ax.plot(t, xs[:, i], color="C0")
            name, lo, hi = system.state_names[i], a["x_lower"][i], a["x_upper"][i]
            if system.x_final[i] is not None:
                ax.plot([T], [system.x_final[i]], "o", color="C3", markersize=4)
        else:
            j = i - n
            if us.shape[0]:
                ax.step(t[: us.shape[0] + 1], np.append(us[:, j], us[-1, j]), where="post", color="C1")
            name, lo, hi = system.control_names[j], a["u_lower"][j], a["u_upper"][j]
        for b in (lo, hi):
            if np.isfinite(b):
                ax.axhline(b, color="0.6", linewidth=0.8, linestyle="--")
        ax.set_ylabel(name, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xlim(0.0, T)
    for ax in axes[n + m:]:
        ax.set_visible(False)
    fig.suptitle(f"{system.title}: t = {t[-1]:.3g} of {T:g}", fontsize=9)
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.07, top=0.92, hspace=0.35, wspace=0.3)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
