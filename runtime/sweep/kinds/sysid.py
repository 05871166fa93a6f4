"""``sysid``: one system-identification experiment (:func:`~myriad.runtime.sysid.run.run_sysid`) with the task's
seed: sample trajectories, fit, plan on the learned model, judge the plan on the true system.

    --method sysid                                   # parametric, least squares
    --method node=sysid:model=node,epochs=200,hidden=[32,32]
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from ...system import System
from .base import AbstractKind, Outcome, refuse_unsupported

__all__ = ["Sysid", "SysidSettings"]


@dataclasses.dataclass(frozen=True)
class SysidSettings:
    """The options of ``myriad sysid`` (its ``--seed`` is the task's seed).

    Attributes:
        model: ``parametric`` (the spec's learnable parameters) or ``node`` (a Neural ODE).
        method: ``least_squares`` (parametric default) or ``adam`` (Neural ODE default).
        trajectories: training trajectories per dataset.
        rounds: datasets in sequence (default: 3 for a Neural ODE, 1 for a parametric model).
        noise: observation noise, a fraction of the state range.
        epochs: adam's most epochs (default 1000).
        hidden, activation: the Neural ODE's network.
    """

    model: str = "parametric"
    method: str | None = None
    trajectories: int = 10
    rounds: int | None = None
    noise: float = 0.0
    epochs: int | None = None
    hidden: tuple[int, ...] = (100, 100)
    activation: str = "tanh"

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(self.hidden) if isinstance(self.hidden, (list, tuple))
                           else self.hidden)
        config(self, seed=0)  # SysidConfig's own checks, without a system


def config(s: SysidSettings, seed: int):
    """The :class:`~myriad.runtime.sysid.run.SysidConfig` of these settings (``ValueError`` if they are bad)."""
    from ...sysid.fit import FitConfig
    from ...sysid.run import SysidConfig, node_fit_config

    if s.epochs is not None and (isinstance(s.epochs, bool) or not isinstance(s.epochs, int) or s.epochs < 1):
        raise ValueError(f"sysid: epochs must be an integer >= 1, got {s.epochs!r}")
    if not (isinstance(s.hidden, tuple) and s.hidden and all(isinstance(w, int) and w >= 1 for w in s.hidden)):
        raise ValueError(f"sysid: hidden must be a list of layer widths >= 1, got {s.hidden!r}")
    fit = None
    if s.epochs is not None:
        fit = node_fit_config(s.epochs) if s.model == "node" else FitConfig(epochs=s.epochs)
    try:
        return SysidConfig(model=s.model, method=s.method, trajectories=s.trajectories, rounds=s.rounds,
                           noise=s.noise, seed=seed, hidden=s.hidden, activation=s.activation, fit=fit)
    except TypeError as exc:  # a comparison of a string with a number inside SysidConfig's checks
        raise ValueError(f"sysid: {exc}") from None


class Sysid(AbstractKind):
    """A success is a fit that finished and a plan that converged (``SysidReport.converged``)."""

    name: ClassVar[str] = "sysid"
    Settings: ClassVar[type] = SysidSettings
    columns: ClassVar[tuple[str, ...]] = ("achieved_cost", "optimal_cost", "relative_gap", "fit_status")

    def check_system(self, system: System, settings: dict[str, Any]) -> None:
        refuse_unsupported(system, "sysid (its datasets and plans)")
        if settings["model"] == "parametric" and not system.learnable:
            raise ValueError(f"sysid: {system.name} declares no learnable parameters; use model=node")

    def run(self, system: System, settings: dict[str, Any], seed: int) -> Outcome:
        from ...sysid.run import run_sysid

        report = run_sysid(system, config(SysidSettings(**settings), seed), progress=False)
        fields = report.record()
        del fields["system"], fields["seed"]  # the task's own fields
        fields["fit_method"] = fields.pop("method")
        message = fields.pop("message")  # the reason of a failure, else the plan's
        return Outcome(success=bool(report.converged), message=message, fields=fields)
