"""Mesh refinement (``solve(..., tolerance=TOL)``) with every direct transcription: the levels (intervals, error
estimate, cost, seconds) and the final accuracy (cost against the best known optimum, the re-simulated final-state
defect). Prints figures only.

Default systems: the hyper-sensitive problem (tests/runtime/specs/hypersensitive.yaml, T = 10000, boundary layers
at both ends, published J* = 3.3620563) and three shipped ones with smooth solutions (van_der_pol, cancer_treatment,
mountain_car). ``--peers`` runs the 14 problems of ``specs/peers/`` instead and judges each (``--check``, default
10 x the tolerance): "ok" where refinement met the tolerance within the check of the best known optimum, "could not"
with refinement's reason where it stopped before the tolerance, and "WRONG" (exit 1) where it met the tolerance but
lands farther off: a silent wrong answer. The best known optimum is the published one, or an independent fine-grid
solve (BEST_KNOWN) where the published figure has fewer digits than the check needs.

``--fine-grid N1 N2 N3`` makes that independent figure: one uniform solve per N (no refinement), the observed order
p = log2((J1 - J2) / (J2 - J3)) on grids that double, and the Richardson extrapolation
J* = J3 + (J3 - J2) / (2^p - 1), with |J* - J3| as its uncertainty.

Each level compiles its NLP once (new shapes): the seconds are mostly compilation.

Usage: python -m bench.mesh_refinement [--systems NAME|PATH ... | --peers [NAME ...]] [--transcriptions NAME ...]
                                       [--intervals N] [--tolerance 1e-6] [--max-refinements 10]
                                       [--max-intervals N] [--check RTOL] [--fine-grid N1 N2 N3] [--json FILE]
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
from myriad.runtime.atomic import atomic_write_text
from myriad.runtime.solve import solve
from myriad.runtime.systems import peers
from myriad.runtime.transcriptions import TRANSCRIPTIONS

HYPER = str(Path(__file__).resolve().parent.parent / "tests" / "runtime" / "specs" / "hypersensitive.yaml")
DEFAULT_SYSTEMS = [HYPER, "van_der_pol", "cancer_treatment", "mountain_car"]

# Peers whose published optimum has fewer digits than a 1e-5 check needs: an independent figure, with how it was made
# (docs/notes/2026-12-06-peer-tolerance.md has the runs). Every other peer is judged against reference.published.
BEST_KNOWN: dict[str, tuple[float, str]] = {
    "brachistochrone": (1.8016033, "Hermite-Simpson N = 200, 400, 800 agree to 4e-9"),
    "catalyst_mixing": (-0.048055685860877, "three phases: u = 1, singular u = 0.227142, u = 0"),
    "goddard_rocket": (-1.0128369177, "three phases: full thrust, singular (Chebyshev), coast"),
    "hanging_chain": (5.068480111, "the catenary (analytic)"),
    "lotka_volterra_fishing": (1.3440812, "three phases: w = 0, w = 1, singular (Chebyshev)"),
    "particle_steering": (0.55457087812, "Hermite-Simpson N = 200, 400, 800 agree to 4e-10"),
    "robot_arm": (9.1409117459, "bang-bang by switching times"),
}


def best_known(system) -> tuple[float | None, str]:
    """The best known continuous optimum of ``system`` and its source."""
    name = system.name
    if name in BEST_KNOWN:
        return BEST_KNOWN[name]
    published = (system.reference or {}).get("published")
    return (None, "-") if published is None else (float(published), "published")


def run(target: str, method: str, intervals: int, tolerance: float, max_refinements: int,
        max_intervals: int = 2000) -> dict:
    system = load(target)
    start = time.perf_counter()
    try:
        sol = solve(system, TRANSCRIPTIONS[method].on_grid(intervals), tolerance=tolerance,
                    max_refinements=max_refinements, max_intervals=max_intervals)
    except Exception as exc:  # a bench row, not a crash: say what failed
        return {"system": system.name, "transcription": method, "error": f"{type(exc).__name__}: {exc}"}
    best, source = best_known(system)
    return {
        "system": system.name, "transcription": method, "seconds": time.perf_counter() - start,
        "published": (system.reference or {}).get("published"), "best_known": best, "source": source,
        "record": sol.record(),
        "relative_gap": None if best is None else (sol.cost - best) / max(abs(best), 1e-300),
        "max_simulated_defect": max((abs(d) for d in sol.simulated_defect), default=0.0),
    }


def verdict(row: dict, check: float) -> str:
    """"ok", "could not: <reason>" (refinement stopped before the tolerance, and said so) or "WRONG: ..." (it met
    the tolerance but the cost is more than ``check`` off the best known optimum: a silent wrong answer)."""
    if "error" in row:
        return f"could not: {row['error']}"
    ref = row["record"]["refinement"]
    if not ref["met"]:
        return f"could not: {ref['reason']}"
    gap = row["relative_gap"]
    if gap is None:
        return "ok (no best known optimum to compare)"
    return "ok" if abs(gap) <= check else f"WRONG: met the tolerance {abs(gap):.1e} off the best known optimum"


def fine_grid(target: str, method: str, grids: list[int]) -> dict:
    """Uniform solves on grids that double, the observed order and the Richardson extrapolation (module docstring)."""
    system = load(target)
    costs, seconds = [], []
    for n in grids:
        start = time.perf_counter()
        sol = solve(system, TRANSCRIPTIONS[method].on_grid(n))
        costs.append(float(sol.cost) if sol.converged else math.nan)
        seconds.append(time.perf_counter() - start)
        print(f"{system.name:<28} {method} N={n:<5} cost={costs[-1]!r} converged={sol.converged} "
              f"{seconds[-1]:.1f}s", flush=True)
    j1, j2, j3 = costs[-3:]
    ratio = (j1 - j2) / (j2 - j3) if j2 != j3 else math.inf
    order = math.log2(ratio) if ratio > 1 else math.nan
    # Without an order (the differences do not shrink geometrically) nothing is extrapolated: the finest cost, as
    # uncertain as its last change.
    extrapolated = j3 + (j3 - j2) / (2.0 ** order - 1.0) if math.isfinite(order) else j3
    spread = abs(extrapolated - j3) if math.isfinite(order) else abs(j3 - j2)
    return {"system": system.name, "transcription": method, "grids": grids, "costs": costs, "seconds": seconds,
            "observed_order": order, "extrapolated": extrapolated,
            "uncertainty": spread / max(abs(extrapolated), 1e-300)}


def _fmt(v, spec=".3g"):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def report(row: dict, check: float | None = None) -> None:
    if "error" in row:
        print(f"{row['system']:<18} {row['transcription']:<18} FAILED: {row['error']}")
        return
    rec = row["record"]
    ref = rec["refinement"]
    levels = "  ".join(f"{lv['intervals']}:{_fmt(lv['error'], '.1e')}/{_fmt(lv['cost'], '.10g')}/{lv['seconds']:.1f}s"
                       for lv in ref["history"])
    print(f"{row['system']:<18} {row['transcription']:<18} met={ref['met']!s:<5} N={rec['intervals']:<5} "
          f"err={_fmt(rec['error_estimate'], '.1e')} cost={_fmt(rec['cost'], '.10g')} "
          f"best={_fmt(row['best_known'], '.10g')} ({row['source']}) gap={_fmt(row['relative_gap'], '.1e')} "
          f"sim.defect={_fmt(row['max_simulated_defect'], '.1e')} {row['seconds']:.1f}s")
    print(f"{'':<38}levels (intervals:error/cost/seconds): {levels}")
    if not ref["met"]:
        print(f"{'':<38}stopped: {ref['reason']}")
    if check is not None:
        print(f"{'':<38}verdict (within {check:g} of the best known): {verdict(row, check)}")


def table(rows: list[dict], check: float) -> str:
    """The peer rows as a markdown table, each judged (:func:`verdict`) against the current BEST_KNOWN: a table
    re-made from earlier runs' JSON (``--table``) sees a best known figure found since."""
    lines = ["| problem | cost | best known | source | relative gap | verdict | grids (first, last) | seconds |",
             "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        if "record" in row:
            best, source = BEST_KNOWN.get(row["system"], (row["published"], "published"))
            row = row | {"best_known": best, "source": source,
                         "relative_gap": (row["record"]["cost"] - best) / abs(best)}
            cells = [f"{row['record']['cost']:.10g}", f"{best:.10g}", source, f"{row['relative_gap']:.1e}",
                     verdict(row, check), f"{row['record']['refinement']['history'][0]['intervals']}, "
                     f"{row['record']['intervals']}", f"{row['seconds']:.0f}"]
        else:
            cells = ["-", "-", "-", "-", verdict(row, check), "-", "-"]
        lines.append(f"| {row['system']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _targets(args, p) -> list[str]:
    if args.peers is None:
        return args.systems
    names = args.peers or list(peers.NAMES)
    unknown = [n for n in names if n not in peers.NAMES]
    if unknown:
        p.error(f"unknown peer problem(s) {', '.join(unknown)}; choose from {', '.join(peers.NAMES)}")
    return [f"peers/{n}" for n in names]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--systems", nargs="+", default=DEFAULT_SYSTEMS)
    p.add_argument("--peers", nargs="*", metavar="NAME", help="the peer problems (default all) instead of --systems")
    p.add_argument("--transcriptions", nargs="+", default=list(TRANSCRIPTIONS), choices=list(TRANSCRIPTIONS))
    p.add_argument("--intervals", type=int, default=50, help="the first, uniform grid (default 50)")
    p.add_argument("--tolerance", type=float, default=1e-6)
    p.add_argument("--max-refinements", type=int, default=10)
    p.add_argument("--max-intervals", type=int, default=2000)
    p.add_argument("--check", type=float, default=None, metavar="RTOL",
                   help="with --peers: the bar against the best known optimum (default 10 x the tolerance)")
    p.add_argument("--fine-grid", type=int, nargs=3, metavar="N",
                   help="uniform solves on three doubling grids and their Richardson extrapolation, no refinement")
    p.add_argument("--json", metavar="FILE")
    p.add_argument("--table", nargs="+", metavar="FILE",
                   help="solve nothing: the markdown table of the peer rows in these --json files, judged now")
    args = p.parse_args(argv)
    if args.table:
        rows = [row for path in args.table for row in json.loads(Path(path).read_text())]
        print(table(rows, args.check or 10 * args.tolerance), end="")
        return 0
    targets = _targets(args, p)
    if args.json and not Path(args.json).resolve().parent.is_dir():
        p.error(f"the folder of {args.json} does not exist: create it first")
    check = None if args.peers is None else (args.check or 10 * args.tolerance)
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, jax {jax.__version__}"
    rows = []
    if args.fine_grid:
        print(f"# uniform grids {args.fine_grid}, Richardson with the observed order; {machine}")
        for target in targets:
            for method in args.transcriptions:
                row = fine_grid(target, method, args.fine_grid)
                print(f"{row['system']:<28} order {_fmt(row['observed_order'])} extrapolated "
                      f"{row['extrapolated']!r} (uncertainty {row['uncertainty']:.1e})", flush=True)
                rows.append(row)
    else:
        print(f"# mesh refinement, tolerance {args.tolerance:g}, first grid {args.intervals} uniform intervals; "
              f"{machine}")
        for target in targets:
            for method in args.transcriptions:
                row = run(target, method, args.intervals, args.tolerance, args.max_refinements, args.max_intervals)
                report(row, check)
                sys.stdout.flush()
                rows.append(row | ({} if check is None else {"verdict": verdict(row, check)}))
    if args.json:
        atomic_write_text(args.json, json.dumps(rows, indent=1, default=str) + "\n")
    return 1 if check is not None and any(r["verdict"].startswith("WRONG") for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
