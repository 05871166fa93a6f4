"""What an end-to-end run learns and how (a frozen, checked configuration)."""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..learn.identity import describe, digest, optimizer_identity
from ..learn.models import MODELS as _REGISTRY
from ..learn.models import network_error
from ..solvers.adjoint import Implicit, Unrolled, adjoint
from ..solvers.extragradient import Extragradient
from ..solvers.interior_point import InteriorPoint

__all__ = ["E2EConfig", "INITS", "LOSSES", "MODELS", "ON_FAILURE"]

MODELS = tuple(_REGISTRY)  # the learning kit's model names (one spelling each)
INITS = ("guess", "sysid")
LOSSES = ("controls", "states", "both")
ON_FAILURE = ("skip", "unrolled", "backtrack")


def _int(v: Any, low: int) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= low


def _pairs(value: Any) -> tuple[tuple[str, float], ...]:
    """``cost_guess`` as ``((name, value), ...)`` from a mapping or a list of pairs (JSON gives either)."""
    items = value.items() if isinstance(value, Mapping) else value
    try:
        pairs = tuple((k, v) for k, v in items) if not isinstance(value, str) else None
    except (TypeError, ValueError):  # not iterable, or items that are not pairs
        pairs = None
    if pairs is None or not all(isinstance(k, str) and isinstance(v, numbers.Real) and not isinstance(v, bool)
                                and math.isfinite(v) for k, v in pairs):
        raise ValueError(f'E2EConfig: cost_guess must map names in learn_cost to finite numbers, e.g. {{"w": 0.5}} '
                         f'or [["w", 0.5]], got {value!r}')
    return tuple((k, float(v)) for k, v in dict(pairs).items())


@dataclasses.dataclass(frozen=True)
class E2EConfig:
    """Algorithm 2's settings (every field is checked on construction).

    Attributes:
        model: ``"parametric"`` (the spec's learnable parameters, from their guesses) or ``"node"`` (a Neural ODE).
        adjoint: how the plan is differentiated: ``Unrolled(K)``, reverse mode through K warm-started extragradient
            steps, or ``Implicit()``, the implicit function theorem at a converged solve
            (``Implicit(fallback_steps=K)``: K of the unrolled fallback); K = None is 10 for a parametric model, 5 for
            a Neural ODE, as published. A name (``"unrolled"``, ``"implicit"``) is read as that adjoint with the
            default K.
        iterations: the most outer iterations (one optimiser update each); None: 1200 for a parametric model, 600
            for a Neural ODE.
        optimizer: a learning rate for ``optax.adam`` or an ``optax.GradientTransformation`` (theta and cost weights).
        reset_every: restart the planner from the initial guess (duals 0) every this many iterations; None: never.
        loss: imitate the expert's ``"controls"`` (published: mean over nodes of ||u_t - u*_t||^2), its
            ``"states"`` (the model's planned states against the expert's), or ``"both"`` (the sum).
        on_failure: implicit mode, when the solve or the KKT solve failed: ``"skip"`` the update, ``"unrolled"``
            (K unrolled steps from the unconverged iterate), or ``"backtrack"``: the last step whose plan converged
            again at half the length (a step can make the model's plan infeasible; skipping would stay there).
        learn_dynamics: learn the model's parameters (False, with ``learn_cost``: inverse optimal control).
        learn_cost: names of the spec's cost parameters to learn (their start: ``cost_guess``).
        cost_guess: ``((name, value), ...)``, the starting values of ``learn_cost`` (default: the spec's value / 2).
        hidden, activation: the Neural ODE's network.
        planner: the :class:`Extragradient` of the unrolled planner (None: :func:`~.planner.default_planner_solver`).
        implicit_solver: the solver run to tolerance in implicit mode: an :class:`Extragradient` (None: tol 1e-9,
            20,000 iterations) or an :class:`InteriorPoint` (much faster where final values are required).
        checkpoint_every: iterations between checkpoints (with a checkpoint folder); None: 10 per run.
        snapshot_every: iterations between stored plans for the training figure; None: 40 per run.
        seed: the Neural ODE's initialisation (and the system-identification fit's, with ``init="sysid"``).
        init: where theta starts: ``"guess"`` (the spec's guesses; a Neural ODE's random weights, normalised by the
            bounds), ``"sysid"`` (fitted first by system identification, ``SysidConfig(model, hidden, activation,
            seed, rounds=1)``), or a ``SysidConfig`` for that fit (its model, hidden and activation must be these).
        soft_state_bounds: None (hard final-state bounds), or c > 0: plan the model with elastic final-state bounds,
            penalty ``c * max(1, |J*|)`` per unit of scaled violation (J*: the expert's cost), as a learned model need
            not keep a state in bounds where the true one does by itself; c = 10 leaves the true optimum unchanged.
            Not in the unrolled planner, whose K steps cannot fail. Single shooting only.
        reaim: re-aim the trained model's plan at the required final values at most this many times from observed
            true runs (:mod:`~myriad.runtime.learn.reaim`; not the training); None: 6 for a Neural ODE, 0 parametric.
    """

    model: str = "parametric"
    adjoint: Unrolled | Implicit = Unrolled()
    iterations: int | None = None
    optimizer: Any = 1e-2
    reset_every: int | None = 1000
    loss: str = "controls"
    on_failure: str = "backtrack"
    learn_dynamics: bool = True
    learn_cost: tuple[str, ...] = ()
    cost_guess: tuple = ()
    hidden: tuple[int, ...] = (50, 50)
    activation: str = "tanh"
    planner: Extragradient | None = None
    implicit_solver: Extragradient | InteriorPoint | None = None
    checkpoint_every: int | None = None
    snapshot_every: int | None = None
    seed: int = 0
    init: Any = "guess"
    reaim: int | None = None
    soft_state_bounds: float | None = None

    def __post_init__(self):
        for name, allowed in (("model", MODELS), ("loss", LOSSES), ("on_failure", ON_FAILURE)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"E2EConfig({name}={getattr(self, name)!r}): expected one of {allowed}")
        adj = adjoint(self.adjoint)
        if adj.unroll is None:
            adj = adj.with_unroll(_REGISTRY[self.model].default_unroll)
        object.__setattr__(self, "adjoint", adj)
        for name in ("reaim", "iterations"):  # None: the model's default
            if getattr(self, name) is None:
                object.__setattr__(self, name, getattr(_REGISTRY[self.model], f"default_{name}"))
        for name, low, optional in (("iterations", 1, False), ("reset_every", 1, True),
                                    ("checkpoint_every", 1, True), ("snapshot_every", 1, True), ("seed", 0, False),
                                    ("reaim", 0, False)):
            v = getattr(self, name)
            if not ((optional and v is None) or _int(v, low)):
                raise ValueError(f"E2EConfig: {name} must be an integer >= {low}{' or None' if optional else ''}, "
                                 f"got {v!r}")
        opt = self.optimizer
        if isinstance(opt, (int, float)) and not isinstance(opt, bool):
            if not (math.isfinite(opt) and opt > 0):
                raise ValueError(f"E2EConfig: optimizer as a learning rate must be finite and > 0, got {opt!r}")
            object.__setattr__(self, "optimizer", float(opt))
        elif not (callable(getattr(opt, "init", None)) and callable(getattr(opt, "update", None))):
            raise ValueError(f"E2EConfig: optimizer must be a learning rate or an optax.GradientTransformation, "
                             f"got {opt!r}")
        object.__setattr__(self, "learn_cost", tuple(self.learn_cost))
        object.__setattr__(self, "cost_guess", _pairs(self.cost_guess))
        unknown = set(dict(self.cost_guess)) - set(self.learn_cost)
        if unknown:
            raise ValueError(f"E2EConfig: cost_guess names {sorted(unknown)}, which are not in learn_cost")
        if not self.learn_dynamics and not self.learn_cost:
            raise ValueError("E2EConfig: nothing to learn (learn_dynamics=False and no learn_cost)")
        if self.planner is not None and not isinstance(self.planner, Extragradient):
            raise ValueError(f"E2EConfig: planner must be an Extragradient, got {type(self.planner).__name__}")
        if self.implicit_solver is not None and not isinstance(self.implicit_solver, (Extragradient, InteriorPoint)):
            raise ValueError(f"E2EConfig: implicit_solver must be an Extragradient or an InteriorPoint, got "
                             f"{type(self.implicit_solver).__name__}")
        if error := network_error(self.hidden, self.activation):
            raise ValueError(f"E2EConfig: {error}")
        object.__setattr__(self, "hidden", tuple(int(w) for w in self.hidden))
        soft = self.soft_state_bounds
        if soft is not None:
            if isinstance(soft, bool) or not isinstance(soft, (int, float)) or not (math.isfinite(soft) and soft > 0):
                raise ValueError(f"E2EConfig: soft_state_bounds must be None or a finite factor > 0, got {soft!r}")
            object.__setattr__(self, "soft_state_bounds", float(soft))
        self._check_init()

    def _check_init(self) -> None:
        from ..sysid.run import SysidConfig  # lazily: the sysid runner is only needed for init="sysid"

        init = self.init
        if isinstance(init, str) and init in INITS:
            return
        if not isinstance(init, SysidConfig):
            raise ValueError(f"E2EConfig(init={init!r}): expected one of {INITS} or a SysidConfig")
        mine = {"model": self.model, "hidden": self.hidden, "activation": self.activation}
        theirs = {"model": init.model, "hidden": tuple(init.hidden), "activation": init.activation}
        if init.model == "parametric":
            mine, theirs = {"model": self.model}, {"model": init.model}
        differ = sorted(k for k in mine if mine[k] != theirs[k])
        if differ:
            raise ValueError(f"E2EConfig: init's SysidConfig must fit the model learned here; it differs in {differ} "
                             f"({ {k: theirs[k] for k in differ} } against { {k: mine[k] for k in differ} })")

    def sysid_config(self) -> Any:
        """The system-identification configuration that fits the start (``init`` not ``"guess"``), else None."""
        from ..sysid.run import SysidConfig

        if isinstance(self.init, SysidConfig):
            return self.init
        if self.init == "guess":
            return None
        return SysidConfig(model=self.model, hidden=self.hidden, activation=self.activation, seed=self.seed, rounds=1,
                           reaim=0)

    def identity(self, system: str) -> tuple[str, dict]:
        """``(sha256, description)`` of what fixes the sequence of iterates (not ``iterations``,
        ``checkpoint_every``, ``snapshot_every`` or ``reaim``, which a resumed run may change)."""
        desc = {f.name: describe(getattr(self, f.name)) for f in dataclasses.fields(self)
                if f.name not in ("iterations", "checkpoint_every", "snapshot_every", "reaim")}
        desc["optimizer"] = optimizer_identity(self.optimizer)
        desc["system"] = system
        return digest(desc), desc
