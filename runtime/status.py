"""One vocabulary of outcomes for every solver, the sweep, :class:`~myriad.runtime.nlp.NLPResult` and
:class:`~myriad.runtime.solve.Solution`.

A solver keeps its own code and message beside the :class:`Status` (IPOPT's ``-1``, SciPy's ``9``); everything
that judges or reports an outcome uses the status. It is an ``IntEnum`` so that a pure JAX solve can carry it as an
integer array inside ``jit`` and ``vmap`` (``Status(int(code))`` on the host).
"""

from __future__ import annotations

import enum

__all__ = ["Status", "from_ipopt", "from_scipy_slsqp"]


class Status(enum.IntEnum):
    """The outcome of a solve. Only :attr:`CONVERGED` is a success."""

    CONVERGED = 0
    ITERATION_LIMIT = 1
    NOT_FINITE = 2
    INFEASIBLE = 3
    NOT_CONVERGED = 4
    STATE_BOUNDS_VIOLATED = 5

    @property
    def success(self) -> bool:
        return self is Status.CONVERGED

    @property
    def message(self) -> str:
        return _MESSAGES[self]

    def __str__(self) -> str:  # the JSON and the CLI print the name, never the integer
        return self.name.lower()


_MESSAGES = {
    Status.CONVERGED: "converged to the solver's tolerance at a feasible point",
    Status.ITERATION_LIMIT: "the iteration limit was reached before convergence",
    Status.NOT_FINITE: "stopped at a non-finite value (NaN or inf)",
    Status.INFEASIBLE: "the problem looks infeasible (or the feasibility restoration failed)",
    Status.NOT_CONVERGED: "did not converge (stalled, line search or step failure, or tolerance not met)",
    Status.STATE_BOUNDS_VIOLATED: "converged, but the trajectory violates state bounds that the method cannot enforce",
}

# IPOPT's ApplicationReturnStatus codes (IpReturnCodes_inc.h).
_IPOPT = {
    0: Status.CONVERGED,  # Solve_Succeeded
    1: Status.CONVERGED,  # Solved_To_Acceptable_Level
    2: Status.INFEASIBLE,  # Infeasible_Problem_Detected
    -1: Status.ITERATION_LIMIT,  # Maximum_Iterations_Exceeded
    -2: Status.INFEASIBLE,  # Restoration_Failed
    -4: Status.ITERATION_LIMIT,  # Maximum_CpuTime_Exceeded
    -5: Status.ITERATION_LIMIT,  # Maximum_WallTime_Exceeded
    -13: Status.NOT_FINITE,  # Invalid_Number_Detected
}


def from_ipopt(code: int, success: bool) -> Status:
    """The status for IPOPT's return code; ``success`` is myriad's own judgement (violation, finite objective)."""
    status = _IPOPT.get(int(code), Status.NOT_CONVERGED)
    if status is Status.CONVERGED and not success:
        return Status.NOT_CONVERGED
    return status


# scipy.optimize.minimize(method="SLSQP") exit modes (scipy/optimize/_slsqp_py.py).
_SLSQP = {
    0: Status.CONVERGED,
    4: Status.INFEASIBLE,  # Inequality constraints incompatible
    9: Status.ITERATION_LIMIT,  # Iteration limit reached
}


def from_scipy_slsqp(code: int, success: bool) -> Status:
    """The status for SciPy SLSQP's exit mode; ``success`` is myriad's own judgement."""
    status = _SLSQP.get(int(code), Status.NOT_CONVERGED)
    if status is Status.CONVERGED and not success:
        return Status.NOT_CONVERGED
    return status
