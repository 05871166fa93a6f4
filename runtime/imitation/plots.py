"""The imitation command's figures: the fit's loss curve and the policy's nominal episode beside the optimum's."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..learn.plots import plot_loss
from ..plotting import pyplot, save_png
from ..rl.env import play
from ..rl.reference import reference_env, reference_record
from .rollout import rollout

__all__ = ["plot_report"]


def plot_report(report, folder: Path) -> list[str]:
    """``loss.png`` (the behaviour-cloning fit, or the end-to-end learner's iterations) and ``episode.png`` (states
    and controls of the policy's nominal episode, solid, and of the optimiser's controls played open loop, dashed,
    where the reference scores have them)."""
    folder.mkdir(parents=True, exist_ok=True)
    name = report.system.name
    if report.e2e is not None:  # the end-to-end learner's imitation loss and its planner's KKT residual
        paths = [plot_loss(report.e2e.history, folder / "loss.png", f"{name}: end-to-end learning", xlabel="iteration",
                           labels=("imitation loss", "planner KKT residual"), ylabel=None, floor=1e-300)]
    else:
        paths = [plot_loss(report.fit_history, folder / "loss.png", f"{name}: behaviour cloning",
                           labels=("training", "held-out"), ylabel="action loss (mean squared error)")]
    env = reference_env(report.system)
    data = jax.tree.map(jnp.asarray, env.default_params())
    ep = rollout(env, report.policy, report.net, data, jax.random.PRNGKey(0), jnp.asarray(0.0))
    stored = reference_record(report.system)["optimal"].get("controls")  # what the normalised score measured
    optimum = None if stored is None else play(env, np.asarray(stored, np.float64), data)
    times = np.linspace(0.0, float(report.system.horizon), env.options.steps + 1)
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True)
    for i, label in enumerate(report.system.state_names):
        top.plot(times, np.asarray(ep.states)[:, i], color=f"C{i}", label=label)
        if optimum is not None:
            top.plot(times, np.asarray(optimum.states)[:, i], color=f"C{i}", ls="--")
    for j, label in enumerate(report.system.control_names):
        bottom.step(times[:-1], np.asarray(ep.controls)[:, j], where="post", color=f"C{j}", label=label)
        if stored is not None:
            bottom.step(times[:-1], np.asarray(stored)[:, j], where="post", color=f"C{j}", ls="--")
    top.set_ylabel("state")
    bottom.set_ylabel("control")
    bottom.set_xlabel("t")
    top.legend(fontsize="small")
    bottom.legend(fontsize="small")
    top.set_title(f"{name}: {report.config.method} policy (solid), optimum (dashed)")
    save_png(fig, folder / "episode.png")
    return [*paths, str(folder / "episode.png")]
