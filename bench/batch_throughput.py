"""Batch throughput: one NLP, a batch of problems that differ in parameters and initial state, solved as one program
(``solve_batch`` with a pure-JAX solver) against one-at-a-time solves by myriad's IPOPT and by CasADi + IPOPT, all in
the same run. Prints figures only.

``solve_batch`` runs the batch as the solver's ``batch_strategy(nlp)`` says: InteriorPoint vmaps the members where
its Newton step can follow the stages under ``vmap`` (on a CPU with ``InteriorPoint.batch_chunk()`` members in
flight, each stopped member's place taken by the next) and otherwise maps over them (``jax.lax.map``, one after
another in one program) on a CPU, and vmaps them on an accelerator; the batched row's label names the strategy and
the Newton step's method (``kkt_method(nlp, vmapped=...)``: dense, banded or riccati). ``--compare`` adds a row with
its other strategy, so what vectorising gains on this device is measured, not assumed.

The NLP is ``--transcription`` at ``--grid`` intervals (``bench.casadi_transcriptions.SETTINGS``; by default the
published setting, single shooting with Heun and 100 controls), and the CasADi row solves the same discrete problems
with the peer of ``bench/casadi_transcriptions.py`` built once, parametric (parameters and x0 are nlpsol or Opti
parameters, each member posed by setting them), so its time is IPOPT's call alone. Every member's cost is compared
between the rows (CasADi's the reference), and members that fail to converge or disagree are listed, not dropped. The
one-at-a-time rates are measured on the first ``--subset`` members and extrapolated to the whole batch (the output
says so). Compile and build time (the first, untimed call) is reported separately and excluded from every rate.
JAX's default device is used (a GPU where there is one); set JAX_PLATFORMS=cpu to force the CPU.

On a CPU the batch is spread over ``--host-devices`` host devices (default: the machine's cores; JAX sees one
unless ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` is set before it starts, which this script does), each
a thread solving its share: the one-at-a-time rows use one core, as IPOPT does.

Usage: python -m bench.batch_throughput [--systems mould_fungicide epidemic] [--solver interior_point]
                                        [--transcription single_shooting|multiple_shooting|trapezoidal|
                                         hermite_simpson] [--grid 100] [--batch 1024]
                                        [--subset 32] [--spread 0.1] [--compare] [--host-devices N] [--repeat 3]
                                        [--json FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

# One OpenBLAS thread (before NumPy/SciPy load it): JAX's CPU LAPACK calls (InteriorPoint's Cholesky factorisations)
# go through SciPy's threaded OpenBLAS, and on the busy 2-core machine a 202 x 202 Cholesky measured a median 10 ms
# (worst 1.5 s) with its default threads against 1 ms (worst 16 ms) with one. IPOPT's own BLAS (Debian's
# openblas-serial) is single-threaded already. Set OPENBLAS_NUM_THREADS yourself to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


# --host-devices (default: this machine's cores) is read here, before JAX loads: the batch is spread over that many
# host devices, each a thread running its share (``solve_batch`` splits a batch over the default backend's devices).
# JAX sees one host device unless told otherwise, so the flag must be in XLA_FLAGS before it loads (main() rejects
# a count below 1).
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    _pre = argparse.ArgumentParser(add_help=False)
    _pre.add_argument("--host-devices", type=int, default=os.cpu_count() or 1)
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count="
                               + str(max(1, _pre.parse_known_args()[0].host_devices))).strip()

import jax
import numpy as np

from bench.casadi_transcriptions import SETTINGS
from myriad.runtime import load
from myriad.runtime.solve import solve, solve_batch, transcribe
from myriad.runtime.solvers import Extragradient, InteriorPoint, Ipopt

ROOT = Path(__file__).resolve().parent.parent
BATCHED = {"interior_point": InteriorPoint, "extragradient": Extragradient}
CASADI = "CasADi + IPOPT, one at a time"
AGREE = 1e-6  # a member whose cost differs from CasADi's by more (relative) is listed as disagreeing


def make_batch(system, batch: int, spread: float, seed: int):
    """Every parameter and every initial state scaled by independent factors U(1 - spread, 1 + spread); initial
    states are kept strictly inside their bounds. Parameters that bounds or final values were compiled with
    (``system.structural_params``) keep their value: the runtime refuses to vary them."""
    rng = np.random.default_rng(seed)
    base = system.default_params()
    params = {k: float(v) * rng.uniform(1 - spread, 1 + spread, batch) for k, v in base.items()
              if k not in system.structural_params}
    arrays = system.arrays()
    x0 = np.asarray(arrays["x0"], float) * rng.uniform(1 - spread, 1 + spread, (batch, system.n_states))
    lo, hi = np.asarray(arrays["x_lower"], float), np.asarray(arrays["x_upper"], float)
    width = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    x0 = np.clip(x0, lo + 1e-3 * width, hi - 1e-3 * width)
    return params, x0


def member(params, x0, i):
    return {k: float(v[i]) for k, v in params.items()}, x0[i]


def one_at_a_time(system, transcription, solver, params, x0, n):
    """Solve members 0..n-1 one by one, after an untimed solve of member 0 that compiles (and traces)."""
    t0 = time.perf_counter()
    solve(system, transcription, solver, params=member(params, x0, 0)[0], x0=x0[0], resimulate=False)
    compile_s = time.perf_counter() - t0
    out = {"costs": [], "converged": [], "iterations": [], "status": [], "compile_seconds": compile_s, "seconds": 0.0}
    for i in range(n):
        p, x = member(params, x0, i)
        t0 = time.perf_counter()
        sol = solve(system, transcription, solver, params=p, x0=x, resimulate=False)
        out["seconds"] += time.perf_counter() - t0
        for key, value in (("costs", sol.cost), ("converged", sol.converged), ("iterations", sol.iterations),
                           ("status", str(sol.status))):
            out[key].append(value)
    return out


def casadi_one_at_a_time(system, name, transcription: str, grid: int, params, x0, n):
    """The same members by CasADi + IPOPT: the peer of bench/casadi_transcriptions.py built once, parametric, each
    member posed by setting its parameters and x0; timed: IPOPT's call alone. Its build and an untimed solve of
    member 0 (which builds IPOPT's NLP, for an Opti peer) are the "compile" figure."""
    from bench.casadi_transcriptions import peer  # after JAX chose its device
    from myriad.compiler.casadi_export import export_file

    cs = export_file(ROOT / "specs" / f"{name}.yaml")
    t0 = time.perf_counter()
    solver = peer(transcription, cs, system, grid, Ipopt().ipopt_options(), parametric=True)
    solver.set(*member(params, x0, 0))
    solver.solve()
    out = {"costs": [], "converged": [], "iterations": [], "status": [],
           "compile_seconds": time.perf_counter() - t0, "seconds": 0.0}
    for i in range(n):
        solver.set(*member(params, x0, i))
        r = solver.solve()
        out["seconds"] += r["seconds"]
        for key, field in (("costs", "cost"), ("converged", "converged"), ("iterations", "iterations"),
                           ("status", "status")):
            out[key].append(r[field])
    return out


def _machine() -> str:
    model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                  if line.startswith("model name")), "unknown CPU") if Path("/proc/cpuinfo").exists() else "?"
    return f"{model}, {os.cpu_count()} cores"


def _rel(a, b):
    return abs(a - b) / max(abs(b), 1e-12)


def _rounds(measures: dict, repeat: int) -> dict:
    """Every row once a round, side by side, so that a ratio is taken between neighbours in time (the host's speed
    drifts); each row's figure is its median round, the spread its slowest and fastest."""
    rows: dict = {}
    for _ in range(repeat):
        for label, measure in measures.items():
            r = measure()
            rows.setdefault(label, {**r, "round_seconds": []})["round_seconds"].append(r["seconds"])
    return rows


def _print_rates(rows: dict, repeat: int) -> None:
    """Each row's median rate, its range over the rounds, compile time, convergence and iterations (the medians go
    into rows)."""
    width = max(36, *(len(label) for label in rows))
    print(f"{'':{width}s} {'problems/s':>11s} {'(range)':>15s} {'compile s':>10s} {'converged':>12s} {'iter':>9s}"
          f"  (median of {repeat} rounds; warm, Python overhead included; compile s: the first, untimed call; "
          "iter: median/max per member)")
    for label, r in rows.items():
        rates = [r["n"] / sec for sec in r["round_seconds"]]
        r["seconds"] = float(np.median(r["round_seconds"]))
        r["problems_per_second"] = r["n"] / r["seconds"]
        spread = f"{min(rates):.1f}-{max(rates):.1f}"
        its = f"{int(np.median(r['iterations']))}/{max(r['iterations'])}" if r["iterations"] else "-"
        print(f"{label:{width}s} {r['problems_per_second']:11.1f} {spread:>15s} {r['compile_seconds']:10.2f} "
              f"{sum(r['converged']):5d}/{r['n']:<6d} {its:>9s}")


def _print_ratios(rows: dict, base: dict, batch: int, subset: int) -> None:
    """The batched row against every other: throughput ratio per round, and how far the costs agree."""
    for label, r in list(rows.items())[1:]:
        pairs = [_rel(a, b) for a, b, ca, cb in zip(base["costs"], r["costs"], base["converged"], r["converged"])
                 if ca and cb]
        worst = f"{max(pairs):.1e}" if pairs else "-"
        ratios = [(base["n"] / sb) / (r["n"] / so) for sb, so in zip(base["round_seconds"], r["round_seconds"])]
        r["ratios"] = ratios
        print(f"  batched / {label}: {float(np.median(ratios)):.1f}x throughput (rounds: "
              + ", ".join(f"{x:.1f}x" for x in ratios) + f"); cost max relative difference {worst} over "
              f"{len(pairs)} members converged on both sides "
              + ("(all members)" if r["n"] == batch else f"(one at a time: first {subset} of {batch}, extrapolated)"))


def _members(rows: dict, subset: int) -> dict:
    """Per member of the first ``subset`` (those every row solved): which rows did not converge (with the status
    where the row has one), and which converged costs differ from CasADi's by more than AGREE (relative); printed
    and returned for the JSON, so that a failing member is reported, never dropped from a median."""
    failed = {label: [(i, r["status"][i] if r.get("status") else "not converged")
                      for i in range(len(r["converged"])) if not r["converged"][i]] for label, r in rows.items()}
    ref = rows[CASADI]
    worst, disagree = {}, []
    for label, r in rows.items():
        if label == CASADI:
            continue
        both = [(i, _rel(r["costs"][i], ref["costs"][i])) for i in range(subset)
                if r["converged"][i] and ref["converged"][i]]
        worst[label] = max((d for _, d in both), default=None)
        disagree += [(label, i, d) for i, d in both if not d <= AGREE]
    for label, f in failed.items():
        if f:
            print(f"  NOT CONVERGED, {label}: {len(f)} member(s): "
                  + ", ".join(f"#{i} ({s})" for i, s in f[:20]) + (" ..." if len(f) > 20 else ""))
    print(f"  per member, first {subset}, against CasADi's cost: "
          + "; ".join(f"{label} max {d:.1e}" if d is not None else f"{label} -" for label, d in worst.items())
          + (f"; {len(disagree)} DISAGREE by more than {AGREE:g}: "
             + ", ".join(f"#{i} {label} {d:.1e}" for label, i, d in disagree[:20]) if disagree
             else f"; none differs by more than {AGREE:g}"), flush=True)
    return {"not_converged": {k: [i for i, _ in v] for k, v in failed.items()},
            "max_relative_difference_to_casadi": worst,
            "disagreements": [{"row": label, "member": i, "relative_difference": d} for label, i, d in disagree]}


def _batched_rows(system, tr, solver, args, params, x0) -> dict:
    """The batched row (``solver``), and with ``--compare`` its other strategy, each labelled with its strategy and
    Newton step: ``{label: measure}``, and the rows' kkt methods under ``"kkt"``."""
    nlp = transcribe(system, tr)

    def how(s) -> str:
        """The strategy: vmapped (at once, in chunks, or as a queue that refills stopped members' places) or mapped,
        and the Newton step's method (an interior point's)."""
        strategy, chunk = s.batch_strategy(nlp), s.batch_chunk(nlp)
        kkt = s.kkt_method(nlp, vmapped=strategy == "vmap") if hasattr(s, "kkt_method") else None
        if strategy == "vmap" and chunk is not None:
            strategy = f"vmap, {chunk} in flight" if s.batch_stepper(nlp) is not None else f"vmap, chunks of {chunk}"
        return strategy + (f"; kkt {kkt}" if kkt else ""), kkt

    # The first call compiles and traces (a batch of other members, same shape: the "compile s" column is its whole
    # wall time); later calls are timed, from the host's arrays to the B Solutions.
    warm_p, warm_x = make_batch(system, args.batch, args.spread, args.seed + 1)

    def batched(s):
        t0 = time.perf_counter()
        solve_batch(system, tr, s, params=warm_p, x0=warm_x)
        compile_s = time.perf_counter() - t0

        def measure():
            t0 = time.perf_counter()
            out = solve_batch(system, tr, s, params=params, x0=x0)
            return {"costs": [m.cost for m in out], "converged": [m.converged for m in out],
                    "iterations": [m.iterations for m in out], "status": [str(m.status) for m in out],
                    "compile_seconds": compile_s, "seconds": time.perf_counter() - t0, "n": args.batch}
        return measure

    solvers = [solver]
    if args.compare and hasattr(solver, "batch"):
        solvers.append(dataclasses.replace(solver, batch="vmap" if solver.batch_strategy(nlp) == "map" else "map"))
    measures, kkts = {}, {}
    for s in solvers:
        text, kkt = how(s)
        label = f"{args.solver}, solve_batch ({text})"
        measures[label], kkts[label] = batched(s), kkt
    return measures, kkts


def run_system(name, args) -> dict:
    system = load(name)
    tr = SETTINGS[args.transcription](args.grid)
    solver = BATCHED[args.solver]()
    params, x0 = make_batch(system, args.batch, args.spread, args.seed)
    subset = min(args.subset, args.batch)
    print(f"\n{name}, {tr!r}; batch {args.batch}: every parameter and x0 scaled by U({1 - args.spread:g}, "
          f"{1 + args.spread:g}) (seed {args.seed}); batched solver {solver!r}", flush=True)

    measures, kkts = _batched_rows(system, tr, solver, args, params, x0)
    main_row = next(iter(measures))
    measures["ipopt (cyipopt), one at a time"] = lambda: {
        **one_at_a_time(system, tr, Ipopt(), params, x0, subset), "n": subset}
    measures[CASADI] = lambda: {
        **casadi_one_at_a_time(system, name, args.transcription, args.grid, params, x0, subset), "n": subset}
    rows = _rounds(measures, args.repeat)
    _print_rates(rows, args.repeat)
    base = rows[main_row]
    _print_ratios(rows, base, args.batch, subset)
    members = _members(rows, subset)
    its = np.array(base["iterations"])
    print(f"  batched iterations per member: median {int(np.median(its))}, max {its.max()} (a vmapped loop runs "
          f"until its last member stops; a queue refills stopped members' places)", flush=True)
    return {"system": name, "transcription": repr(tr), "batch": args.batch, "subset": subset,
            "iterations_median": float(np.median(its)), "iterations_max": int(its.max()),
            "batched_kkt": kkts, "members": members,
            "rows": {k: {**{f: v for f, v in r.items() if f not in ("costs", "converged", "iterations", "status")},
                         "converged": int(sum(r["converged"])),
                         "iterations_median": float(np.median(r["iterations"])),
                         "iterations_max": int(max(r["iterations"]))} for k, r in rows.items()}}


def _head() -> str:
    """HEAD's short hash, with the files of runtime/ and compiler/ that differ from it (a shared work tree measures
    whatever is there, committed or not)."""
    def git(*argv) -> str:
        return subprocess.run(["git", "-C", str(ROOT), *argv], capture_output=True, text=True, timeout=10).stdout

    try:
        head = git("rev-parse", "--short", "HEAD").strip() or "?"
        dirty = [line[3:] for line in git("status", "--porcelain", "--", "runtime", "compiler").splitlines()]
    except (OSError, subprocess.SubprocessError):
        return "?"
    return head + (f" + uncommitted {', '.join(dirty)}" if dirty else "")


def _checked(argv) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", nargs="+", default=["mould_fungicide", "epidemic"], metavar="NAME")
    ap.add_argument("--solver", choices=list(BATCHED), default="interior_point", help="the batched solver")
    ap.add_argument("--transcription", default="single_shooting", choices=list(SETTINGS),
                    help="myriad's transcription (bench.casadi_transcriptions.SETTINGS: single shooting with Heun, "
                         "the published setting; multiple shooting with one RK4 step per interval)")
    ap.add_argument("--grid", type=int, default=100, help="intervals (controls, for single shooting)")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--subset", type=int, default=32, help="members solved one at a time (then extrapolated)")
    ap.add_argument("--spread", type=float, default=0.1, help="relative perturbation of parameters and x0")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--compare", action="store_true",
                    help="also the solver's other batch strategy (vmap against map), where it has one")
    ap.add_argument("--json", metavar="FILE", help="also write the records as JSON (atomically)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds: every row once a round, side by side")
    ap.add_argument("--host-devices", type=int, default=os.cpu_count() or 1,
                    help="host devices (threads) a CPU batch is spread over; 1 for one (read before JAX starts)")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.batch < 1 or args.subset < 1 or args.host_devices < 1:
        ap.error("--repeat, --batch, --subset and --host-devices must be at least 1")
    if args.grid < 2:
        ap.error(f"--grid {args.grid}: give at least 2 intervals, e.g. --grid 50")
    missing = [n for n in args.systems if not (ROOT / "specs" / f"{n}.yaml").is_file()]
    if missing:
        ap.error(f"--systems {' '.join(missing)}: no spec in specs/ (the CasADi row poses it from there); e.g. "
                 "--systems mould_fungicide epidemic")
    if args.json and not Path(args.json).resolve().parent.is_dir():
        ap.error(f"--json {args.json}: its folder does not exist; create it or choose another path")
    return args


def main(argv=None) -> int:
    from myriad.runtime.atomic import atomic_write_text

    args = _checked(argv)
    info = {"device": str(jax.devices()), "machine": _machine(), "head": _head(), "solver": args.solver,
            "transcription": args.transcription, "grid": args.grid, "spread": args.spread, "seed": args.seed,
            "load_before": list(os.getloadavg())}
    print(f"device: {jax.devices()} (jax {jax.__version__}); host CPU: {_machine()}; HEAD {info['head']}; load "
          f"average {' '.join(f'{x:.2f}' for x in info['load_before'])}")
    records = [run_system(name, args) for name in args.systems]
    info["load_after"] = list(os.getloadavg())
    print(f"load average after: {' '.join(f'{x:.2f}' for x in info['load_after'])}")
    if args.json:
        atomic_write_text(args.json, json.dumps({**info, "systems": records}, indent=1) + "\n")
    return 0 if all(math.isfinite(next(iter(r["rows"].values()))["problems_per_second"]) for r in records) else 1


if __name__ == "__main__":
    sys.exit(main())
