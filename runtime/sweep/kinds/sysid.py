"""``sysid``: one system-identification experiment (:func:`~myriad.runtime.sysid.run.run_sysid`; the settings are
:class:`~myriad.runtime.sysid.run.SysidConfig`'s fields) with the task's seed. On a schema 3 spec that declares its
noise the data get that noise (``declared_noise``, default true), not the ``noise`` setting's.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from ...learn.dataset import sampling_scales
from ...sysid.run import SysidConfig, data_noise
from ...system import System
from .base import AbstractKind, Outcome, refuse_unsupported

__all__ = ["Sysid"]


class Sysid(AbstractKind):
    """A success is an experiment that passed: the fit finished, the plan converged, and the parameters and the plan's
    gap are within the config's bounds (:func:`~myriad.runtime.sysid.run.failed`)."""

    name: ClassVar[str] = "sysid"
    Settings: ClassVar[type] = SysidConfig
    columns: ClassVar[tuple[str, ...]] = ("achieved_cost", "optimal_cost", "relative_gap", "fit_status")

    def check_system(self, system: System, settings: dict[str, Any]) -> None:
        refuse_unsupported(system, "sysid (its datasets and plans)")
        if settings["model"] == "parametric" and not system.learnable:
            raise ValueError(f"sysid: {system.name} declares no learnable parameters; use model=node")
        config = self.config(settings, seed=0)
        data_noise(system, config)  # the kit's noise on top of a spec's declared noise is refused before any work
        sampling_scales(system, dataclasses.replace(config.sampling, noise=config.noise))  # the bounds it needs

    def run(self, system: System, settings: dict[str, Any], seed: int) -> Outcome:
        from ...sysid.run import failed, run_sysid

        report = run_sysid(system, self.config(settings, seed), progress=False)
        fields = report.record()
        del fields["system"], fields["seed"]  # the task's own fields
        fields["fit_method"] = fields.pop("method")
        message = fields.pop("message")  # the reason of a failure, else the plan's
        return Outcome(success=failed(report) is None, message=message, fields=fields)
