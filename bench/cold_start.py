"""The cold start (issue 31): how long a new user waits, each figure over fresh processes.

    myriad --help                                  goal < 0.3 s
    python -c "import myriad.runtime"              goal < 1 s
    myriad solve SPEC            (IPOPT)           goal < 3 s from empty caches
    myriad solve SPEC --solver interior_point      goal < 5 s from empty caches

SPEC is a two-state spec no cache has seen (a two-compartment dosing problem, written to a temporary folder; or
--spec PATH). "cold" runs get a new, empty cache folder each (``$MYRIAD_JAX_CACHE``: JAX's compilation cache and the
program store; ``$MYRIAD_CACHE``: the specs compiled by path); "warm" runs share one that a first, uncounted run
filled. Each row prints the min and median wall seconds and CPU seconds (user + system of the child, which a busy
machine inflates less than the wall time) of --repeat runs, beside the machine and its load average.

Usage: python -m bench.cold_start [--repeat N] [--spec PATH] [--no-solve]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

# A two-compartment pharmacokinetic model: infuse a drug into the central compartment, which exchanges it with a
# peripheral one and eliminates it; hold the central concentration near a target with the least infusion.
DOSING_SPEC = """\
schema: 1
name: two_compartment_dosing
title: Two-compartment dosing
description: Hold the central drug concentration near a target with the least infusion.
source: a textbook two-compartment pharmacokinetic model
parameters:
  k12: {value: 0.6, description: central to peripheral rate}
  k21: {value: 0.3, description: peripheral to central rate}
  k10: {value: 0.4, description: elimination rate}
  c_target: {value: 2.0, description: target central concentration}
  w: {value: 0.5, description: weight on the infusion}
states:
  c1: {initial: 0, bounds: [0, 10], description: central concentration}
  c2: {initial: 0, bounds: [0, 10], description: peripheral concentration}
controls:
  u: {bounds: [0, 5], description: infusion rate}
dynamics:
  c1: -(k12 + k10)*c1 + k21*c2 + u
  c2: k12*c1 - k21*c2
cost:
  sense: minimize
  running: (c1 - c_target)**2 + w*u**2
horizon: 6
"""


def machine() -> str:
    cpu = "unknown CPU"
    if Path("/proc/cpuinfo").exists():
        with open("/proc/cpuinfo") as fh:
            cpu = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), cpu)
    return f"{cpu}, {os.cpu_count()} cores"


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def _myriad() -> list[str]:
    """The installed `myriad` command beside this Python, as a user runs it; else the module."""
    script = Path(sys.executable).with_name("myriad")
    return [str(script)] if script.exists() else [sys.executable, "-m", "myriad.runtime.cli"]


def run_once(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """One fresh process: (wall seconds, CPU seconds of the child); a failure stops the bench with its output."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"cold_start: {' '.join(argv)} exited {done.returncode}:\n{done.stdout}{done.stderr}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _cases(spec: Path, solve: bool) -> list[tuple[str, list[str], str | None, float]]:
    """(label, argv, cache: "cold" / "warm" / None, goal in wall seconds)."""
    cases = [("myriad --help", [*_myriad(), "--help"], None, 0.3),
             ("import myriad.runtime", [sys.executable, "-c", "import myriad.runtime"], None, 1.0)]
    if solve:
        for cache in ("cold", "warm"):
            cases.append((f"myriad solve SPEC ({cache})", [*_myriad(), "solve", str(spec)], cache,
                          3.0 if cache == "cold" else float("nan")))
            cases.append((f"myriad solve SPEC --solver interior_point ({cache})",
                          [*_myriad(), "solve", str(spec), "--solver", "interior_point"], cache,
                          5.0 if cache == "cold" else float("nan")))
    return cases


def measure(argv: list[str], cache: str | None, repeat: int, scratch: Path) -> list[tuple[float, float]]:
    env = dict(os.environ)
    env.setdefault("JAX_PLATFORMS", "cpu")
    runs = []
    if cache == "warm":  # one folder for every run; the run that fills it is not counted
        folder = tempfile.mkdtemp(dir=scratch)
        env.update(MYRIAD_JAX_CACHE=os.path.join(folder, "jax"), MYRIAD_CACHE=folder)
        run_once(argv, env)
    for _ in range(repeat):
        if cache == "cold":  # a new, empty folder for each run
            folder = tempfile.mkdtemp(dir=scratch)
            env.update(MYRIAD_JAX_CACHE=os.path.join(folder, "jax"), MYRIAD_CACHE=folder)
        runs.append(run_once(argv, env))
    return runs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5, metavar="N", help="fresh processes per row (default 5)")
    parser.add_argument("--spec", type=Path, metavar="PATH", help="the spec to solve (default: a new two-state "
                                                                  "dosing spec in a temporary folder)")
    parser.add_argument("--no-solve", action="store_true", help="only --help and the import")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    if args.spec is not None and not args.spec.is_file():
        parser.error(f"--spec {args.spec}: no such file")
    print(f"machine: {machine()}; load average {_load()} (1, 5, 15 min) at the start")
    print(f"{'':52s} {'goal':>6s} {'wall min':>9s} {'median':>7s} {'cpu min':>8s} {'median':>7s}")
    with tempfile.TemporaryDirectory(prefix="myriad-cold-") as tmp:
        scratch = Path(tmp)
        spec = args.spec
        if spec is None:
            spec = scratch / "spec" / "two_compartment_dosing.yaml"
            spec.parent.mkdir()
            spec.write_text(DOSING_SPEC)
        (scratch / "caches").mkdir()
        for label, command, cache, goal in _cases(spec, not args.no_solve):
            runs = measure(command, cache, args.repeat, scratch / "caches")
            wall, cpu = [w for w, _ in runs], [c for _, c in runs]
            print(f"{label:52s} {'' if goal != goal else f'{goal:.1f}':>6s} {min(wall):9.2f} "
                  f"{statistics.median(wall):7.2f} {min(cpu):8.2f} {statistics.median(cpu):7.2f}", flush=True)
    print(f"load average {_load()} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
