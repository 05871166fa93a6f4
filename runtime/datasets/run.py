"""``myriad dataset``'s configuration and work: collect the episodes of a policy, write them as a dataset."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

from ..configs import FieldError
from .collect import Perturbation, collect
from .policies import POLICIES, PolicySettings
from .storage import FORMATS, write_dataset

__all__ = ["DatasetConfig", "run_dataset"]


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """A dataset of demonstrations (README.md in this folder).

    Attributes:
        policy: optimal (the env's optimum per episode, open loop), noisy (optimal plus action noise), mpc
            (receding-horizon re-planning) or random (uniform actions).
        episodes: how many episodes.
        seed: every draw's seed (start states, parameters, action noise, random actions).
        format: minari (a Minari dataset under --out) or npz (one file under --out).
        name: the dataset's name in its id myriad/SYSTEM/NAME-v0 (default: the policy's).
        start_noise: each start state x0 + start_noise * s * U(-1, 1) per state, s its nominal scale (0: x0).
        param_noise: each uncertain parameter times 1 + param_noise * U(-1, 1) per episode (0: the spec's).
        noise: noisy: the action noise's standard deviation, a fraction of each action's range.
        replan_every: mpc: steps between re-plans.
        env: the environment's options as a JSON object of EnvOptions fields, e.g. {"steps": 50, "max_steps": 40}.
    """

    policy: Literal["optimal", "noisy", "mpc", "random"] = "optimal"
    episodes: int = 10
    seed: int = 0
    format: Literal["minari", "npz"] = "minari"
    name: str | None = None
    start_noise: float = 0.0
    param_noise: float = 0.0
    noise: float = 0.1
    replan_every: int = 10
    env: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.policy not in POLICIES:
            raise FieldError(f"policy must be one of {', '.join(POLICIES)}, got {self.policy!r}", "policy")
        if self.format not in FORMATS:
            raise FieldError(f"format must be one of {', '.join(FORMATS)}, got {self.format!r}", "format")
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise FieldError(f"episodes must be a positive integer, got {self.episodes!r}", "episodes")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**32:
            raise FieldError(f"seed must be an integer in [0, 2^32), got {self.seed!r}", "seed")
        if self.name is not None and not _plain_name(self.name):
            raise FieldError(f"name must be letters, digits, '_' or '.', not empty, got {self.name!r}", "name")
        for field, make in (("start_noise", lambda v: Perturbation(start=v)),
                            ("param_noise", lambda v: Perturbation(params=v)),
                            ("noise", lambda v: PolicySettings(noise=v)),
                            ("replan_every", lambda v: PolicySettings(replan_every=v))):
            try:
                make(getattr(self, field))
            except ValueError as exc:
                raise FieldError(f"{field}: {exc}", field) from None
        try:
            self.options()
        except (TypeError, ValueError) as exc:
            raise FieldError(f"env: {exc}", "env") from None

    def options(self):
        """The :class:`~myriad.runtime.rl.env.EnvOptions` of ``env``."""
        from ..rl.env import EnvOptions

        if not isinstance(self.env, dict):
            raise ValueError(f"a JSON object of EnvOptions fields, got {self.env!r}")
        if "start_noise" in self.env:
            raise ValueError("start_noise is --start-noise")
        return EnvOptions(**self.env)


def _plain_name(text: str) -> bool:
    return bool(text) and all(c.isalnum() or c in "_." for c in text) and text.isascii()


def run_dataset(target: Any, config: DatasetConfig, out: str | Path) -> tuple[Path, Any]:
    """Collect ``config.episodes`` episodes of ``config.policy`` on ``target`` and write them under ``out``:
    ``(the dataset's path, the episodes)``."""
    episodes = collect(target, config.policy, config.episodes, config.seed, options=config.options(),
                       perturb=Perturbation(start=config.start_noise, params=config.param_noise),
                       settings=PolicySettings(noise=config.noise, replan_every=config.replan_every))
    return write_dataset(episodes, out, config.name, config.format, target=episodes.info["target"]), episodes
