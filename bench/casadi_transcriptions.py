"""CasADi + IPOPT on the NLP of each of myriad's direct transcriptions, as a timing and cost peer
(``bench/ipm_scaling.py``).

Each peer poses, from the spec's sympy IR (``myriad.compiler.casadi_export``), the discrete problem that
``myriad.runtime.transcriptions`` poses at the same N, so the optimal costs agree to the solvers' tolerance (the
variables, their scaling and the starting points differ, so iterations may too):

    single_shooting     Heun, controls at the N + 1 nodes: ``bench.casadi_peer.CasadiShooting`` (SX, nlpsol), from
                        myriad's own starting point (``SingleShooting(intervals=N, integrator=Heun())``)
    trapezoidal         ``myriad.compiler.casadi_opti.trapezoidal`` (``Trapezoidal(intervals=N)``)
    hermite_simpson     compressed Hermite-Simpson: node states, node and midpoint controls, the Hermite midpoint
                        state, Simpson's rule for the dynamics and the cost (``HermiteSimpson(intervals=N)``)
    multiple_shooting   one RK4 step per shooting interval, the running cost integrated as an extra state by the
                        same step, controls linear in between (``MultipleShooting(intervals=N, steps_per_interval=1,
                        integrator=RK4())``)

The collocation and multiple-shooting peers are ``casadi.Opti`` problems with x(0), the final values, the state
bounds and the straight-line start of ``casadi_opti.node_conditions``, expanded to SX for IPOPT (``expand``: SX
evaluates several times faster than Opti's MX graph). Every peer uses IPOPT with the options it is given (myriad's
``Ipopt().ipopt_options()`` in the bench) and re-solves from the same start on each ``solve()``.

A ``parametric`` peer (``bench/batch_throughput.py``) takes the spec's parameters and x(0) as data: ``set(params,
x0)`` poses another member of a batch on the same built NLP (nlpsol parameters for single shooting, Opti parameters
and the straight-line start from the new x(0) for the others), so that its re-solve times IPOPT alone. The default
bakes the spec's values in as constants (``bench/ipm_scaling.py``).
"""

from __future__ import annotations

import time

import numpy as np

from myriad.compiler.casadi_export import CasadiSystem, _casadi
from myriad.compiler.casadi_opti import (
    _bound,
    _bound_controls,
    _path,
    _start,
    node_conditions,
    posed_at,
    straight_line_start,
    trapezoidal,
)
from myriad.runtime.integrators import RK4, Heun
from myriad.runtime.transcriptions import (
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
    control_scale,
    default_data,
    state_scale,
)

__all__ = ["PEERS", "SETTINGS", "peer"]

# myriad's transcription at N intervals, the one each peer poses.
SETTINGS = {
    "single_shooting": lambda n: SingleShooting(intervals=n, integrator=Heun()),
    "multiple_shooting": lambda n: MultipleShooting(intervals=n, steps_per_interval=1, integrator=RK4()),
    "trapezoidal": lambda n: Trapezoidal(intervals=n),
    "hermite_simpson": lambda n: HermiteSimpson(intervals=n),
}


class OptiPeer:
    """An Opti problem solved by IPOPT (expanded to SX), from the initial values set on it, each call; ``posed``
    (cs, the node states X, N, the parameters' and x(0)'s Opti parameters) where it is parametric."""

    def __init__(self, opti, J, ipopt_options: dict, posed: tuple | None = None):
        self.opti, self.J, self.posed = opti, J, posed
        opti.solver("ipopt", {"print_time": False, "expand": True}, {"print_level": 0, "sb": "yes", **ipopt_options})

    def set(self, params: dict | None, x0) -> None:
        """Pose the member at ``params`` ({name: value} over the spec's values) and initial state ``x0``, and start
        from the straight line out of ``x0``."""
        if self.posed is None:
            raise ValueError("OptiPeer.set: this peer bakes its parameters in; build it with parametric=True")
        cs, X, N, P, X0 = self.posed
        if P is not None:
            self.opti.set_value(P, cs.params_vector(params))
        self.opti.set_value(X0, [float(v) for v in x0])
        straight_line_start(self.opti, cs, X, N, x0)

    def solve(self) -> dict:
        start = time.perf_counter()
        sol = self.opti.solve_limited()  # no exception when IPOPT fails: the status says so
        seconds = time.perf_counter() - start
        stats = self.opti.stats()
        return {"cost": float(sol.value(self.J)), "converged": bool(stats["success"]),
                "status": stats["return_status"], "iterations": int(stats["iter_count"]), "seconds": seconds}


class ShootingPeer:
    """``CasadiShooting`` at N controls, from myriad's starting point."""

    def __init__(self, cs: CasadiSystem, system, intervals: int, ipopt_options: dict):
        from bench.casadi_peer import CasadiShooting
        from myriad.runtime.solve import transcribe

        self.peer = CasadiShooting(cs, control_scale(system), state_scale(system), ipopt_options, intervals=intervals)
        z0 = transcribe(system, SETTINGS["single_shooting"](intervals)).initial_guess(default_data(system))
        self.w0 = np.asarray(z0, dtype=np.float64) / self.peer.s_u
        self.cs = cs

    def set(self, params: dict | None, x0) -> None:
        """Pose the member at ``params`` and ``x0`` (nlpsol parameters); the start stays myriad's controls'."""
        self.peer.p = np.concatenate([self.cs.params_vector(params), np.asarray(x0, dtype=np.float64)])

    def solve(self) -> dict:
        return self.peer.solve(self.w0)


def _hermite_simpson(opti, cs: CasadiSystem, X, U, T, p, N: int):
    """Compressed Hermite-Simpson defects, midpoint controls (bounded) and path rows; returns the cost."""
    ca = _casadi()
    Um = opti.variable(cs.n_controls, N)
    _bound_controls(opti, cs, Um)
    h = T / N
    t = [T * k / N for k in range(N + 1)]
    f = [cs.f(X[:, k], U[:, k], t[k], p) for k in range(N + 1)]
    L = [cs.L(X[:, k], U[:, k], t[k], p) for k in range(N + 1)]
    J = cs.phi(X[:, N], T, p)
    defects, mid_rows = [], []
    for k in range(N):
        xm, tm = (X[:, k] + X[:, k + 1]) / 2 + h / 8 * (f[k] - f[k + 1]), t[k] + h / 2
        fm, Lm = cs.f(xm, Um[:, k], tm, p), cs.L(xm, Um[:, k], tm, p)
        defects.append(X[:, k + 1] - X[:, k] - h / 6 * (f[k] + 4 * fm + f[k + 1]))
        J += h / 6 * (L[k] + 4 * Lm + L[k + 1])
        if cs.n_path:
            mid_rows.append(cs.g(xm, Um[:, k], tm, p))
    opti.subject_to(ca.horzcat(*defects) == 0)
    if mid_rows:  # myriad's Hermite-Simpson also holds the path constraints at the midpoints
        G = ca.horzcat(*mid_rows)
        for i, (lo, hi) in enumerate(zip(cs.path_lower, cs.path_upper)):
            _bound(opti, G[i, :], lo, hi)
    return J


def _multiple_shooting(opti, cs: CasadiSystem, X, U, T, p, N: int):
    """One RK4 step per interval on the state augmented with the running cost; returns the cost."""
    ca = _casadi()
    n = cs.n_states
    h = T / N

    def aug(y, u, t):
        return ca.vertcat(cs.f(y[:n], u, t, p), cs.L(y[:n], u, t, p))

    J = cs.phi(X[:, N], T, p)
    defects = []
    for k in range(N):
        t, y, um = T * k / N, ca.vertcat(X[:, k], 0), (U[:, k] + U[:, k + 1]) / 2
        k1 = aug(y, U[:, k], t)
        k2 = aug(y + h / 2 * k1, um, t + h / 2)
        k3 = aug(y + h / 2 * k2, um, t + h / 2)
        k4 = aug(y + h * k3, U[:, k + 1], t + h)
        end = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        defects.append(end[:n] - X[:, k + 1])
        J += end[n]
    opti.subject_to(ca.horzcat(*defects) == 0)
    return J


def _opti_peer(cs: CasadiSystem, N: int, ipopt_options: dict, dynamics, parametric: bool) -> OptiPeer:
    """Node states and controls, ``dynamics``' defects and cost, then the conditions every transcription shares."""
    ca, opti, U, T = _start(cs, N)
    p, x0 = posed_at(opti, cs, parametric=parametric)
    X = opti.variable(cs.n_states, N + 1)
    J = dynamics(opti, cs, X, U, T, p, N)
    node_conditions(opti, cs, X, N, x0)
    _bound_controls(opti, cs, U)
    _path(opti, cs, X, U, T, p, N)
    opti.minimize(J)
    posed = (cs, X, N, p if cs.n_params else None, x0) if parametric else None
    return OptiPeer(opti, J, ipopt_options, posed)


def _trapezoidal(cs: CasadiSystem, N: int, ipopt_options: dict, parametric: bool) -> OptiPeer:
    problem = trapezoidal(cs, N, ipopt_options=ipopt_options, parametric=parametric)
    posed = (cs, problem.X, N, problem.P, problem.X0) if parametric else None
    return OptiPeer(problem.opti, problem.J, ipopt_options, posed)


PEERS = {
    "single_shooting": lambda cs, system, n, opts, parametric: ShootingPeer(cs, system, n, opts),
    "multiple_shooting": lambda cs, system, n, opts, parametric: _opti_peer(cs, n, opts, _multiple_shooting,
                                                                            parametric),
    "trapezoidal": lambda cs, system, n, opts, parametric: _trapezoidal(cs, n, opts, parametric),
    "hermite_simpson": lambda cs, system, n, opts, parametric: _opti_peer(cs, n, opts, _hermite_simpson,
                                                                          parametric),
}


def peer(transcription: str, cs: CasadiSystem, system, intervals: int, ipopt_options: dict,
         parametric: bool = False):
    """The CasADi peer of ``SETTINGS[transcription](intervals)`` for ``system`` (its export ``cs``): an object whose
    ``solve()`` returns cost, converged, status, iterations and seconds (IPOPT's call alone); with ``parametric``
    its ``set(params, x0)`` poses another member first (single shooting's peer is always parametric)."""
    return PEERS[transcription](cs, system, intervals, dict(ipopt_options), parametric)
