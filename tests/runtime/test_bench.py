"""The reference-table logic: what meets a target and which alternative counts as best (no solving here)."""

import dataclasses

import numpy as np
import pytest

from myriad.runtime.bench import BenchRow, _best, markdown_table, meets_target
from myriad.runtime.solve import Solution

BASE = Solution(system="s", transcription="single_shooting", solver="ipopt", integrator="heun", times=np.zeros(2),
                states=np.zeros((2, 1)), controls=np.zeros((2, 1)), cost=10.0, defect=[], converged=True, status=0,
                message="ok", iterations=3, constraint_violation=0.0, simulated_cost=10.0, simulated_defect=[],
                simulated_bound_violation=0.0)


def test_meets_target_needs_convergence_cost_and_defect():
    assert meets_target(BASE, 10.0)
    assert meets_target(dataclasses.replace(BASE, cost=10.05 - 1e-9), 10.0)  # target + 0.5 % of its magnitude
    assert not meets_target(dataclasses.replace(BASE, cost=10.06), 10.0)
    assert meets_target(dataclasses.replace(BASE, cost=-7.98), -7.98)
    assert not meets_target(dataclasses.replace(BASE, defect=[2e-6]), 10.0)
    assert not meets_target(dataclasses.replace(BASE, converged=False), 10.0)
    assert meets_target(BASE, None) is None


def test_best_ignores_failed_solves_and_missed_final_values():
    cheap_but_missing = dataclasses.replace(BASE, simulated_cost=5.0, simulated_defect=[1.2])
    failed = dataclasses.replace(BASE, simulated_cost=1.0, converged=False)
    good = dataclasses.replace(BASE, transcription="hermite_simpson", simulated_cost=9.0, simulated_defect=[1e-6])
    assert _best([BASE, cheap_but_missing, failed, good]) is good
    # When nothing meets its final values, the closest one is reported.
    far = dataclasses.replace(BASE, simulated_defect=[3.0])
    assert _best([cheap_but_missing, far]) is cheap_but_missing
    assert _best([failed]) is None


def test_markdown_table_has_one_row_per_system():
    row = BenchRow("s", 10.0, 10.0, BASE, True, best=BASE)
    table = markdown_table([row, dataclasses.replace(row, system="t", meets=False)], total_seconds=1.0)
    lines = table.splitlines()
    assert lines[0].startswith("| system |") and lines[2].startswith("| s |") and lines[3].startswith("| t |")
    assert "| NO |" in lines[3]


def test_best_ignores_solutions_that_leave_a_bound_when_resimulated():
    overspent = dataclasses.replace(BASE, simulated_cost=1.0, simulated_bound_violation=0.01)
    assert _best([BASE, overspent]) is BASE


def test_resample_puts_a_solution_on_another_grid():
    from myriad.runtime import Trapezoidal, load
    from myriad.runtime.bench import _resample
    from myriad.runtime.transcriptions import default_data

    system = load("simple_case")
    t = np.linspace(0.0, 1.0, 101)
    sol = dataclasses.replace(BASE, times=t, states=(1 + t ** 2)[:, None], controls=np.sin(t)[:, None])
    tr = Trapezoidal(intervals=10)
    times, states, controls = tr.transcribe(system).unravel(_resample(system, tr, sol), default_data(system))
    np.testing.assert_allclose(np.asarray(states)[1:, 0], (1 + np.asarray(times) ** 2)[1:], atol=1e-4)
    np.testing.assert_allclose(np.asarray(controls)[:, 0], np.sin(np.asarray(times)), atol=1e-4)


@pytest.mark.slow
def test_worker_processes_give_the_rows_of_one_process_in_order():
    """Two spawned workers (what a first `myriad bench` on two cores uses) return the same rows, in the order asked,
    as solving in this process."""
    import pytest

    from myriad.runtime.bench import run_bench

    names = ["simple_case", "harvest", "mould_fungicide"]
    lines = []
    parallel = run_bench(names, alternatives=False, jobs=2, progress=lines.append)
    serial = run_bench(names, alternatives=False, jobs=1)
    assert [r.system for r in parallel] == names and len(lines) == len(names)
    for p, s in zip(parallel, serial):
        assert p.meets and p.main.converged and p.main.iterations == s.main.iterations
        np.testing.assert_allclose(p.main.cost, s.main.cost, rtol=1e-12)
        np.testing.assert_allclose(p.main.simulated_cost, s.main.simulated_cost, rtol=1e-12)
    with pytest.raises(ValueError, match="jobs"):
        run_bench(names, jobs=0)
