"""Elastic final-state bounds leave a feasible optimum where it was: every spec with bounded final states, IPOPT,
the published setting, hard rows against ``SingleShooting(soft_state_bounds=c max(1, |J*|))``.

    python bench/soft_bounds.py [--factor C ...]

Prints the relative change of the cost per spec and factor (default c = 10, the factor end-to-end learning uses on
request, and 100); the change is the slacks' barrier residue at IPOPT's tolerance, not a moved optimum.
"""

from __future__ import annotations

import argparse
import os

import jax

jax.config.update("jax_enable_x64", True)

from myriad.runtime import load, systems  # noqa: E402
from myriad.runtime.solve import solve  # noqa: E402
from myriad.runtime.solvers import Ipopt  # noqa: E402
from myriad.runtime.transcriptions import SingleShooting  # noqa: E402
from myriad.runtime.transcriptions._common import bounded_free_states  # noqa: E402


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
