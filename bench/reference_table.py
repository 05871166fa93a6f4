"""The 18-system reference table in the published setting, timed as a user meets it: one fresh process, JIT included.

Prints per system the cold time (load + compile + solve + re-simulation), the compile and solve split, and the warm
solve time (the same problem solved again: no tracing, no compilation), then the totals against the 60 s goal.

Usage: python -m bench.reference_table [--systems NAME ...] [--no-resimulate]
"""

import argparse
import os
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import jax

from bench import STARTED
from myriad.runtime import Heun, Ipopt, SingleShooting, load, solve
from myriad.runtime.bench import meets_target
from myriad.runtime.systems import NAMES


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--systems", nargs="+", default=list(NAMES))
    ap.add_argument("--no-resimulate", action="store_true", help="skip the adaptive re-simulation")
    args = ap.parse_args()
    setting = SingleShooting(intervals=100, integrator=Heun())
    print(f"device: {jax.devices()[0].platform}; imports {time.perf_counter() - STARTED:.2f} s")
    print(f"{'system':18s} {'cost':>12s} {'target':>10s} {'meets':>5s} {'cold s':>7s} {'compile s':>9s} "
          f"{'solve s':>7s} {'warm s':>7s}")
    rows = []
    for name in args.systems:
        t0 = time.perf_counter()
        system = load(name)
        sol = solve(system, setting, Ipopt(), resimulate=not args.no_resimulate)
        cold = time.perf_counter() - t0
        t1 = time.perf_counter()
        warm_sol = solve(system, setting, Ipopt(), resimulate=False)
        warm = time.perf_counter() - t1
        assert warm_sol.compile_seconds == 0.0, "a warm solve must not compile"
        ok = meets_target(sol, system.reference.get("target"))
        rows.append((name, sol, cold, warm, ok))
        print(f"{name:18s} {sol.cost:12.6g} {system.reference.get('target', float('nan')):10.6g} "
              f"{'yes' if ok else 'NO':>5s} {cold:7.2f} {sol.compile_seconds:9.2f} {sol.solve_seconds:7.3f} "
              f"{warm:7.3f}", flush=True)
        if sol.accuracy_warning:  # only where the discretised and re-simulated answers disagree
            print(f"  warning: {name}: {sol.accuracy_warning}", flush=True)
    cold_total = sum(r[2] for r in rows)
    warm = sorted(r[3] for r in rows)
    print()
    print(f"systems meeting their target: {sum(1 for r in rows if r[4])} / {len(rows)}")
    print(f"table wall time (cold, JIT included, {len(rows)} systems): {cold_total:.1f} s "
          f"(process total incl. imports and warm re-solves: {time.perf_counter() - STARTED:.1f} s; goal: < 60 s)")
    print(f"warm solve: median {warm[len(warm) // 2]:.3f} s, max {warm[-1]:.3f} s, sum {sum(warm):.2f} s")


if __name__ == "__main__":
    main()
