"""Cross-check matrix: transcriptions against each other, and NLP solvers against each other. Prints figures only.

(a) Transcriptions (IPOPT): every Lenhart system and van_der_pol, solved with multiple shooting (RK4), trapezoidal and
    Hermite-Simpson collocation on fine grids, and the forward-backward sweep where the system has u*. Different
    discretisations have different discrete costs, so the comparison is on the *re-simulated* cost (each solution's
    controls, linearly interpolated, in the true dynamics with the adaptive integrator). The sweep is "n/a" where
    it cannot apply: no u* (the compiler could not characterise it), or a state bound binds (the sweep has no
    state-constraint multipliers and reports the violation).
(b) Solvers (same NLP): the smooth Lenhart systems on one transcription, IPOPT vs. SLSQP vs. Extragradient vs.
    InteriorPoint (pure JAX). Same discretisation, so the discrete ``cost`` is compared directly.

Usage: python -m bench.cross_check [--systems a,b,...] [--part a|b|ab] [--solvers ipopt,interior_point,...]
                                   [--json FILE] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# One OpenBLAS thread (before NumPy/SciPy load it): SciPy's SLSQP calls LAPACK on small dense matrices, and
# threaded OpenBLAS on a busy 2-core machine measured 175 s instead of 1.4 s for 103 SLSQP iterations
# (bear_populations, Trapezoidal(50)). Set OPENBLAS_NUM_THREADS yourself to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import numpy as np

from myriad.runtime import load
from myriad.runtime.integrators import RK4, DormandPrince
from myriad.runtime.simulate import simulate
from myriad.runtime.solve import Solution, solve
from myriad.runtime.solvers import SLSQP, Extragradient, InteriorPoint, Ipopt
from myriad.runtime.system import OptimalControlUnavailable
from myriad.runtime.transcriptions import (
    ForwardBackwardSweep,
    HermiteSimpson,
    MultipleShooting,
    Trapezoidal,
    default_data,
    state_scale,
)

LENHART = ("bacteria", "bear_populations", "bioreactor", "cancer_treatment", "epidemic", "glucose", "harvest",
           "hiv_treatment", "mould_fungicide", "predator_prey", "simple_case", "timber_harvest", "tumour")
TRANSCRIPTION_SYSTEMS = (*LENHART, "van_der_pol")
# Smooth: no bang-bang arcs, so every solver sees a smooth NLP (u* is stationary in H; bacteria's is smooth too,
# though the compiler could not certify its u*).
SOLVER_SYSTEMS = ("bacteria", "bear_populations", "cancer_treatment", "epidemic", "glucose", "harvest",
                  "hiv_treatment", "mould_fungicide", "simple_case")

# (a): grids fine enough that the discretisation error of the re-simulated cost is well below 1 %: every method has
# 200 control intervals (Hermite-Simpson: 100 intervals, i.e. 201 points on its half-step grid).
METHODS_A = {
    "multiple_shooting": MultipleShooting(intervals=50, steps_per_interval=4, integrator=RK4()),
    "trapezoidal": Trapezoidal(intervals=200),
    "hermite_simpson": HermiteSimpson(intervals=100),
    "fbsm": ForwardBackwardSweep(intervals=1000),
}
# (b): one moderate grid, the same NLP for every solver (SLSQP is dense: keep it small).
TRANSCRIPTION_B = Trapezoidal(intervals=50)
# Extragradient's default budget is 1e5 iterations; Epidemic needs 2.8e5 from the transcription's start (its E and I
# start held at 100 and 50 but fall to 1e-4, so the start's magnitudes, which scale the steps, are poor there). At
# about 7 us per iteration on this grid that is 2 s, so the cross-check grants 4e5 rather than change the default for
# every solve (a failing single-shooting solve of Cartpole costs 1.8 ms per iteration).
SOLVERS_B = {"ipopt": Ipopt(), "slsqp": SLSQP(), "extragradient": Extragradient(max_iter=400_000),
             "interior_point": InteriorPoint()}
AGREE = 0.01  # relative spread at which results "agree"
RESIM_TOL = 1e-4  # re-simulated state-bound or final-value violation (relative to the state's scale) worth a mark
ACTIVE_TOL = 1e-6  # a state bound is "active" where a direct solution comes this close (relative to the state scale)


def spread(values) -> float:
    """(max - min) / max(|median|, 1e-12) of the finite values; NaN with fewer than two."""
    v = np.array([x for x in values if x is not None and math.isfinite(x)])
    if v.size < 2:
        return math.nan
    return float((v.max() - v.min()) / max(abs(float(np.median(v))), 1e-12))


def active_state_bounds(system, sol: Solution) -> list[str]:
    """Names of states whose bounds a (direct) solution touches at some node, e.g. ['x (upper)']."""
    arrays = system.arrays()
    lo, hi = np.asarray(arrays["x_lower"], float), np.asarray(arrays["x_upper"], float)
    scale = state_scale(system)
    states = np.asarray(sol.states)[1:]  # x(0) is data, not a decision
    out = []
    for i, name in enumerate(system.state_names):
        # A required final value is not a bound: look at the other nodes only.
        col = states[:-1, i] if system.final_mask[i] else states[:, i]
        if col.size == 0:
            continue
        if np.isfinite(lo[i]) and np.min(col - lo[i]) <= ACTIVE_TOL * scale[i]:
            out.append(f"{name} (lower)")
        if np.isfinite(hi[i]) and np.min(hi[i] - col) <= ACTIVE_TOL * scale[i]:
            out.append(f"{name} (upper)")
    return out


def resimulated_infeasibility(system, sol: Solution) -> tuple[float, str]:
    """The worst violation, relative to the state's nominal scale, of a state bound or a required final value by the
    re-simulated trajectory (the controls as ``solve`` re-simulates them: linear interpolation, adaptive integrator),
    and what it is. A re-simulated cost is only comparable when this is small: an open-loop control that overspends
    a budget or misses a final state in the true dynamics can look cheaper than the optimum."""
    times, controls = np.asarray(sol.times), np.asarray(sol.controls)
    grid = np.linspace(0.0, system.horizon, times.shape[0])
    if not np.allclose(times, grid, rtol=0, atol=1e-9 * max(1.0, system.horizon)):  # same rule as solve's
        grid = np.linspace(0.0, system.horizon, 4 * times.shape[0])
        controls = np.stack([np.interp(grid, times, controls[:, j]) for j in range(controls.shape[1])], 1)
    data = default_data(system)
    sim = simulate(system, controls, data.params, data.x0, integrator=DormandPrince())
    xs = np.asarray(sim.states)
    arrays = system.arrays()
    scale = state_scale(system)
    below = np.max(np.asarray(arrays["x_lower"], float) - xs, axis=0) / scale
    above = np.max(xs - np.asarray(arrays["x_upper"], float), axis=0) / scale
    final = np.where(system.final_mask, np.abs(np.nan_to_num(np.asarray(sim.defect))), 0.0) / scale
    worst, what = 0.0, ""
    for i, name in enumerate(system.state_names):
        for v, kind in ((below[i], "below its lower bound"), (above[i], "above its upper bound"),
                        (final[i], "off its final value")):
            if v > worst:
                worst, what = float(v), f"{name} {kind}"
    return worst, what


def _fmt(v, spec="{:.6g}") -> str:
    return "-" if v is None or not math.isfinite(v) else spec.format(v)


# ---- (a) transcriptions --------------------------------------------------------------------------------------------


def part_a(names, log) -> list[dict]:
    rows = []
    for name in names:
        system = load(name)
        row = {"system": name, "results": {}, "notes": []}
        for key, method in METHODS_A.items():
            t0 = time.perf_counter()
            try:
                sol = solve(system, method, Ipopt() if method.uses_solver else None)
            except OptimalControlUnavailable:
                row["results"][key] = {"na": "no u*"}
                row["notes"].append(f"sweep n/a: no u* ({system.optimal_control_note or 'not characterised'})")
                continue
            rec = sol.record()
            rec["wall_seconds"] = round(time.perf_counter() - t0, 3)
            rec["resim_infeasibility"], rec["resim_infeasible"] = resimulated_infeasibility(system, sol)
            if key != "fbsm":
                rec["active_state_bounds"] = active_state_bounds(system, sol)
            elif not sol.converged and "violates the bounds" in sol.message:
                rec["na"] = "state bound"
                row["notes"].append("sweep n/a: " + sol.message.split(": ", 1)[1])
            elif not sol.converged:
                row["notes"].append("sweep FAILED: " + sol.message.split(": ", 1)[1])
            row["results"][key] = rec
            log(f"  {name:17s} {key:17s} cost {_fmt(sol.cost):>12s}  re-simulated {_fmt(sol.simulated_cost):>12s}  "
                f"re-sim infeasibility {rec['resim_infeasibility']:.1e}  "
                f"{'ok' if sol.converged else 'NOT CONVERGED'}  {rec['wall_seconds']:.1f} s")
        active = sorted({b for k, r in row["results"].items() if k != "fbsm" for b in r.get("active_state_bounds", [])})
        row["active_state_bounds"] = active
        if active:
            sweep = row["results"].get("fbsm", {})
            tail = ("" if "na" in sweep or not sweep else
                    "; the sweep's trajectory stays within them, so it is compared" if sweep.get("converged") else "")
            row["notes"].insert(0, f"active state bound(s) in the direct solutions: {', '.join(active)}{tail}")
        for k, r in row["results"].items():
            if "na" not in r and r.get("converged") and r["resim_infeasibility"] > RESIM_TOL:
                row["notes"].append(f"{k}: re-simulated {r['resim_infeasible']} by {r['resim_infeasibility']:.1e} "
                                    f"(of the state's scale)")
        counted = {k: r["simulated_cost"] for k, r in row["results"].items()
                   if "na" not in r and r.get("converged") and r.get("simulated_cost") is not None}
        row["counted"] = sorted(counted)
        row["failed"] = [k for k, r in row["results"].items() if "na" not in r and not r.get("converged")]
        row["spread"] = spread(counted.values())
        row["agree"] = bool(len(counted) >= 2 and row["spread"] <= AGREE)
        rows.append(row)
    return rows


def table_a(rows) -> str:
    cols = list(METHODS_A)
    head = ("| system | " + " | ".join(cols) + " | spread | agree within 1 % | notes |")
    lines = [head, "|" + "---|" * (len(cols) + 4)]
    for row in rows:
        cells = []
        for k in cols:
            r = row["results"].get(k)
            if r is None:
                cells.append("-")
            elif "na" in r:
                cells.append(f"n/a ({r['na']})")
            else:
                flag = "" if r["resim_infeasibility"] <= RESIM_TOL else " †"
                cells.append(_fmt(r["simulated_cost"]) + flag + ("" if r["converged"] else " (FAILED, not counted)"))
        verdict = "yes" if row["agree"] else "NO"
        n_methods = sum("na" not in r for r in row["results"].values())
        if len(row["counted"]) < n_methods:
            verdict += f" ({len(row['counted'])} of {n_methods})"
        lines.append(f"| {row['system']} | " + " | ".join(cells) +
                     f" | {_fmt(row['spread'], '{:.1e}')} | {verdict} | {'; '.join(row['notes'])} |")
    lines.append("")
    lines.append(f"spread = (max - min) / |median| over the converged methods. † the re-simulated trajectory leaves a "
                 f"state bound or misses a required final value by more than {RESIM_TOL:g} of the state's nominal "
                 f"scale (see notes): its re-simulated cost is that of a slightly infeasible trajectory.")
    return "\n".join(lines)


# ---- (b) solvers ---------------------------------------------------------------------------------------------------


def part_b(names, log, solvers=tuple(SOLVERS_B)) -> list[dict]:
    rows = []
    for name in names:
        system = load(name)
        row = {"system": name, "transcription": repr(TRANSCRIPTION_B), "results": {}}
        for key in solvers:
            solver = SOLVERS_B[key]
            t0 = time.perf_counter()
            sol = solve(system, TRANSCRIPTION_B, solver, resimulate=False)
            rec = sol.record()
            rec["wall_seconds"] = round(time.perf_counter() - t0, 3)
            row["results"][key] = rec
            log(f"  {name:17s} {key:14s} cost {_fmt(sol.cost):>12s}  {sol.iterations:6d} it  "
                f"viol {sol.constraint_violation:.1e}  "
                f"{'ok' if sol.converged else 'NOT CONVERGED (' + sol.message + ')'}"
                f"  compile {sol.compile_seconds:.2f} s  solve {sol.solve_seconds:.2f} s")
        ref = row["results"]["ipopt"]["cost"]
        row["rel_diff_to_ipopt"] = {k: (abs(r["cost"] - ref) / max(abs(ref), 1e-12) if r["cost"] is not None else None)
                                    for k, r in row["results"].items()}
        row["spread"] = spread([r["cost"] for r in row["results"].values() if r["converged"]])
        row["agree"] = bool(all(r["converged"] for r in row["results"].values()) and row["spread"] <= AGREE)
        rows.append(row)
    return rows


def table_b(rows) -> str:
    cols = list(rows[0]["results"]) if rows else list(SOLVERS_B)
    head = ("| system | " + " | ".join(f"{c} cost" for c in cols) + " | max rel. diff to IPOPT | agree within 1 % | "
            "iterations (" + " / ".join(cols) + ") | solve s (" + " / ".join(cols) + ") | notes |")
    lines = [head, "|" + "---|" * (len(cols) + 6)]
    for row in rows:
        res = row["results"]
        costs = [_fmt(res[c]["cost"]) + ("" if res[c]["converged"] else " ✗") for c in cols]
        diff = max((v for v in row["rel_diff_to_ipopt"].values() if v is not None), default=math.nan)
        notes = "; ".join(f"{c} not converged: {res[c]['message']} (constraint violation "
                          f"{res[c]['constraint_violation']:.1e})" for c in cols if not res[c]["converged"])
        lines.append(f"| {row['system']} | " + " | ".join(costs) + f" | {_fmt(diff, '{:.1e}')} | "
                     f"{'yes' if row['agree'] else 'NO'} | " + " / ".join(str(res[c]["iterations"]) for c in cols)
                     + " | " + " / ".join(f"{res[c]['solve_seconds']:.2f}" for c in cols) + f" | {notes} |")
    lines.append("")
    lines.append("✗ not converged (its cost is shown, and counted in the max rel. diff, but the row does not agree). "
                 "Iterations: IPOPT, SLSQP and interior-point iterations, extragradient steps (two gradient "
                 "evaluations each). Solve seconds exclude compilation.")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", help="comma-separated subset (each part keeps only its own systems)")
    ap.add_argument("--part", default="ab", choices=["a", "b", "ab"], help="which matrix to run (default both)")
    ap.add_argument("--solvers", default=",".join(SOLVERS_B),
                    help=f"(b): comma-separated columns, ipopt always among them (default: {','.join(SOLVERS_B)})")
    ap.add_argument("--json", metavar="FILE", help="write every record as JSON")
    ap.add_argument("--markdown", metavar="FILE", help="write the tables as Markdown")
    args = ap.parse_args(argv)
    chosen = None if not args.systems else [s.strip() for s in args.systems.split(",") if s.strip()]
    names_a = [n for n in TRANSCRIPTION_SYSTEMS if chosen is None or n in chosen]
    names_b = [n for n in SOLVER_SYSTEMS if chosen is None or n in chosen]
    solvers_b = ["ipopt"] + [s.strip() for s in args.solvers.split(",") if s.strip() and s.strip() != "ipopt"]
    if bad := sorted(set(solvers_b) - set(SOLVERS_B)):
        ap.error(f"unknown solver(s) {bad}; choose from {', '.join(SOLVERS_B)}")
    if chosen is not None:
        unknown = sorted(set(chosen) - set(TRANSCRIPTION_SYSTEMS))
        if unknown:
            ap.error(f"unknown system(s) {unknown}; choose from {', '.join(TRANSCRIPTION_SYSTEMS)}")

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    print(f"device: {jax.devices()}")
    out, md = {"device": str(jax.devices())}, []
    t0 = time.perf_counter()
    if "a" in args.part and names_a:
        log("(a) transcriptions, IPOPT, re-simulated with the adaptive integrator")
        rows_a = part_a(names_a, log)
        text = ("(a) Re-simulated cost (adaptive integrator) per transcription, IPOPT; "
                + ", ".join(f"{k} = {v!r}" for k, v in METHODS_A.items()) + "\n\n" + table_a(rows_a))
        print(text + "\n")
        md.append(text)
        out["transcriptions"] = rows_a
    if "b" in args.part and names_b:
        log(f"(b) solvers on {TRANSCRIPTION_B!r}")
        rows_b = part_b(names_b, log, solvers_b)
        text = (f"(b) Discrete cost per NLP solver on {TRANSCRIPTION_B!r} (iterations: IPOPT/SLSQP/interior-point "
                f"iterations, extragradient steps); " + ", ".join(f"{k} = {SOLVERS_B[k]!r}" for k in solvers_b)
                + "\n\n" + table_b(rows_b))
        print(text + "\n")
        md.append(text)
        out["solvers"] = rows_b
    total = time.perf_counter() - t0
    print(f"total wall time {total:.0f} s")
    out["wall_seconds"] = round(total, 1)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=str)
    if args.markdown:
        with open(args.markdown, "w") as fh:
            fh.write("\n\n".join(md) + f"\n\nTotal wall time {total:.0f} s on {jax.devices()}.\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
