"""The re-simulation every solve reports, two adaptive integrators: diffrax's Tsit5 (``Adaptive``) against the
Dormand-Prince pair written for it (``DormandPrince``, ``runtime/integrators/dormand_prince.py``).

For each system: its published-setting controls (SingleShooting(100), Heun, IPOPT), re-simulated by each integrator
as ``myriad.runtime.solution.resimulate`` does (restarted at every node, rtol 1e-8): the seconds to trace and compile
the program (what a first run pays, once per system), the median run time over ``--repeat`` calls, and the relative
difference of the two re-simulated costs.

Usage: python -m bench.resimulation [--systems NAME ...] [--repeat R]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import jax.numpy as jnp

from myriad.runtime import load
from myriad.runtime.bench import PUBLISHED_SETTING
from myriad.runtime.integrators import Adaptive, DormandPrince
from myriad.runtime.simulate import _simulate
from myriad.runtime.solve import solve
from myriad.runtime.systems import NAMES


def measure(system, integrator, controls, repeat: int) -> tuple[float, float, float]:
    """(trace and compile seconds, median run seconds, re-simulated cost)."""
    params, x0 = system.default_params(jnp.float64), jnp.asarray(system.x0, dtype=jnp.float64)
    fn = jax.jit(lambda c, p, x: _simulate(system, integrator, c, p, x))
    start = time.perf_counter()
    executable = fn.lower(controls, params, x0).compile()
    compile_seconds = time.perf_counter() - start
    cost = float(executable(controls, params, x0).cost)
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        jax.block_until_ready(executable(controls, params, x0))
        runs.append(time.perf_counter() - start)
    return compile_seconds, statistics.median(runs), cost


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--systems", nargs="+", default=list(NAMES))
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    import diffrax  # noqa: F401  (its import is not part of a program's compile time)

    print(f"{'system':18s} {'compile Tsit5 s':>15s} {'compile DP s':>12s} {'run Tsit5 ms':>12s} {'run DP ms':>9s} "
          f"{'rel cost diff':>13s}")
    compiles, worst = [], 0.0
    for name in args.systems:
        system = load(name)
        controls = jnp.asarray(solve(system, PUBLISHED_SETTING, resimulate=False).controls)
        (ca, ra, a), (cb, rb, b) = (measure(system, integ, controls, args.repeat)
                                    for integ in (Adaptive(), DormandPrince()))
        diff = abs(a - b) / max(abs(a), 1e-12)
        worst = max(worst, diff)
        compiles.append((ca, cb))
        print(f"{name:18s} {ca:15.2f} {cb:12.2f} {ra * 1e3:12.2f} {rb * 1e3:9.2f} {diff:13.1e}", flush=True)
    tsit5, dp = (statistics.median(c[i] for c in compiles) for i in (0, 1))
    print(f"trace and compile, median over {len(compiles)} systems: Tsit5 {tsit5:.2f} s, Dormand-Prince {dp:.2f} s; "
          f"largest relative cost difference {worst:.1e}")


if __name__ == "__main__":
    main()
