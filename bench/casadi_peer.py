"""An independent peer, side by side: the published setting solved by CasADi + IPOPT and by myriad, in one run.

Both sides solve the same NLP, the one runtime/transcriptions/single_shooting.py poses (the published setting):

    decision     the controls u_0..u_N at the N + 1 = 101 nodes (linearly interpolated in between), as IPOPT's
                 variables w = u / s_u with myriad's nominal control scale s_u; myriad's starting point
    dynamics     Heun (explicit trapezoid) steps on the uniform grid t_k = k T / N from x(0) = x0, the running cost
                 integrated as an extra state by the same steps
    objective    C_N + phi(x_N, T)
    constraints  x_N,i - x_final,i = 0 for every state with a required final value;
                 lo_i / s_x,i <= x_N,i / s_x,i <= hi_i / s_x,i for every other state with a finite bound;
                 u_lower <= u_k <= u_upper
    IPOPT        exact Hessian, and myriad's own option set (Ipopt().ipopt_options(): tol 1e-8, bound_relax_factor 0,
                 honor_original_bounds, ...) on both sides

CasADi side: f, L and phi come from the compiler's sympy IR through myriad.compiler.casadi_export (not from the
generated JAX code); the rollout is unrolled in SX, derivatives are CasADi's AD, IPOPT is CasADi's nlpsol plugin.
Parameters and x0 are nlpsol parameters (data, as in myriad), not constants folded into the graph.
myriad side: solve(system, SingleShooting(intervals=100, integrator=Heun()), SOLVER, resimulate=False), SOLVER being
Ipopt() (cyipopt, one Python callback per evaluation) or, with --solver interior_point, InteriorPoint() (the whole
solve one compiled XLA program; its own algorithm and stopping test, IPOPT's tol = 1e-8, so the costs agree to about
1e-8, not to the last digit).

Times: cold = the first solve of the system in this process, building included (CasADi: the SX graph and nlpsol with
its derivative functions, but not the sympy export, which stands for myriad's ready-made generated module; myriad:
loading the module, transcription, tracing, XLA compilation, Hessian-pattern detection; the 'cold m/c' column and
its median line are their ratio, the process's JAX start paid beforehand, so the first system is not penalised for
it; XLA's default options, which the warm solves reuse, where `myriad solve` compiles with --compile quick); warm = the
same solve called again with the same inputs (myriad reuses its compiled functions; CasADi re-calls the nlpsol
object), the minimum over --repeat calls, the two sides alternating so that a burst of load from other processes hits
both; 'spread' is the range of the --repeat paired ratios (the i-th myriad over the i-th CasADi re-solve). After
timing, both NLPs are evaluated at the common starting point as a check that they are the same problem ("start"
column: the largest relative difference of objective and constraints).

Usage: python -m bench.casadi_peer [--solver ipopt|interior_point] [--systems NAME ...] [--repeat R] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")  # like CasADi, on the CPU (tiny problems gain nothing from a GPU)
# One OpenBLAS thread (before NumPy/SciPy load it): JAX's CPU LAPACK calls (InteriorPoint's Cholesky factorisations)
# go through SciPy's threaded OpenBLAS, and on the busy 2-core machine a 202 x 202 Cholesky measured a median 10 ms
# (worst 1.5 s) with its default threads against 1 ms (worst 16 ms) with one. IPOPT's own BLAS (Debian's
# openblas-serial) is single-threaded already. Set OPENBLAS_NUM_THREADS yourself to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import casadi
import cyipopt
import jax
import jax.numpy as jnp
import numpy as np

from myriad.compiler.casadi_export import CasadiSystem, export_file
from myriad.runtime import Heun, Ipopt, SingleShooting, load, solve
from myriad.runtime.solve import transcribe
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.systems import NAMES
from myriad.runtime.transcriptions import control_scale, default_data, state_scale

ROOT = Path(__file__).resolve().parent.parent
N = 100
SETTING = SingleShooting(intervals=N, integrator=Heun())


# ---- the CasADi side ---------------------------------------------------------------------------------------------


class CasadiShooting:
    """The published-setting NLP of one system built in CasADi, and its IPOPT solver."""

    def __init__(self, cs: CasadiSystem, s_u: np.ndarray, s_x: np.ndarray, ipopt_options: dict, intervals: int = N):
        N = intervals  # the published 100 by default; bench/ipm_scaling.py poses larger grids
        n, m = cs.n_states, cs.n_controls
        T = cs.horizon
        h = T / N
        w = casadi.SX.sym("w", (N + 1) * m)
        p = casadi.SX.sym("p", cs.n_params)
        x0 = casadi.SX.sym("x0", n)
        x, u, t = casadi.SX.sym("x", n), casadi.SX.sym("u", m), casadi.SX.sym("t")
        aug = casadi.Function("aug", [x, u, t, p], [casadi.vertcat(cs.f(x, u, t, p), cs.L(x, u, t, p))])

        us = [w[k * m:(k + 1) * m] * s_u for k in range(N + 1)]  # node-major, like myriad's z
        y = casadi.vertcat(x0, 0)
        for k in range(N):  # Heun on the state augmented with the accumulated running cost
            tk = k * h
            k1 = aug(y[:n], us[k], tk, p)
            k2 = aug(y[:n] + h * k1[:n], us[k + 1], tk + h, p)
            y = y + 0.5 * h * (k1 + k2)
        xN = y[:n]
        objective = y[n] + cs.phi(xN, T, p)

        fixed = [i for i, v in enumerate(cs.x_final) if v is not None]
        bounded = [i for i in range(n) if cs.x_final[i] is None
                   and (math.isfinite(cs.x_lower[i]) or math.isfinite(cs.x_upper[i]))]
        rows = [xN[i] - cs.x_final[i] for i in fixed] + [xN[i] / s_x[i] for i in bounded]
        g = casadi.vertcat(*rows) if rows else casadi.SX(0, 1)
        self.lbg = [0.0] * len(fixed) + [cs.x_lower[i] / s_x[i] for i in bounded]
        self.ubg = [0.0] * len(fixed) + [cs.x_upper[i] / s_x[i] for i in bounded]
        self.lbx = np.tile(np.asarray(cs.u_lower) / s_u, N + 1)
        self.ubx = np.tile(np.asarray(cs.u_upper) / s_u, N + 1)
        self.p = np.concatenate([cs.param_values, cs.x0])
        self.s_u = np.tile(s_u, N + 1)

        data = casadi.vertcat(p, x0)
        nlp = {"x": w, "p": data, "f": objective}
        if rows:
            nlp["g"] = g
        options = {"print_time": False, "calc_lam_p": False, "ipopt": ipopt_options}
        self.solver = casadi.nlpsol(f"{cs.name}_peer", "ipopt", nlp, options)
        self.evaluate = casadi.Function("fg", [w, data], [objective, g])

    def solve(self, w0: np.ndarray) -> dict:
        start = time.perf_counter()
        r = self.solver(x0=w0, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg, p=self.p)
        seconds = time.perf_counter() - start
        stats = self.solver.stats()
        return {"cost": float(r["f"]), "converged": bool(stats["success"]), "status": stats["return_status"],
                "iterations": int(stats["iter_count"]), "seconds": seconds}


# ---- one system, both sides --------------------------------------------------------------------------------------


def _timed(fn):
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def _rel(a: float, b: float) -> float:
    if not (math.isfinite(a) and math.isfinite(b)):
        return math.inf
    scale = max(abs(a), abs(b))
    return 0.0 if scale == 0.0 else abs(a - b) / scale


SOLVERS = {"ipopt": Ipopt, "interior_point": InteriorPoint}


def run_system(name: str, repeat: int, solver_name: str = "ipopt") -> dict:
    solver = SOLVERS[solver_name]()
    ipopt = Ipopt()  # the peer's options: myriad's IPOPT settings, whichever solver myriad uses

    # myriad: everything from scratch (the system module is imported, nothing compiled yet)
    def myriad_solve():
        return solve(system, SETTING, solver, resimulate=False)

    system, load_seconds = _timed(lambda: load(name))
    sol, m_cold = _timed(myriad_solve)
    m_cold += load_seconds

    # CasADi: export from the spec, build the NLP, solve
    nlp = transcribe(system, SETTING)  # cached by the solve above: only its starting point and scales are used here
    data = default_data(system)
    z0 = np.asarray(nlp.initial_guess(data), dtype=np.float64)

    # The export (sympy -> CasADi) is not timed: it stands for myriad's generated module, imported ready-made.
    cs, export_seconds = _timed(lambda: export_file(ROOT / "specs" / f"{name}.yaml"))
    peer, c_build = _timed(lambda: CasadiShooting(cs, control_scale(system), state_scale(system),
                                                  dict(ipopt.ipopt_options())))
    w0 = z0 / peer.s_u
    res = peer.solve(w0)
    c_cold = c_build + res["seconds"]
    m_times, c_times = [], []
    for _ in range(repeat):  # alternating, so that load from other processes hits both sides alike
        m_times.append(_timed(myriad_solve)[1])
        c_times.append(peer.solve(w0)["seconds"])
    m_warm, c_warm = min(m_times), min(c_times)
    paired = [m / c for m, c in zip(m_times, c_times)]

    # The same problem? Both NLPs at the common starting point (outside the timed regions).
    f_c, g_c = (np.asarray(v, dtype=np.float64).ravel() for v in peer.evaluate(w0, peer.p))
    f_m = float(jax.jit(nlp.objective)(jnp.asarray(z0), data))
    g_m = np.asarray(jax.jit(nlp.constraints)(jnp.asarray(z0), data)) if nlp.constraints is not None else np.zeros(0)
    start_diff = max([_rel(float(f_c[0]), f_m)] + [_rel(a, b) for a, b in zip(g_c, g_m)])
    if g_c.shape != g_m.shape:
        start_diff = math.inf

    return {
        "system": name,
        "myriad": {"cost": sol.cost, "converged": sol.converged, "status": str(sol.status), "message": sol.message,
                   "iterations": sol.iterations, "cold_seconds": m_cold, "warm_seconds": m_warm,
                   "compile_seconds": sol.compile_seconds, "ipopt_seconds": sol.solve_seconds},
        "casadi": {"cost": res["cost"], "converged": res["converged"], "status": res["status"],
                   "iterations": res["iterations"], "cold_seconds": c_cold, "warm_seconds": c_warm,
                   "build_seconds": c_build, "export_seconds": export_seconds},
        "relative_difference": _rel(sol.cost, res["cost"]),
        "start_point_difference": start_diff,
        "warm_ratio": m_warm / c_warm if c_warm > 0 else math.inf,
        "cold_ratio": m_cold / c_cold if c_cold > 0 else math.inf,
        "paired_ratios": paired,
    }


def _warm_up() -> None:
    """Pay the one-off costs of the process (JAX backend start, loading CasADi's IPOPT plugin) before any timing."""
    jax.jit(lambda a: a * 2.0)(jnp.ones(2)).block_until_ready()
    x = casadi.SX.sym("x")
    s = casadi.nlpsol("warm_up", "ipopt", {"x": x, "f": (x - 1) ** 2},
                      {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}})
    s(x0=0.0)


# ---- output ------------------------------------------------------------------------------------------------------


HEAD = (f"{'system':18s} {'myriad cost':>13s} {'CasADi cost':>13s} {'rel diff':>8s} {'start':>7s} {'iters':>9s} "
        f"{'cold m s':>8s} {'cold c s':>8s} {'cold m/c':>8s} {'warm m s':>8s} {'warm c s':>8s} {'warm m/c':>8s} "
        f"{'spread':>11s}")


def _line(r: dict) -> str:
    m, c = r["myriad"], r["casadi"]
    flag = "" if m["converged"] and c["converged"] else \
        f"  [myriad: {m['status'] if not m['converged'] else 'ok'}; CasADi: {c['status']}]"
    return (f"{r['system']:18s} {m['cost']:13.7g} {c['cost']:13.7g} {r['relative_difference']:8.1e} "
            f"{r['start_point_difference']:7.0e} {m['iterations']:>4d}/{c['iterations']:<4d} "
            f"{m['cold_seconds']:8.2f} {c['cold_seconds']:8.2f} {r['cold_ratio']:8.2f} "
            f"{m['warm_seconds']:8.3f} {c['warm_seconds']:8.3f} "
            f"{r['warm_ratio']:8.2f} {min(r['paired_ratios']):5.2f}-{max(r['paired_ratios']):<5.2f}{flag}")


def _machine() -> str:
    """The CPU model and core count, for the figures' provenance."""
    model = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores"


def _json_safe(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_json_safe(v) for v in obj]
    return obj


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--solver", choices=list(SOLVERS), default="ipopt",
                    help="myriad's NLP solver (the peer is always CasADi + IPOPT)")
    ap.add_argument("--systems", nargs="+", default=list(NAMES), metavar="NAME")
    ap.add_argument("--repeat", type=int, default=3, help="warm solves per side; the minimum is reported")
    ap.add_argument("--json", metavar="FILE", help="also write the records as JSON")
    args = ap.parse_args(argv)
    unknown = sorted(set(args.systems) - set(NAMES))
    if unknown:
        ap.error(f"unknown systems {unknown}; shipped: {', '.join(NAMES)}")
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")

    _warm_up()
    ipopt_version = ".".join(map(str, cyipopt.IPOPT_VERSION))
    print(f"published setting: single shooting, N = {N}, Heun; IPOPT (exact Hessian) options: "
          f"{Ipopt().ipopt_options()}")
    side = f"IPOPT {ipopt_version} (cyipopt)" if args.solver == "ipopt" else f"{SOLVERS[args.solver]()}"
    print(f"myriad: JAX {jax.__version__} on {jax.devices()[0].platform}, {side}; "
          f"peer: CasADi {casadi.__version__} (SX, its bundled IPOPT); {_machine()}")
    print(f"warm = min over {args.repeat} re-solves; 'start' = relative difference of the two NLPs at the starting "
          "point; 'iters' = myriad/CasADi")
    print(HEAD)
    records = []
    for name in args.systems:
        r = run_system(name, args.repeat, args.solver)
        records.append(r)
        print(_line(r), flush=True)

    ratios = [r["warm_ratio"] for r in records]
    both = [r for r in records if r["myriad"]["converged"] and r["casadi"]["converged"]]
    median = statistics.median(ratios)
    worst = max((r["relative_difference"] for r in both), default=math.nan)
    print()
    print(f"converged: myriad {sum(r['myriad']['converged'] for r in records)}/{len(records)}, "
          f"CasADi {sum(r['casadi']['converged'] for r in records)}/{len(records)}; "
          f"largest relative cost difference where both converged: {worst:.1e}")
    print(f"warm ratio myriad ({args.solver}) / CasADi: median {median:.2f} (min {min(ratios):.2f}, "
          f"max {max(ratios):.2f}) over {len(records)} systems; {sum(x <= 1.0 for x in ratios)} at or below 1.0")
    cold = [r["cold_ratio"] for r in records]
    print(f"cold ratio myriad ({args.solver}) / CasADi (each system's first solve in this process, compiling and "
          f"building included): median {statistics.median(cold):.2f} (min {min(cold):.2f}, max {max(cold):.2f})")
    pooled = sorted(x for r in records for x in r["paired_ratios"])
    print(f"all {len(pooled)} paired re-solve ratios: median {statistics.median(pooled):.2f}, "
          f"quartiles {pooled[len(pooled) // 4]:.2f}-{pooled[(3 * len(pooled)) // 4]:.2f}")
    if args.json:
        summary = {"solver": args.solver, "machine": _machine(),
                   "setting": {"transcription": "single_shooting", "controls": N, "integrator": "heun",
                               "ipopt_options": Ipopt().ipopt_options()},
                   "versions": {"jax": jax.__version__, "casadi": casadi.__version__, "cyipopt_ipopt": ipopt_version},
                   "repeat": args.repeat, "median_warm_ratio": median,
                   "median_cold_ratio": statistics.median(cold), "systems": records}
        Path(args.json).write_text(json.dumps(_json_safe(summary), indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
