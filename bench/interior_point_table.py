"""InteriorPoint (pure JAX) against IPOPT on the 18 systems at the published setting, or at another transcription.

For each system: both solvers' cost, their relative difference, the largest difference of the required final values
(the defects ``x_N - x_final``), iterations, compile seconds and the warm solve time (the minimum over ``--repeat``
solves of the same NLP and data after the first; for InteriorPoint one dispatch of the compiled ``while_loop``).

The transcriptions: the published setting, ``myriad bench``'s three alternatives, or the three of the cross-check's
part (a) (``cross_check_*``: 200 control intervals, the settings of ``bench/cross_check.py``; ``--systems cross_check``
takes its 13 Lenhart systems and Van der Pol).

Usage: python -m bench.interior_point_table [--systems NAME ... | cross_check] [--transcription published|
       multiple_shooting|trapezoidal|hermite_simpson|cross_check_multiple_shooting|cross_check_trapezoidal|
       cross_check_hermite_simpson] [--repeat R] [--max-iter K]

``--repeat 0`` skips the warm timings (convergence and costs only).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# One OpenBLAS thread (before NumPy/SciPy load it): JAX's CPU LAPACK calls (InteriorPoint's Cholesky factorisations)
# go through SciPy's threaded OpenBLAS, and on the busy 2-core machine a 202 x 202 Cholesky measured a median 10 ms
# (worst 1.5 s) with its default threads against 1 ms (worst 16 ms) with one. IPOPT's own BLAS (Debian's
# openblas-serial) is single-threaded already. Set OPENBLAS_NUM_THREADS yourself to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


from bench.cross_check import METHODS_A, TRANSCRIPTION_SYSTEMS
from myriad.runtime import load, solve
from myriad.runtime.bench import ALTERNATIVES, PUBLISHED_SETTING
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.systems import NAMES

SETTINGS = {"published": PUBLISHED_SETTING, "multiple_shooting": ALTERNATIVES[0], "trapezoidal": ALTERNATIVES[1],
            "hermite_simpson": ALTERNATIVES[2],
            **{f"cross_check_{k}": v for k, v in METHODS_A.items() if k != "fbsm"}}


def warm_seconds(system, transcription, solver, repeat: int) -> float:
    if repeat < 1:
        return float("nan")
    return min(solve(system, transcription, solver, resimulate=False).solve_seconds for _ in range(repeat))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", nargs="*", default=sorted(NAMES))
    parser.add_argument("--transcription", choices=list(SETTINGS), default="published")
    parser.add_argument("--repeat", type=int, default=3, help="warm solves per solver (0: no timings)")
    parser.add_argument("--max-iter", type=int, default=InteriorPoint().max_iter, help="the interior point's limit")
    args = parser.parse_args()
    if args.systems == ["cross_check"]:
        args.systems = list(TRANSCRIPTION_SYSTEMS)
    transcription = SETTINGS[args.transcription]
    model = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
                 "unknown CPU") if os.path.exists("/proc/cpuinfo") else "unknown CPU"
    print(f"{args.transcription}: {transcription}; {model}, {os.cpu_count()} CPUs")
    print(f"{'system':18s} {'IPOPT cost':>16s} {'IP cost':>16s} {'rel diff':>9s} {'final diff':>10s} "
          f"{'it':>7s} {'status':>14s} {'compile s':>9s} {'IPOPT ms':>9s} {'IP ms':>8s} {'ratio':>6s}")
    ratios, agree = [], 0
    for name in args.systems:
        system = load(name)
        ref = solve(system, transcription, Ipopt(), resimulate=False)
        ip = solve(system, transcription, InteriorPoint(max_iter=args.max_iter), resimulate=False)
        rel = abs(ip.cost - ref.cost) / max(abs(ref.cost), 1e-300)
        final = max((abs(a - b) for a, b in zip(ip.defect, ref.defect)), default=0.0)
        t_ref = warm_seconds(system, transcription, Ipopt(), args.repeat)
        t_ip = warm_seconds(system, transcription, InteriorPoint(max_iter=args.max_iter), args.repeat)
        ratio = t_ip / t_ref
        ratios.append(ratio)
        ok = ref.converged and ip.converged and rel <= 1e-8 and final <= 1e-8
        agree += ok
        print(f"{name:18s} {ref.cost:16.10g} {ip.cost:16.10g} {rel:9.1e} {final:10.1e} "
              f"{ref.iterations:3d}/{ip.iterations:<3d} {str(ip.status):>14s} {ip.compile_seconds:9.1f} "
              f"{1e3 * t_ref:9.1f} {1e3 * t_ip:8.1f} {ratio:6.2f}{'' if ok else '  <- differs'}", flush=True)
    timed = [r for r in ratios if r == r]
    print(f"agree (both converged, cost to 1e-8 relative, final values to 1e-8): {agree}/{len(args.systems)}"
          + (f"; warm-time ratio InteriorPoint / IPOPT (myriad's cyipopt): median {statistics.median(timed):.2f}, "
             f"range {min(timed):.2f} to {max(timed):.2f}" if timed else ""))


if __name__ == "__main__":
    main()
