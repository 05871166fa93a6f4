"""Batch throughput: one NLP, a batch of problems that differ in parameters and initial state, solved as one program
(``solve_batch`` with a pure-JAX solver) against one-at-a-time solves by myriad's IPOPT and by CasADi + IPOPT, all in
the same run. Prints figures only.

``solve_batch`` runs the batch as the solver's ``batch_strategy(nlp)`` says: InteriorPoint vmaps the members with
its stage-wise (Riccati) Newton step where the NLP allows one (single shooting here; on a CPU with
``InteriorPoint.batch_chunk()`` members in flight, each stopped member's place taken by the next) and otherwise maps
over them (``jax.lax.map``, one after another in one program, dense Newton steps) on a CPU, and vmaps them on an
accelerator;
``--compare`` adds a row with its other strategy, so what vectorising gains on this device is measured, not assumed.

The NLP is the published setting by default (single shooting, Heun, 100 control intervals), the one
``bench/casadi_peer.py`` builds in CasADi, so the CasADi row solves the same problems (parameters and x0 are nlpsol
parameters there). The one-at-a-time rates are measured on the first ``--subset`` members and extrapolated to the
whole batch (the output says so). Compile and build time is reported separately and excluded from every rate. JAX's
default device is used (a GPU where there is one); set JAX_PLATFORMS=cpu to force the CPU.

On a CPU the batch is spread over ``--host-devices`` host devices (default: the machine's cores; JAX sees one
unless ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` is set before it starts, which this script does), each
a thread solving its share: the one-at-a-time rows use one core, as IPOPT does.

Usage: python -m bench.batch_throughput [--systems mould_fungicide epidemic] [--solver interior_point]
                                        [--transcription single_shooting] [--grid 100] [--batch 1024]
                                        [--subset 32] [--spread 0.1] [--compare] [--host-devices N] [--repeat 3]
                                        [--json FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
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

from myriad.runtime import load
from myriad.runtime.integrators import Heun
from myriad.runtime.solve import solve, solve_batch
from myriad.runtime.solvers import Extragradient, InteriorPoint, Ipopt
from myriad.runtime.transcriptions import SingleShooting, Trapezoidal, control_scale, state_scale

ROOT = Path(__file__).resolve().parent.parent
BATCHED = {"interior_point": InteriorPoint, "extragradient": Extragradient}


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
    costs, converged, wall = [], [], 0.0
    for i in range(n):
        p, x = member(params, x0, i)
        t0 = time.perf_counter()
        sol = solve(system, transcription, solver, params=p, x0=x, resimulate=False)
        wall += time.perf_counter() - t0
        costs.append(sol.cost)
        converged.append(sol.converged)
    return {"costs": costs, "converged": converged, "compile_seconds": compile_s, "seconds": wall}


def casadi_one_at_a_time(system, name, params, x0, n):
    """The same members by CasADi + IPOPT (the published-setting NLP of bench/casadi_peer.py), one nlpsol call each."""
    from bench.casadi_peer import CasadiShooting, export_file  # after JAX chose its device: it defaults JAX to the CPU

    cs = export_file(ROOT / "specs" / f"{name}.yaml")
    t0 = time.perf_counter()
    peer = CasadiShooting(cs, control_scale(system), state_scale(system), dict(Ipopt().ipopt_options()))
    build = time.perf_counter() - t0
    nlp_z0 = None
    costs, converged, wall = [], [], 0.0
    for i in range(n):
        p, x = member(params, x0, i)
        peer.p = np.concatenate([cs.params_vector(p), x])
        if nlp_z0 is None:  # myriad's own starting point (the controls' initial guess), as in casadi_peer
            from myriad.runtime.solve import transcribe
            from myriad.runtime.transcriptions import default_data

            nlp_z0 = np.asarray(transcribe(system, SingleShooting(intervals=100, integrator=Heun()))
                                .initial_guess(default_data(system)), float)
        r = peer.solve(nlp_z0 / peer.s_u)
        wall += r["seconds"]
        costs.append(r["cost"])
        converged.append(r["converged"])
    return {"costs": costs, "converged": converged, "compile_seconds": build, "seconds": wall}


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
    """Each row's median rate, its range over the rounds, compile time and convergence (the medians go into rows)."""
    print(f"{'':36s} {'problems/s':>11s} {'(range)':>15s} {'compile s':>10s} {'converged':>12s}  (median of "
          f"{repeat} rounds; warm, Python overhead included; compile s: the first, untimed call)")
    for label, r in rows.items():
        rates = [r["n"] / sec for sec in r["round_seconds"]]
        r["seconds"] = float(np.median(r["round_seconds"]))
        r["problems_per_second"] = r["n"] / r["seconds"]
        spread = f"{min(rates):.1f}-{max(rates):.1f}"
        print(f"{label:36s} {r['problems_per_second']:11.1f} {spread:>15s} {r['compile_seconds']:10.2f} "
              f"{sum(r['converged']):5d}/{r['n']:<6d}")


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


def run_system(name, args) -> dict:
    system = load(name)
    tr = (Trapezoidal(intervals=args.grid) if args.transcription == "trapezoidal"
          else SingleShooting(intervals=args.grid, integrator=Heun()))
    solver = BATCHED[args.solver]()
    params, x0 = make_batch(system, args.batch, args.spread, args.seed)
    subset = min(args.subset, args.batch)
    print(f"\n{name}, {tr!r}; batch {args.batch}: every parameter and x0 scaled by U({1 - args.spread:g}, "
          f"{1 + args.spread:g}) (seed {args.seed}); batched solver {solver!r}", flush=True)

    # Batched: one program (vmapped or mapped: the solver's batch_strategy). The first call compiles and traces (a
    # batch of other members, same shape: the "compile s" column is its whole wall time); later calls are timed, from
    # the host's arrays to the B Solutions.
    warm_p, warm_x = make_batch(system, args.batch, args.spread, args.seed + 1)

    def batched(s):
        t0 = time.perf_counter()
        solve_batch(system, tr, s, params=warm_p, x0=warm_x)
        compile_s = time.perf_counter() - t0

        def measure():
            t0 = time.perf_counter()
            out = solve_batch(system, tr, s, params=params, x0=x0)
            return {"costs": [m.cost for m in out], "converged": [m.converged for m in out],
                    "iterations": [m.iterations for m in out], "compile_seconds": compile_s,
                    "seconds": time.perf_counter() - t0, "n": args.batch}
        return measure

    from myriad.runtime.solve import transcribe

    nlp = transcribe(system, tr)
    def how(s) -> str:
        """The row's label: vmapped (at once, in chunks, or as a queue that refills stopped members' places) or
        mapped."""
        strategy, chunk = s.batch_strategy(nlp), s.batch_chunk(nlp)
        if strategy != "vmap" or chunk is None:
            return strategy
        return f"vmap, {chunk} in flight" if s.batch_stepper(nlp) is not None else f"vmap, chunks of {chunk}"

    strategy = solver.batch_strategy(nlp)
    main_row = f"{args.solver}, solve_batch ({how(solver)})"
    measures = {main_row: batched(solver)}
    if args.compare and hasattr(solver, "batch"):
        other = dataclasses.replace(solver, batch="vmap" if strategy == "map" else "map")
        measures[f"{args.solver}, solve_batch ({how(other)})"] = batched(other)
    measures["ipopt (cyipopt), one at a time"] = lambda: {
        **one_at_a_time(system, tr, Ipopt(), params, x0, subset), "n": subset}
    published = args.transcription == "single_shooting" and args.grid == 100
    if published:
        measures["CasADi + IPOPT, one at a time"] = lambda: {
            **casadi_one_at_a_time(system, name, params, x0, subset), "n": subset}
    rows = _rounds(measures, args.repeat)
    _print_rates(rows, args.repeat)
    base = rows[main_row]
    _print_ratios(rows, base, args.batch, subset)
    if not published:
        print("  (no CasADi row: it poses the published setting only, --transcription single_shooting --grid 100)")
    its = np.array(base["iterations"])
    print(f"  batched iterations per member: median {int(np.median(its))}, max {its.max()} (a vmapped loop runs "
          f"until its last member stops; a queue refills stopped members' places)", flush=True)
    return {"system": name, "transcription": repr(tr), "batch": args.batch, "subset": subset,
            "iterations_median": float(np.median(its)), "iterations_max": int(its.max()),
            "rows": {k: {**{f: v for f, v in r.items() if f not in ("costs", "converged", "iterations")},
                         "converged": int(sum(r["converged"]))} for k, r in rows.items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", nargs="+", default=["mould_fungicide", "epidemic"], metavar="NAME")
    ap.add_argument("--solver", choices=list(BATCHED), default="interior_point", help="the batched solver")
    ap.add_argument("--transcription", default="single_shooting", choices=["single_shooting", "trapezoidal"],
                    help="single shooting uses Heun (the published setting)")
    ap.add_argument("--grid", type=int, default=100, help="intervals (trapezoidal) or controls (single shooting)")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--subset", type=int, default=32, help="members solved one at a time (then extrapolated)")
    ap.add_argument("--spread", type=float, default=0.1, help="relative perturbation of parameters and x0")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--compare", action="store_true",
                    help="also the solver's other batch strategy (vmap against map), where it has one")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--repeat", type=int, default=3, help="rounds: every row once a round, side by side")
    ap.add_argument("--host-devices", type=int, default=os.cpu_count() or 1,
                    help="host devices (threads) a CPU batch is spread over; 1 for one (read before JAX starts)")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.batch < 1 or args.subset < 1 or args.host_devices < 1:
        ap.error("--repeat, --batch, --subset and --host-devices must be at least 1")
    print(f"device: {jax.devices()} (jax {jax.__version__}); host CPU: {_machine()}")
    records = [run_system(name, args) for name in args.systems]
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"device": str(jax.devices()), "machine": _machine(), "solver": args.solver,
                       "spread": args.spread, "seed": args.seed, "systems": records}, fh, indent=1)
    return 0 if all(math.isfinite(next(iter(r["rows"].values()))["problems_per_second"]) for r in records) else 1


if __name__ == "__main__":
    sys.exit(main())
