"""Time `myriadc build` of all shipped specs (cold process, as a user runs it) and the in-process pipeline.

Usage: python -m bench.compile_specs [--repeat N]
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    specs = sorted((ROOT / "specs").glob("*.yaml"))
    cold = []
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "myriad.compiler", "build", "specs", "-o", out, "-q"], cwd=ROOT,
                           check=True)
            cold.append(time.perf_counter() - t0)
    from myriad.compiler import compile_file

    per_spec = {}
    t_all = time.perf_counter()
    for p in specs:
        t0 = time.perf_counter()
        compile_file(p)
        per_spec[p.stem] = time.perf_counter() - t0
    warm_total = time.perf_counter() - t_all
    print(f"specs: {len(specs)}")
    print(f"myriadc build specs/ (new process, incl. interpreter + sympy import): "
          f"min {min(cold):.2f} s, median {sorted(cold)[len(cold) // 2]:.2f} s over {len(cold)} runs")
    print(f"in-process pipeline, all specs: {warm_total:.2f} s")
    for name, secs in sorted(per_spec.items(), key=lambda kv: -kv[1])[:5]:
        print(f"  slowest: {name:18s} {secs * 1000:7.1f} ms")


if __name__ == "__main__":
    main()
