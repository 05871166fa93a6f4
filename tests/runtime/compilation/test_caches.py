"""clear_caches frees the machine code of every program the runtime kept (runtime/compilation/caches.py)."""

import os

import pytest

from myriad.runtime import Ipopt, Trapezoidal, load, solve
from myriad.runtime.compilation.caches import clear_caches
from myriad.runtime.transcriptions.base import transcribe


def _mappings() -> int:
    with open(f"/proc/{os.getpid()}/maps") as f:
        return sum(1 for _ in f)


@pytest.mark.skipif(not os.path.exists("/proc/self/maps"), reason="counts Linux memory mappings")
def test_clear_caches_unmaps_the_programs_a_solve_kept():
    solve(load("van_der_pol"), Trapezoidal(intervals=8), Ipopt(tol=1e-8))  # loads the libraries a solve maps once
    clear_caches()
    before = _mappings()
    solution = solve(load("van_der_pol"), Trapezoidal(intervals=10), Ipopt(tol=1e-8))
    assert solution.converged
    kept = _mappings() - before
    assert transcribe.cache_info().currsize == 1
    # Each XLA CPU program holds about three mappings: a solve keeps tens of programs (objective, constraints,
    # derivatives, trajectory, error estimate), and every one of them must go.
    assert kept > 30
    clear_caches()
    assert transcribe.cache_info().currsize == 0
    assert _mappings() - before < 0.1 * kept
    again = solve(load("van_der_pol"), Trapezoidal(intervals=10), Ipopt(tol=1e-8))
    assert again.cost == pytest.approx(solution.cost, rel=1e-12, abs=1e-12)
