"""The trajectory-optimisation expert that labels states: from state x at step k, re-solve the problem left and take
the plan's control at k (what model-predictive control plays there).

    expert = Expert(env)                                   # runtime/rl/mpc.py's planning NLP, nominal parameters
    plans, ok = expert.label(xs, ks, previous)             # (B, n), (B,), (B, N, m) -> (B, N, m), (B,)
    first = plans[np.arange(B), ks]                        # each state's expert action

The planning problem is :class:`~myriad.runtime.rl.mpc.MPC`'s (single shooting on the env's own grid and step,
the start index and state as data, so one compiled program serves every state of every episode); here it is solved
for a batch of states at once with the pure-JAX interior point (:meth:`InteriorPoint.solve_batch`, IPOPT's method,
one program), each member warm-started from the plan it is given. A member that does not converge is reported in
``ok`` and its label must not be used.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..data import ProblemData
from ..rl.env import Env
from ..rl.mpc import MPC
from ..solvers import InteriorPoint

__all__ = ["Expert"]


class Expert:
    """Labels states of ``env`` with the optimiser's plan from them (module docstring).

    Args:
        env: the environment (its options fix the grid, integrator and penalty of the planning problem).
        params: the expert's model parameters (default: the spec's: the expert knows the nominal system).
        solver: the batched solver (default ``InteriorPoint()``).
    """

    def __init__(self, env: Env, params: dict | None = None, solver: InteriorPoint | None = None):
        self.mpc = MPC(env, params, replan_every=1)
        self.solver = InteriorPoint() if solver is None else solver
        self.steps = env.options.steps
        self.solves, self.failures = 0, 0

    def label(self, xs: Any, ks: Any, previous: Any) -> tuple[np.ndarray, np.ndarray]:
        """Solve from each state ``xs[b]`` at step ``ks[b]`` warm-started from ``previous[b]`` (N, m): the plans
        (B, N, m) (``plans[b, :ks[b]]`` are ``previous[b]``'s: played already) and whether each converged (B,)."""
        xs = np.asarray(xs, np.float64)
        previous = np.asarray(previous, np.float64)
        ks = np.broadcast_to(np.asarray(ks, np.int32), (xs.shape[0],))
        batch = xs.shape[0]
        model = {k: np.broadcast_to(np.asarray(v, np.float64), (batch, *np.shape(v))) for k, v in
                 self.mpc.params.items()}
        data = ProblemData({"model": model, "k": ks, "prev": previous}, xs)
        results = self.solver.solve_batch(self.mpc.nlp, data, previous.reshape(batch, -1))
        plans = np.stack([np.asarray(r.z, np.float64).reshape(previous.shape[1:]) for r in results])
        ok = np.array([bool(r.success) and bool(np.all(np.isfinite(r.z))) for r in results])
        played = np.arange(self.steps)[None, :] < ks[:, None]
        plans = np.where(played[..., None], previous, plans)
        self.solves, self.failures = self.solves + batch, self.failures + int(np.sum(~ok))
        return plans, ok

    def optimal_plan(self, x0: Any) -> np.ndarray:
        """The expert's plan (N, m) from ``x0`` at step 0, cold-started from the transcriptions' default guess."""
        plans, ok = self.label(np.asarray(x0, np.float64)[None], 0, self.mpc.initial_plan()[None])
        if not ok[0]:
            raise RuntimeError(f"{self.mpc.env.system.name}: the expert's plan from x0 did not converge")
        return plans[0]
