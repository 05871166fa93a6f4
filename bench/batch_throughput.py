"""Extragradient batch throughput: one NLP, a batch of problems that differ in parameters and initial state, solved
as one vmapped program (``solve_batch``) vs. one at a time (``solve(..., Extragradient(), resimulate=False)``), with
IPOPT one at a time for reference. Prints figures only.

The one-at-a-time rates are measured on the first ``--subset`` members and extrapolated to the whole batch (the
output says so). Compile time is reported separately and excluded from every rate. JAX's default device is used (a
GPU where there is one: that is where one vmapped program should pay off); set JAX_PLATFORMS=cpu to force the CPU.

Usage: python bench/batch_throughput.py [--system mould_fungicide] [--transcription trapezoidal] [--grid 50]
                                        [--batch 1024] [--subset 32] [--spread 0.1] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from myriad.runtime import load  # noqa: E402
from myriad.runtime.solve import solve, solve_batch  # noqa: E402
from myriad.runtime.solvers import Extragradient, Ipopt  # noqa: E402
from myriad.runtime.transcriptions import SingleShooting, Trapezoidal  # noqa: E402


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
    return {k: v[i] for k, v in params.items()}, x0[i]


def one_at_a_time(system, transcription, solver, params, x0, n):
    """Solve members 0..n-1 one by one; the first solve compiles (its compile time is returned separately)."""
    sols, compile_s, solve_s, wall = [], 0.0, 0.0, 0.0
    for i in range(n):
        p, x = member(params, x0, i)
        t0 = time.perf_counter()
        sol = solve(system, transcription, solver, params=p, x0=x, resimulate=False)
        elapsed = time.perf_counter() - t0
        compile_s += sol.compile_seconds
        solve_s += sol.solve_seconds
        wall += elapsed - sol.compile_seconds
        sols.append(sol)
    return sols, compile_s, solve_s, wall


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--system", default="mould_fungicide")
    ap.add_argument("--transcription", default="trapezoidal", choices=["trapezoidal", "single_shooting"])
    ap.add_argument("--grid", type=int, default=50, help="intervals (trapezoidal) or controls (single shooting)")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--subset", type=int, default=32, help="members solved one at a time (then extrapolated)")
    ap.add_argument("--spread", type=float, default=0.1, help="relative perturbation of parameters and x0")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)

    system = load(args.system)
    tr = (Trapezoidal(intervals=args.grid) if args.transcription == "trapezoidal"
          else SingleShooting(controls=args.grid))
    eg = Extragradient()
    params, x0 = make_batch(system, args.batch, args.spread, args.seed)
    subset = min(args.subset, args.batch)
    print(f"device: {jax.devices()} (jax {jax.__version__}, {os.cpu_count()} CPUs visible)")
    print(f"system {args.system}, {tr!r}; batch {args.batch}: every parameter and x0 scaled by "
          f"U({1 - args.spread:g}, {1 + args.spread:g}) (seed {args.seed}); solver {eg!r}")

    # Batched: one vmapped program. compile_seconds/solve_seconds of each result are the batch totals / B.
    t0 = time.perf_counter()
    batch = solve_batch(system, tr, eg, params=params, x0=x0)
    wall_b = time.perf_counter() - t0
    compile_b = sum(s.compile_seconds for s in batch)
    solve_b = sum(s.solve_seconds for s in batch)
    its_b = np.array([s.iterations for s in batch])
    conv_b = sum(s.converged for s in batch)

    # One at a time, Extragradient and IPOPT, on the first `subset` members.
    seq, compile_s, solve_s, wall_s = one_at_a_time(system, tr, eg, params, x0, subset)
    ipo, compile_i, solve_i, wall_i = one_at_a_time(system, tr, Ipopt(), params, x0, subset)

    rate_b = args.batch / solve_b
    rate_s, rate_i = subset / solve_s, subset / solve_i
    # Wall-clock rates exclude compilation but include everything else a caller waits for (data preparation, the
    # per-member results, Python overhead).
    wall_rate_b = args.batch / (wall_b - compile_b)
    wall_rate_s, wall_rate_i = subset / wall_s, subset / wall_i
    same = [abs(a.cost - b.cost) / max(abs(b.cost), 1e-12) for a, b in zip(seq, batch)]
    vs_ipopt = [abs(a.cost - b.cost) / max(abs(b.cost), 1e-12)
                for a, b in zip(batch, ipo) if a.converged and b.converged]

    print()
    print(f"{'':36s} {'problems/s':>11s} {'problems/s':>11s} {'solve s':>9s} {'compile s':>10s} {'converged':>12s}")
    print(f"{'':36s} {'(solve)':>11s} {'(wall)':>11s}")
    rows = [
        ("extragradient, solve_batch (vmap)", rate_b, wall_rate_b, solve_b, compile_b, conv_b, args.batch),
        ("extragradient, one at a time", rate_s, wall_rate_s, solve_s, compile_s, sum(s.converged for s in seq),
         subset),
        ("ipopt, one at a time", rate_i, wall_rate_i, solve_i, compile_i, sum(s.converged for s in ipo), subset),
    ]
    for label, r, w, t, c, k, n in rows:
        print(f"{label:36s} {r:11.1f} {w:11.1f} {t:9.2f} {c:10.2f} {k:5d}/{n:<6d}")
    print()
    print(f"speed-up of solve_batch over extragradient one at a time: {rate_b / rate_s:.2f}x on solve time, "
          f"{wall_rate_b / wall_rate_s:.2f}x on wall time (over IPOPT one at a time: {rate_b / rate_i:.2f}x, "
          f"{wall_rate_b / wall_rate_i:.2f}x)")
    print(f"one-at-a-time figures: {subset} of {args.batch} members, extrapolated: {args.batch} problems would take "
          f"{args.batch / rate_s:.3g} s (extragradient) and {args.batch / rate_i:.3g} s (IPOPT) of solve time; "
          f"wall time per solve incl. Python overhead: {wall_s / subset * 1e3:.1f} ms and "
          f"{wall_i / subset * 1e3:.1f} ms")
    print(f"solve_batch wall time {wall_b:.2f} s (incl. compile and per-member result assembly); extragradient "
          f"iterations per member: median {int(np.median(its_b))}, max {its_b.max()} (the vmapped loop runs max "
          f"iterations for all {args.batch})")
    print(f"batched vs. single extragradient cost (same members): max relative difference {max(same):.1e}")
    if vs_ipopt:
        print(f"extragradient vs. IPOPT cost (converged pairs, first {subset}): max relative difference "
              f"{max(vs_ipopt):.1e}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({
                "device": str(jax.devices()), "system": args.system, "transcription": repr(tr), "batch": args.batch,
                "subset": subset, "spread": args.spread, "seed": args.seed,
                "batched": {"problems_per_second": rate_b, "solve_seconds": solve_b, "compile_seconds": compile_b,
                            "wall_seconds": wall_b, "wall_problems_per_second": wall_rate_b, "converged": int(conv_b),
                            "iterations_median": int(np.median(its_b)), "iterations_max": int(its_b.max())},
                "sequential_extragradient": {"problems_per_second": rate_s, "solve_seconds": solve_s,
                                             "compile_seconds": compile_s, "wall_problems_per_second": wall_rate_s,
                                             "converged": int(sum(s.converged for s in seq))},
                "sequential_ipopt": {"problems_per_second": rate_i, "solve_seconds": solve_i,
                                     "compile_seconds": compile_i, "wall_problems_per_second": wall_rate_i,
                                     "converged": int(sum(s.converged for s in ipo))},
                "speedup": rate_b / rate_s,
                "max_rel_diff_batched_vs_single": max(same),
                "max_rel_diff_vs_ipopt": max(vs_ipopt) if vs_ipopt else None,
            }, fh, indent=1)
    return 0 if math.isfinite(rate_b) else 1


if __name__ == "__main__":
    sys.exit(main())
