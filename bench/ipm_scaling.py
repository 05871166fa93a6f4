"""The interior point at scale (issue 32 item 6): warm and cold solve time against N for every direct transcription,
myriad's InteriorPoint beside myriad's IPOPT and CasADi + IPOPT on the same transcription, in the same run.

For one system (default Van der Pol) and each transcription and N (``bench.casadi_transcriptions.SETTINGS``: single
shooting with Heun, multiple shooting with one RK4 step per interval, trapezoidal and Hermite-Simpson collocation, N
control intervals each), three solvers solve the same discrete problem:

    interior_point   solve(system, transcription, InteriorPoint(kkt=KKT), resimulate=False, nominal=True), KKT from
                     --kkt: one method for every transcription, or TRANSCRIPTION=METHOD for one (repeatable: e.g.
                     --kkt banded --kkt single_shooting=auto)
    ipopt            the same with Ipopt() (cyipopt; sparse MUMPS, exact Hessian)
    casadi           CasADi + IPOPT on the peer transcription of bench/casadi_transcriptions.py, with myriad's IPOPT
                     options (tol 1e-8, ...), built from the spec's sympy export (the export itself is not timed)

cold = the first call at that N (myriad: tracing, XLA compilation and the solve; the transcription object, shared by
both myriad solvers, is built before, untimed; CasADi: building the NLP and the solver, and the solve); compile =
myriad's own compile_seconds of that call. warm = the same call again, --repeat times, the three solvers alternating
so that load from other processes hits them alike: median, and the range (min-max). Each figure is wall time
(Python overhead included); the JSON also has the process's CPU seconds of each call (all its threads: XLA's may
run several), which load distorts less. After each N, myriad's compiled programs are dropped (runtime.clear_caches).

The growth exponent is the least-squares slope of log(warm median) against log(N) over N >= --fit-from (default:
the second smallest N when three or more are given, so 400 to 6400 by default; else the smallest). Costs: the
largest relative difference between the three solvers' costs per row, flagged above 1e-6.

A solve cannot be interrupted: --max-seconds limits what is started. Once a solver's cold or warm call at some N
takes longer than the limit, its larger N are skipped on that transcription ("skipped (over the limit at N=...)");
a larger N is also skipped when the growth of its last two N predicts a call over the limit. Dense single shooting
(IPOPT factorises a dense N x N Hessian of the controls) and the dense interior point grow like N^3: issue 32 allows
skipping IPOPT on single shooting at the largest N.

Usage: python -m bench.ipm_scaling [--system van_der_pol] [--transcriptions T ...] [--intervals 100 400 1600 6400]
       [--solvers interior_point ipopt casadi] [--repeat 3] [--kkt [T=]KKT ...] [--max-seconds 120] [--fit-from N]
       [--json PATH]
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

os.environ.setdefault("JAX_PLATFORMS", "cpu")  # like IPOPT and CasADi, on the CPU
# One OpenBLAS thread (before NumPy/SciPy load it): JAX's CPU LAPACK calls (InteriorPoint's factorisations) go through
# SciPy's threaded OpenBLAS, and threads fighting over small dense factorisations on the loaded 2-core machine made
# Hermite-Simpson(100) take 31 s (issue 32). IPOPT's own BLAS is single-threaded. Set it yourself to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import casadi
import cyipopt
import jax
import numpy as np

from bench.casadi_peer import _json_safe, _machine, _rel, _warm_up
from bench.casadi_transcriptions import SETTINGS, peer
from myriad.compiler.casadi_export import export_file
from myriad.runtime import clear_caches, load, solve
from myriad.runtime.atomic import atomic_write_text
from myriad.runtime.solve import transcribe
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.systems import NAMES

ROOT = Path(__file__).resolve().parent.parent
SOLVERS = {"interior_point": "InteriorPoint", "ipopt": "IPOPT (cyipopt)", "casadi": "CasADi + IPOPT"}
INTERVALS = (100, 400, 1600, 6400)
AGREE = 1e-6  # the costs' largest relative difference flagged above this


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---- one solver's calls --------------------------------------------------------------------------------------------


def myriad_calls(system, transcription, solver):
    """(cold, warm): each one ``solve`` call returning its record (wall seconds, myriad's compile seconds)."""
    def call() -> dict:
        start = time.perf_counter()
        sol = solve(system, transcription, solver, resimulate=False, nominal=True)
        return {"cost": float(sol.cost), "converged": bool(sol.converged), "status": str(sol.status),
                "iterations": int(sol.iterations), "seconds": time.perf_counter() - start,
                "compile_seconds": float(sol.compile_seconds), "solve_seconds": float(sol.solve_seconds)}
    return call, call


def casadi_calls(cs, system, name: str, intervals: int, ipopt_options: dict):
    """(cold, warm): cold builds the peer NLP and its solver and solves (both timed), warm re-solves it."""
    held = {}

    def cold() -> dict:
        start = time.perf_counter()
        held["peer"] = peer(name, cs, system, intervals, ipopt_options)
        build = time.perf_counter() - start
        r = held["peer"].solve()
        return {**r, "seconds": build + r["seconds"], "compile_seconds": build}

    return cold, lambda: held["peer"].solve()


# ---- limits ------------------------------------------------------------------------------------------------------


def predicted_seconds(history: list[tuple[int, float, float]], intervals: int) -> tuple[float, str] | None:
    """A call's seconds at ``intervals``: the compile (or CasADi's build) time and the solve time each extrapolated
    from the last two measured N (the solve growing at least linearly, the compile as it grew), and from where; None
    with fewer than two. Why apart: extrapolating a compile-dominated first call linearly predicted 98 s for a
    Hermite-Simpson(1600) interior point that compiles in 20 s at every N and solves in 0.3 s."""
    if len(history) < 2:
        return None
    (n1, t1, c1), (n2, t2, c2) = history[-2:]

    def slope(a, b):
        return math.log(max(b, 1e-9) / max(a, 1e-9)) / math.log(n2 / n1)

    ratio = intervals / n2
    return c2 * ratio ** max(0.0, slope(c1, c2)) + t2 * ratio ** max(1.0, slope(t1, t2)), f"N={n1}-{n2}"


def skip_reason(state: dict, intervals: int, limit: float) -> str | None:
    """Why this solver does not run at ``intervals`` on this transcription (None: it runs)."""
    if state.get("skip"):
        return state["skip"]
    guess = predicted_seconds(state["history"], intervals)
    if guess is not None and guess[0] > limit:
        state["skip"] = f"skipped (over the limit at N={intervals}: {guess[0]:.0f} s predicted from {guess[1]})"
        return state["skip"]
    return None


# ---- one row: a transcription at one N ---------------------------------------------------------------------------


def _cold(key: str, cold, label: str) -> dict:
    cpu = time.process_time()
    try:
        r = cold()
    except Exception as exc:  # a solve that fails at scale (memory, XLA) is a result: recorded, larger N skipped
        log(f"  {label} {key}: FAILED ({type(exc).__name__}: {exc})")
        return {"error": f"{type(exc).__name__}: {str(exc)[:300]}"}
    log(f"  {label} {key}: cold {r['seconds']:.3f} s, cost {r['cost']:.10g}, {r['iterations']} it, {r['status']}")
    return {"cost": r["cost"], "converged": r["converged"], "status": r["status"], "iterations": r["iterations"],
            "cold_seconds": r["seconds"], "cold_cpu_seconds": time.process_time() - cpu,
            "compile_seconds": r.get("compile_seconds"), "warm": [], "warm_cpu": []}


def _warm(records: dict, calls: dict, repeat: int, limit: float, label: str) -> None:
    """--repeat warm calls of every solver that ran, alternating; a solver stops repeating past the limit."""
    for i in range(repeat):
        for key, rec in records.items():
            if "error" in rec or (rec["warm"] and rec["warm"][-1] > limit):
                continue
            cpu = time.process_time()
            r = calls[key][1]()
            rec["warm_cpu"].append(time.process_time() - cpu)
            rec["warm"].append(r["seconds"])
            if r["iterations"] != rec["iterations"] or _rel(r["cost"], rec["cost"]) > 1e-12:
                rec["warm_differs"] = f"warm call {i + 1}: {r['iterations']} it, cost {r['cost']:.12g}"
        log(f"  {label} warm round {i + 1}: " + ", ".join(f"{k} {v['warm'][-1]:.3f} s" for k, v in records.items()
                                                           if "error" not in v and len(v["warm"]) == i + 1))
    for rec in records.values():
        if rec.get("warm"):
            rec.update(warm_seconds=statistics.median(rec["warm"]), warm_min=min(rec["warm"]),
                       warm_max=max(rec["warm"]), warm_cpu_seconds=statistics.median(rec["warm_cpu"]))


def _agreement(records: dict) -> float | None:
    costs = [r["cost"] for r in records.values() if "cost" in r]
    if len(costs) < 2:
        return None
    return max(_rel(a, b) for i, a in enumerate(costs) for b in costs[i + 1:])


def run_row(ctx: dict, name: str, intervals: int, states: dict, args) -> dict:
    """Every solver on ``name`` at ``intervals`` (those not skipped): cold, then alternating warm calls."""
    system, label = ctx["system"], f"{name} N={intervals}"
    tr = SETTINGS[name](intervals)
    transcribe(system, tr)  # shared by both myriad solvers: built before either is timed
    makers = {"interior_point": lambda: myriad_calls(system, tr, ctx["interior_point"][name]),
              "ipopt": lambda: myriad_calls(system, tr, Ipopt()),
              "casadi": lambda: casadi_calls(ctx["cs"], system, name, intervals, ctx["ipopt_options"])}
    records, calls, skipped = {}, {}, {}
    for key in args.solvers:
        reason = skip_reason(states[key], intervals, args.max_seconds)
        if reason:
            skipped[key] = {"skipped": reason}
            log(f"  {label} {key}: {reason}")
            continue
        calls[key] = makers[key]()
        records[key] = _cold(key, calls[key][0], label)
    _warm(records, calls, args.repeat, args.max_seconds, label)
    for key, rec in records.items():
        state = states[key]
        if "error" in rec:
            state["skip"] = f"skipped (failed at N={intervals})"
            continue
        longest = max(rec["cold_seconds"], max(rec["warm"], default=0.0))
        compile_s = rec.get("compile_seconds") or 0.0
        solve_s = max(rec["cold_seconds"] - compile_s, max(rec["warm"], default=0.0))
        state["history"].append((intervals, solve_s, compile_s))
        if longest > args.max_seconds:
            state["skip"] = f"skipped (over the limit at N={intervals})"
    clear_caches()  # the next N compiles its own programs anyway: free these (memory maps, RAM)
    diff = _agreement(records)
    return {"transcription": name, "intervals": intervals, "solvers": {**records, **skipped},
            "max_relative_cost_difference": diff, "costs_differ": diff is not None and diff > AGREE}


# ---- growth and output ---------------------------------------------------------------------------------------------


def fit_from(intervals: list[int], given: int | None) -> int:
    if given is not None:
        return given
    return intervals[1] if len(intervals) >= 3 else intervals[0]


def exponents(rows: list[dict], solvers: list[str], start: int, field: str = "warm_seconds") -> dict:
    """Per transcription and solver: the least-squares slope of log(field) in log(N) over N >= start (``field``:
    the warm median, or ``compile_seconds``, which should not grow)."""
    out: dict = {}
    for name in dict.fromkeys(r["transcription"] for r in rows):
        for key in solvers:
            pts = [(r["intervals"], r["solvers"][key][field]) for r in rows if r["transcription"] == name
                   and r["intervals"] >= start and r["solvers"].get(key, {}).get(field)]
            fit = {"points": len(pts), "from": pts[0][0] if pts else None, "to": pts[-1][0] if pts else None,
                   "exponent": None}
            if len(pts) >= 2:
                n, t = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
                fit["exponent"] = float(np.polyfit(n, t, 1)[0])
            out.setdefault(name, {})[key] = fit
    return out


def _fit_cell(f: dict) -> str:
    if f["exponent"] is None:
        return f"- ({f['points']} point{'s' if f['points'] != 1 else ''})"
    return f"{f['exponent']:.2f} (N={f['from']}-{f['to']})"


def _cell(rec: dict | None, what: str) -> str:
    if rec is None:
        return "-"
    if "skipped" in rec or "error" in rec:
        return rec.get("skipped") or f"failed: {rec['error'][:60]}"
    if what == "warm":
        if not rec.get("warm"):
            return "-"
        return f"{rec['warm_seconds']:.3g} ({rec['warm_min']:.3g}-{rec['warm_max']:.3g})"
    compile_s = rec.get("compile_seconds")
    return f"{rec['cold_seconds']:.3g}" + (f" ({compile_s:.3g})" if compile_s is not None else "")


def markdown(rows: list[dict], solvers: list[str], fits: dict, compile_fits: dict, start: int) -> str:
    names = [SOLVERS[k] for k in solvers]
    head = (["transcription", "N"] + [f"{n} warm s" for n in names] + ["IP / IPOPT warm"]
            + [f"{n} cold s (compile)" for n in names] + ["iterations (" + " / ".join(names) + ")", "cost",
                                                            "max rel. cost diff"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        s = r["solvers"]
        ip, ipopt = s.get("interior_point", {}), s.get("ipopt", {})
        ratio = (f"{ip['warm_seconds'] / ipopt['warm_seconds']:.2f}"
                 if ip.get("warm_seconds") and ipopt.get("warm_seconds") else "-")
        its = " / ".join(str(s[k].get("iterations", "-")) + ("" if s[k].get("converged", True) else " ✗")
                         for k in solvers)
        cost = next((f"{s[k]['cost']:.10g}" for k in solvers if "cost" in s[k]), "-")
        diff = r["max_relative_cost_difference"]
        flag = "-" if diff is None else f"{diff:.1e}" + (" DIFFERS" if r["costs_differ"] else "")
        lines.append("| " + " | ".join([r["transcription"], str(r["intervals"])]
                                        + [_cell(s.get(k), "warm") for k in solvers] + [ratio]
                                        + [_cell(s.get(k), "cold") for k in solvers] + [its, cost, flag]) + " |")
    lines += ["", f"Growth exponent in N (least squares on log-log, N >= {start}) of the warm median, and of the "
              "compile seconds (myriad's; CasADi's build):", "",
              "| transcription | " + " | ".join(f"{n} warm" for n in names) + " | "
              + " | ".join(f"{n} compile" for n in names) + " |", "|---|" + "---|" * 2 * len(names)]
    for name, per in fits.items():
        cells = [_fit_cell(per[k]) for k in solvers] + [_fit_cell(compile_fits[name][k]) for k in solvers]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def notes(rows: list[dict], args) -> list[str]:
    """What the table's marks mean, and the limit's skips (with the issue's allowance for dense single shooting)."""
    out = [f"warm: median (min-max) of {args.repeat} calls; cold: the first call at that N, compile seconds in "
           f"brackets (myriad's; CasADi's NLP and solver build); ✗ not converged; DIFFERS: costs apart by more than "
           f"{AGREE:g} relative; limit {args.max_seconds:g} s per call."]
    skips = sorted({(r["transcription"], k, rec["skipped"]) for r in rows for k, rec in r["solvers"].items()
                    if "skipped" in rec})
    for name, key, reason in skips:
        allowed = (" (issue 32 allows IPOPT to skip the largest N on dense single shooting: a dense N x N Hessian "
                   "of the controls, about N^3)" if name == "single_shooting" and key in ("ipopt", "casadi") else "")
        out.append(f"{SOLVERS[key]} on {name}: {reason}{allowed}")
    worst = max((r["max_relative_cost_difference"] or 0.0 for r in rows), default=0.0)
    out.append(f"largest relative cost difference between the solvers: {worst:.1e} "
               f"({sum(r['costs_differ'] for r in rows)} of {len(rows)} rows above {AGREE:g})")
    return out


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m bench.ipm_scaling", description=__doc__.split("\n\n")[0])
    ap.add_argument("--system", default="van_der_pol", help="a shipped system with a spec in specs/")
    ap.add_argument("--transcriptions", nargs="+", default=list(SETTINGS), choices=list(SETTINGS), metavar="T",
                    help=f"any of {', '.join(SETTINGS)} (default all)")
    ap.add_argument("--intervals", nargs="+", type=int, default=list(INTERVALS), metavar="N")
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS), choices=list(SOLVERS), metavar="S",
                    help=f"any of {', '.join(SOLVERS)} (default all)")
    ap.add_argument("--repeat", type=int, default=3, help="warm calls per solver and N (median and range)")
    ap.add_argument("--kkt", action="append", default=[], metavar="[T=]KKT",
                    help="InteriorPoint(kkt=KKT), the Newton system's method (default auto), for every transcription "
                         "or, as T=KKT, for transcription T; repeatable")
    ap.add_argument("--max-seconds", type=float, default=120.0,
                    help="a call over this skips the larger N of that solver and transcription")
    ap.add_argument("--fit-from", type=int, default=None, metavar="N",
                    help="the growth exponent's smallest N (default: the second smallest of --intervals when three or "
                         "more are given, else the smallest)")
    ap.add_argument("--json", metavar="PATH", help="also write every record as JSON (atomically)")
    return ap


def _interior_points(ap, kkt: list[str], names: list[str]) -> dict[str, InteriorPoint]:
    """One InteriorPoint per transcription from the --kkt values (later ones win), validated by InteriorPoint."""
    methods = dict.fromkeys(names, "auto")
    for value in kkt:
        name, _, method = value.rpartition("=")
        if name and name not in SETTINGS:
            ap.error(f"--kkt {value!r}: {name!r} is not a transcription; use KKT or T=KKT with T one of "
                     f"{', '.join(SETTINGS)}")
        methods.update({name: method} if name else dict.fromkeys(methods, method))
    out = {}
    for name in names:
        try:
            out[name] = InteriorPoint(kkt=methods[name])
        except ValueError as exc:
            ap.error(f"--kkt {methods[name]!r}: {exc}")
    return out


def _checked(argv) -> tuple[argparse.Namespace, dict[str, InteriorPoint]]:
    """The arguments, or exit 2 naming the input and the fix."""
    ap = _parser()
    args = ap.parse_args(argv)
    spec = ROOT / "specs" / f"{args.system}.yaml"
    if args.system not in NAMES or not spec.is_file():
        ap.error(f"--system {args.system!r}: not a shipped system with a spec in specs/; choose from "
                 f"{', '.join(n for n in NAMES if (ROOT / 'specs' / f'{n}.yaml').is_file())}")
    if min(args.intervals) < 2 or len(set(args.intervals)) != len(args.intervals):
        ap.error(f"--intervals {args.intervals}: give distinct N of at least 2, e.g. --intervals 100 400 1600 6400")
    if args.repeat < 1:
        ap.error(f"--repeat {args.repeat}: at least 1 warm call is needed for a warm time")
    if not args.max_seconds > 0:
        ap.error(f"--max-seconds {args.max_seconds}: give a positive number of seconds")
    if args.json and not Path(args.json).resolve().parent.is_dir():
        ap.error(f"--json {args.json}: its folder does not exist; create it or choose another path")
    ip = _interior_points(ap, args.kkt, args.transcriptions)
    args.intervals = sorted(args.intervals)
    args.transcriptions = list(dict.fromkeys(args.transcriptions))
    args.solvers = [k for k in SOLVERS if k in args.solvers]  # the table's columns in one order
    return args, ip


def _header(args, ip) -> dict:
    versions = {"jax": jax.__version__, "casadi": casadi.__version__,
                "ipopt": ".".join(map(str, cyipopt.IPOPT_VERSION))}
    info = {"system": args.system, "machine": _machine(), "load_before": list(os.getloadavg()),
            "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS"), "versions": versions,
            "interior_point": {k: repr(v) for k, v in ip.items()}, "ipopt_options": Ipopt().ipopt_options(),
            "settings": {k: repr(SETTINGS[k](2)).replace("intervals=2", "intervals=N") for k in args.transcriptions},
            "intervals": args.intervals, "repeat": args.repeat, "max_seconds": args.max_seconds}
    print(f"{args.system}: {info['machine']}, load average {' '.join(f'{x:.2f}' for x in info['load_before'])}, "
          f"OPENBLAS_NUM_THREADS={info['openblas_num_threads']}; JAX {versions['jax']} on "
          f"{jax.devices()[0].platform}, CasADi {versions['casadi']}, IPOPT {versions['ipopt']} (cyipopt)")
    kkt = ", ".join(f"{k} {v.kkt!r}" for k, v in ip.items())
    print(f"InteriorPoint kkt: {kkt}; otherwise as {next(iter(ip.values()))!r}")
    print(f"IPOPT options (both IPOPT columns): {info['ipopt_options']}")
    print("transcriptions: " + "; ".join(f"{k} = {v}" for k, v in info["settings"].items()))
    return info


def main(argv: list[str] | None = None) -> int:
    args, ip = _checked(argv)
    _warm_up()  # the process's one-off costs (JAX backend, CasADi's IPOPT plugin) before any timing
    info = _header(args, ip)
    ctx = {"system": load(args.system), "cs": export_file(ROOT / "specs" / f"{args.system}.yaml"),
           "interior_point": ip, "ipopt_options": Ipopt().ipopt_options()}
    rows = []
    for name in args.transcriptions:
        states = {key: {"history": [], "skip": None} for key in args.solvers}
        for n in args.intervals:
            log(f"{name} N={n} (load {os.getloadavg()[0]:.2f})")
            rows.append(run_row(ctx, name, n, states, args))
    start = fit_from(args.intervals, args.fit_from)
    fits = exponents(rows, args.solvers, start)
    compile_fits = exponents(rows, args.solvers, start, "compile_seconds")
    print()
    print(markdown(rows, args.solvers, fits, compile_fits, start))
    print()
    for line in notes(rows, args):
        print(line)
    info["load_after"] = list(os.getloadavg())
    print(f"load average after: {' '.join(f'{x:.2f}' for x in info['load_after'])}")
    if args.json:
        out = {**info, "fit_from": start, "rows": rows, "exponents": fits, "compile_exponents": compile_fits}
        atomic_write_text(args.json, json.dumps(_json_safe(out), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
