"""Mesh refinement (``solve(..., tolerance=TOL)``) with every direct transcription: the levels (intervals, error
estimate, cost, seconds) and the final accuracy (cost against the published figure, the re-simulated final-state
defect). Prints figures only.

Default systems: the hyper-sensitive problem (tests/runtime/specs/hypersensitive.yaml, T = 10000, boundary layers
at both ends, published J* = 3.3620563) and three shipped ones with smooth solutions (van_der_pol, cancer_treatment,
mountain_car). Each level compiles its NLP once (new shapes): the seconds are mostly compilation.

Usage: python -m bench.mesh_refinement [--systems NAME|PATH ...] [--transcriptions NAME ...] [--intervals N]
                                       [--tolerance 1e-6] [--max-refinements 10] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import jax

from myriad.runtime import load
from myriad.runtime.solve import solve
from myriad.runtime.transcriptions import TRANSCRIPTIONS

HYPER = str(Path(__file__).resolve().parent.parent / "tests" / "runtime" / "specs" / "hypersensitive.yaml")
DEFAULT_SYSTEMS = [HYPER, "van_der_pol", "cancer_treatment", "mountain_car"]


def run(target: str, method: str, intervals: int, tolerance: float, max_refinements: int) -> dict:
    system = load(target)
    start = time.perf_counter()
    try:
        sol = solve(system, TRANSCRIPTIONS[method].on_grid(intervals), tolerance=tolerance,
                    max_refinements=max_refinements)
    except Exception as exc:  # a bench row, not a crash: say what failed
        return {"system": system.name, "transcription": method, "error": f"{type(exc).__name__}: {exc}"}
    published = (system.reference or {}).get("published")
    return {
        "system": system.name, "transcription": method, "seconds": time.perf_counter() - start,
        "published": published, "record": sol.record(),
        "relative_gap": None if published is None else (sol.cost - published) / abs(published),
        "max_simulated_defect": max((abs(d) for d in sol.simulated_defect), default=0.0),
    }


def _fmt(v, spec=".3g"):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def report(row: dict) -> None:
    if "error" in row:
        print(f"{row['system']:<18} {row['transcription']:<18} FAILED: {row['error']}")
        return
    rec = row["record"]
    ref = rec["refinement"]
    levels = "  ".join(f"{lv['intervals']}:{_fmt(lv['error'], '.1e')}/{_fmt(lv['cost'], '.6g')}/{lv['seconds']:.1f}s"
                       for lv in ref["history"])
    print(f"{row['system']:<18} {row['transcription']:<18} met={ref['met']!s:<5} N={rec['intervals']:<5} "
          f"err={_fmt(rec['error_estimate'], '.1e')} cost={_fmt(rec['cost'], '.8g')} "
          f"published={_fmt(row['published'], '.8g')} gap={_fmt(row['relative_gap'], '.1e')} "
          f"sim.defect={_fmt(row['max_simulated_defect'], '.1e')} {row['seconds']:.1f}s")
    print(f"{'':<38}levels (intervals:error/cost/seconds): {levels}")
    if not ref["met"]:
        print(f"{'':<38}stopped: {ref['reason']}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--systems", nargs="+", default=DEFAULT_SYSTEMS)
    p.add_argument("--transcriptions", nargs="+", default=list(TRANSCRIPTIONS), choices=list(TRANSCRIPTIONS))
    p.add_argument("--intervals", type=int, default=50, help="the first, uniform grid (default 50)")
    p.add_argument("--tolerance", type=float, default=1e-6)
    p.add_argument("--max-refinements", type=int, default=10)
    p.add_argument("--json", metavar="FILE")
    args = p.parse_args(argv)
    print(f"# mesh refinement, tolerance {args.tolerance:g}, first grid {args.intervals} uniform intervals; "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, jax {jax.__version__}")
    rows = []
    for target in args.systems:
        for method in args.transcriptions:
            row = run(target, method, args.intervals, args.tolerance, args.max_refinements)
            report(row)
            sys.stdout.flush()
            rows.append(row)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
