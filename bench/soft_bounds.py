"""Elastic final-state bounds leave a feasible optimum where it was: every spec with bounded final states, IPOPT,
the published setting, hard rows against ``SingleShooting(soft_state_bounds=c max(1, |J*|))``.

    python -m bench.soft_bounds [--factor C ...]

Prints the relative change of the cost per spec and factor (default c = 10, the factor end-to-end learning uses on
request, and 100); the change is the slacks' barrier residue at IPOPT's tolerance, not a moved optimum.
"""

from __future__ import annotations

import argparse
import os
import sys

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])


from myriad.runtime import load, systems
from myriad.runtime.solve import solve
from myriad.runtime.solvers import Ipopt
from myriad.runtime.transcriptions import SingleShooting
from myriad.runtime.transcriptions.nlp_parts import bounded_free_states


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--factor", type=float, nargs="+", default=[10.0, 100.0], metavar="C")
    args = ap.parse_args()
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(f"{'system':22s} {'hard cost':>16s} " + " ".join(f"{f'c={c:g} rel change':>18s}" for c in args.factor))
    worst = {c: 0.0 for c in args.factor}
    for name in sorted(systems.MODULES):
        system = load(name)
        if bounded_free_states(system).size == 0:
            continue
        hard = solve(system, SingleShooting(), Ipopt(), resimulate=False)
        J = float(hard.cost)
        cells = []
        for c in args.factor:
            soft = solve(system, SingleShooting(soft_state_bounds=c * max(1.0, abs(J))), Ipopt(), resimulate=False)
            rel = abs(float(soft.cost) - J) / max(1.0, abs(J))
            worst[c] = max(worst[c], rel if soft.converged else float("inf"))
            cells.append(f"{rel:18.1e}" + ("" if soft.converged else f" ({soft.status})"))
        print(f"{system.name:22s} {J:16.10g} " + " ".join(cells))
    print("largest relative change: " + ", ".join(f"c = {c:g}: {w:.1e}" for c, w in worst.items()))


if __name__ == "__main__":
    main()
