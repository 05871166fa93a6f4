"""``mpc``: one closed-loop episode of the receding-horizon policy (:mod:`myriad.runtime.rl.mpc`) in the system's
reference environment, scored against the shipped reference scores. The task's seed draws the signs of the
planner's parameter errors (``mismatch`` > 0) and the observation noise (``obs_noise`` > 0); on a schema 3 spec that
declares its uncertainty, the true parameters drawn from their distributions and the declared process and
observation noise instead (:func:`~myriad.runtime.rl.mpc.perturbed`).
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
        mismatch: the planner's uncertain parameters off by +-this fraction (``mismatched_params``); 0: nominal. On a
            spec that declares uncertain parameters (with ``declared``), > 0 draws the true ones from their
            declared distributions instead (the planner keeps the nominal values).
        obs_noise: observation noise per unit of state scale; 0: none. On a spec that declares its noise (with
            ``declared``), > 0 runs the episode under the declared process and observation noise instead.
        declared: use a schema 3 spec's declared uncertainty for ``mismatch`` and ``obs_noise`` (false: the
            perturbations above on every spec). No effect on a spec that declares none.
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
    declared: bool = True

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
        if not isinstance(self.declared, bool):
            raise ValueError(f"declared must be true or false, got {self.declared!r}")
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
        from ...rl.mpc import MPC, perturbed
        from ...rl.reference import normalized_score, reference_env, reference_scores

        s = self.config(settings, seed)
        env, params, obs_noise = perturbed(reference_env(system), s.mismatch, s.obs_noise, s.seed, s.declared)
        mpc = MPC(env, params, replan_every=s.replan_every, terminal=s.terminal, solver=s.solver())
        ep = mpc.run(env.default_params(), obs_noise=obs_noise, seed=s.seed)
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
        if env.stochastic:  # the declared uncertainty played (the records of other specs keep their fields)
            fields["declared"] = {"parameters": env.randomized, "noise": obs_noise == 0 and s.obs_noise > 0,
                                  "theta": None if ep.theta is None else dict(zip(system.uncertain_params,
                                                                                  ep.theta.tolist()))}
        ok = ep.failures == 0 and math.isfinite(ep.cost)
        message = ("" if ok else f"{ep.failures} of {ep.replans} re-plans failed (the previous plan was kept)"
                   if ep.failures else f"the episode's cost is not finite ({ep.cost})")
        return Outcome(success=ok, message=message, fields=fields)
