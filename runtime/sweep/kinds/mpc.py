"""``mpc``: one closed-loop episode of the receding-horizon policy (:mod:`myriad.runtime.rl.mpc`) in the system's
reference environment, scored against the shipped reference scores. The task's seed draws the signs of the
planner's parameter errors (``mismatch`` > 0) and the observation noise (``obs_noise`` > 0).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

from ...system import System
from .base import AbstractKind, Outcome, refuse_unsupported

__all__ = ["Mpc", "MpcConfig"]


@dataclasses.dataclass(frozen=True)
class MpcConfig:
    """One closed-loop episode of :class:`~myriad.runtime.rl.mpc.MPC` in a system's reference environment.

    Attributes:
        replan_every: re-plan every this many env steps (1: every step).
        mismatch: the planner's uncertain parameters off by +-this fraction (``mismatched_params``); 0: nominal.
        obs_noise: observation noise per unit of state scale; 0: none.
        terminal: ``penalty`` (the env's terminal cost) or ``constraint`` (the published final-value rows).
        solver_options: keyword arguments of :class:`~myriad.runtime.solvers.Ipopt` (default ``{"tol": 1e-8}``).
        seed: draws the parameter errors' signs and the observation noise (a sweep's task seed).
    """

    replan_every: int = 10
    mismatch: float = 0.0
    obs_noise: float = 0.0
    terminal: str = "penalty"
    solver_options: dict = dataclasses.field(default_factory=dict)
    seed: int = 0

    def __post_init__(self):
        for name, low in (("replan_every", 1), ("seed", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
        for name in ("mismatch", "obs_noise"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if self.terminal not in ("penalty", "constraint"):
            raise ValueError(f"terminal must be penalty or constraint, got {self.terminal!r}")
        if not isinstance(self.solver_options, dict):
            raise ValueError(f"solver_options must be a mapping, got {self.solver_options!r}")
        self.solver()

    def solver(self):
        """The planner's IPOPT."""
        from ...solvers import Ipopt

        try:
            return Ipopt(**{"tol": 1e-8, **self.solver_options})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"solver_options for ipopt: {exc}") from None


class Mpc(AbstractKind):
    """A success is an episode in which every re-plan converged (a failed one keeps the previous plan)."""

    name: ClassVar[str] = "mpc"
    Settings: ClassVar[type] = MpcConfig
    columns: ClassVar[tuple[str, ...]] = ("cost", "normalized_score", "relative_gap", "failures")

    def check_system(self, system: System, settings: dict[str, Any]) -> None:
        refuse_unsupported(system, "mpc (the RL environment's fixed-horizon episodes)")

    def run(self, system: System, settings: dict[str, Any], seed: int) -> Outcome:
        from ...rl.mpc import MPC, mismatched_params
        from ...rl.reference import normalized_score, reference_env, reference_scores

        s = self.config(settings, seed)
        env = reference_env(system)
        params = mismatched_params(env, s.mismatch, s.seed) if s.mismatch > 0 else None
        mpc = MPC(env, params, replan_every=s.replan_every, terminal=s.terminal, solver=s.solver())
        ep = mpc.run(env.default_params(), obs_noise=s.obs_noise, seed=s.seed)
        record = reference_scores()["systems"].get(system.name)
        # A spec that does not ship has no reference scores: its episode is reported without a score.
        optimum = record["optimal"]["cost"] if record and record["spec_sha256"] == system.spec_sha256 else None
        fields = {
            "cost": ep.cost,
            "normalized_score": normalized_score(system, ep.cost) if optimum is not None else None,
            "optimal_cost": optimum,
            "relative_gap": (ep.cost - optimum) / abs(optimum) if optimum else None,
            "penalty": ep.penalty,
            "replans": ep.replans,
            "failures": ep.failures,
            "iterations": ep.iterations,
            "solve_seconds": ep.solve_seconds,
            "compile_seconds": ep.compile_seconds,
        }
        ok = ep.failures == 0 and math.isfinite(ep.cost)
        message = ("" if ok else f"{ep.failures} of {ep.replans} re-plans failed (the previous plan was kept)"
                   if ep.failures else f"the episode's cost is not finite ({ep.cost})")
        return Outcome(success=ok, message=message, fields=fields)
