"""Non-uniform grids in every direct transcription, and mesh refinement (runtime/transcriptions/grid.py, refine.py).

Mathematics checked: on randomly graded grids the defects at the analytic solution vanish at each method's local
order and the solved optimum converges at its global order, as on uniform ones; refinement of the hyper-sensitive
problem (boundary layers at both ends of T = 10000) reaches the published optimum and its re-simulated final value.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import myriad.runtime
from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.data import default_data
from myriad.runtime.integrators import Heun
from myriad.runtime.solve import solve
from myriad.runtime.solvers import SLSQP
from myriad.runtime.transcriptions import (
    ForwardBackwardSweep,
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
)
from myriad.runtime.transcriptions.refine import MeshRefinement, refine_positions, split_counts

from .._nlp import _slope, _solve
from .._problems import Decay, DoubleIntegrator, ScalarLQ

SPECS = Path(__file__).parent.parent / "specs"


def _graded(intervals: int, refine: int = 1, seed: int = 0) -> tuple[float, ...]:
    """A random grid of ``intervals`` intervals (widths varying by a factor up to 3), each cut into ``refine``
    equal pieces: nested grids whose largest step halves when ``refine`` doubles."""
    widths = np.random.default_rng(seed).uniform(0.5, 1.5, intervals)
    base = np.concatenate([[0.0], np.cumsum(widths) / widths.sum()])
    base[-1] = 1.0
    return tuple(refine_positions(base, np.full(intervals, refine)))


# ---- the grid option ------------------------------------------------------------------------------------------------
def test_grids_are_checked_and_stored_as_hashable_tuples():
    tr = HermiteSimpson.on_grid([0.0, 0.25, 1.0])  # a list is accepted and stored as a tuple
    assert tr.intervals == 2 and tr.grid == (0.0, 0.25, 1.0) and hash(tr) == hash(HermiteSimpson.on_grid((0, 0.25, 1)))
    assert MultipleShooting.on_grid(_graded(3, 4), steps_per_interval=4).intervals == 3
    assert Trapezoidal.on_grid(5).grid is None  # an int is still the uniform grid
    for grid, match in [((0.0, 1.0, 0.5, 1.0), "strictly increasing; positions 1 and 2"),
                        ((0.1, 0.5, 1.0), "start at 0 and end at 1"), ((0.0, 0.5, 0.9), "start at 0 and end at 1"),
                        ((0.0, math.nan, 1.0), "non-finite"), ((0.0,), "intervals must be at least 1")]:
        with pytest.raises(ValueError, match=match):
            Trapezoidal.on_grid(grid)
    with pytest.raises(ValueError, match=r"the grid has 2 intervals but intervals = 100; build it with "
                                         r"SingleShooting.on_grid\(grid\)"):
        SingleShooting(grid=(0.0, 0.5, 1.0))
    with pytest.raises(ValueError, match="intervals \\* steps_per_interval = 1 \\* 5 = 5"):
        MultipleShooting(intervals=1, grid=(0.0, 0.5, 1.0))
    with pytest.raises(ValueError, match="cannot be cut into shooting intervals of 5 steps"):
        MultipleShooting().with_grid((0.0, 0.5, 1.0))


_MAKERS = {  # (transcription on a grid, problem, local order of the constraint residual (see test_transcriptions.py),
    # intervals of the coarsest graded grid: multiple shooting's O(S h^3) is asymptotic from 16 steps of 4)
    "single_shooting": (lambda g: SingleShooting.on_grid(g), DoubleIntegrator, 2, 8),
    "multiple_shooting": (lambda g: MultipleShooting.on_grid(g, steps_per_interval=4), ScalarLQ, 3, 16),
    "trapezoidal": (lambda g: Trapezoidal.on_grid(g), ScalarLQ, 3, 8),
    "hermite_simpson": (lambda g: HermiteSimpson.on_grid(g), ScalarLQ, 5, 8),
}


@pytest.mark.parametrize("method", list(_MAKERS))
def test_on_a_graded_grid_the_defects_vanish_at_the_method_order(method):
    make, problem, order, coarsest = _MAKERS[method]
    system = problem()
    data = default_data(system)
    errors, ns = [], (1, 2, 4)
    for r in ns:
        tr = make(_graded(coarsest, r))
        nlp = tr.transcribe(system)
        z = jnp.asarray(tr.sample(system, system.x_exact, system.u_exact))
        c, times = (np.asarray(a) for a in jax.jit(lambda z, d: (nlp.constraints(z, d), nlp.unravel(z, d)[0]))(z, data))
        errors.append(np.max(np.abs(c - nlp.c_lower)))
        nodes = times[::2] if method == "hermite_simpson" else times  # the half-step grid interleaves midpoints
        np.testing.assert_allclose(nodes, np.asarray(tr.grid) * system.horizon, rtol=0, atol=1e-15)
        if r == 1 and nlp.jacobian_sparsity is not None:
            # The declared pattern still holds every structural non-zero (checked at a random point).
            A = np.asarray(jax.jacfwd(nlp.constraints)(jnp.asarray(np.random.default_rng(1).normal(size=z.shape)),
                                                       data))
            declared = np.zeros(A.shape, dtype=bool)
            declared[nlp.jacobian_sparsity] = True
            assert not np.any((A != 0) & ~declared)
    assert abs(_slope(ns, errors) - order) <= 0.3, errors


@pytest.mark.parametrize("method", list(_MAKERS))
def test_an_explicit_uniform_grid_is_the_default_nlp(method):
    make, problem, _, _ = _MAKERS[method]
    system = problem()
    data = default_data(system)
    uniform = make(8)
    explicit = make(tuple(np.linspace(0.0, 1.0, 9)))
    assert uniform.grid is None and explicit != uniform
    z = jnp.asarray(uniform.sample(system, system.x_exact, system.u_exact))
    np.testing.assert_array_equal(np.asarray(explicit.sample(system, system.x_exact, system.u_exact)), np.asarray(z))
    a, b = (jax.jit(tr.transcribe(system).evaluate) for tr in (uniform, explicit))
    for fa, fb in zip(a(z, data), b(z, data)):
        np.testing.assert_allclose(np.asarray(fb), np.asarray(fa), rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("method, ns, order", [
    (lambda g: Trapezoidal.on_grid(g), (1, 2, 4), 2),
    (lambda g: HermiteSimpson.on_grid(g), (1, 2, 4), 4),
], ids=["trapezoidal", "hermite_simpson"])
def test_on_a_graded_grid_the_optimum_converges_at_the_method_order(method, ns, order):
    system = ScalarLQ()
    data = default_data(system)
    errors = []
    for r in ns:
        nlp = method(_graded(6, r, seed=2)).transcribe(system)
        z, at = _solve(nlp, data)
        errors.append(abs(float(at(z)[0]) - system.J_STAR))
    assert abs(_slope(ns, errors) - order) <= 0.5, errors


# ---- how refinement cuts ------------------------------------------------------------------------------------------
def test_split_counts_follow_the_local_order():
    tol = 1e-6
    e = np.array([0.5e-6, 2e-6, 2e-3, np.inf])
    # p = 4: local error O(h^5); n = ceil((e / (tol / 2))^(1/5)), at least 2, at most 6; infinite -> 6.
    np.testing.assert_array_equal(split_counts(e, tol, 4, 6), [1, 2, 6, 6])
    np.testing.assert_array_equal(split_counts(e, tol, 4, 4), [1, 2, 4, 4])
    # 2e-3 / 0.5e-6 = 4000: 4000^(1/5) = 5.25 -> 6 with p = 4; 4000^(1/3) = 15.9 -> capped at 6 with p = 2.
    assert split_counts(np.array([2e-3]), tol, 4, 10)[0] == 6
    # Order reduction: a parent of error 8e-6 cut in 2 gave 4e-6 (observed local order 1, not 5), so the next cut
    # assumes order 1: ceil(4e-6 / 0.5e-6) = 8, capped at 6; without the history it would be ceil(8^(1/5)) = 2.
    e = np.array([4e-6])
    assert split_counts(e, tol, 4, 6)[0] == 2
    assert split_counts(e, tol, 4, 6, parent_errors=np.array([8e-6]), pieces=np.array([2]))[0] == 6
    # No decrease after a cut: the lowest order too.
    assert split_counts(e, tol, 4, 6, parent_errors=np.array([3e-6]), pieces=np.array([2]))[0] == 6


def test_refined_positions_cut_each_interval_evenly():
    np.testing.assert_allclose(refine_positions(np.array([0.0, 0.5, 1.0]), np.array([1, 3])),
                               [0.0, 0.5, 2 / 3, 5 / 6, 1.0])
    # Multiple shooting: each new shooting interval keeps its S = 2 equal steps.
    np.testing.assert_allclose(refine_positions(np.array([0.0, 0.5, 1.0]), np.array([2, 1]), steps=2),
                               [0.0, 0.125, 0.25, 0.375, 0.5, 0.75, 1.0])


def test_refinement_options_are_checked_before_any_work():
    with pytest.raises(ValueError, match="max_refinements is only for mesh refinement"):
        solve(ScalarLQ(), Trapezoidal(intervals=4), max_refinements=3)
    with pytest.raises(ValueError, match="needs a direct transcription"):
        solve(ScalarLQ(), ForwardBackwardSweep(), tolerance=1e-6)
    for bad in ({"tolerance": 0.0}, {"tolerance": math.inf}, {"tolerance": 1e-6, "max_refinements": -1},
                {"tolerance": 1e-6, "max_intervals": 0}, {"tolerance": 1e-6, "max_split": 1}):
        with pytest.raises(ValueError):
            MeshRefinement(**bad)


@pytest.mark.parametrize("argv, message", [
    (["--max-refinements", "3"], "--max-refinements is only for mesh refinement: add --tolerance"),
    (["--tolerance", "1e-6", "--transcription", "fbsm"], "--tolerance refines the grid of a direct transcription"),
    (["--tolerance", "0"], "--tolerance must be a positive number"),
    (["--tolerance", "1e-6", "--max-intervals", "0"], "--max-intervals must be a whole number >= 1"),
])
def test_the_cli_refuses_refinement_options_before_loading(capsys, monkeypatch, argv, message):
    def reached(*args, **kwargs):
        raise AssertionError("the CLI loaded or solved before refusing its arguments")

    monkeypatch.setattr(myriad.runtime, "load", reached)
    monkeypatch.setattr(myriad.runtime, "solve", reached)
    assert main(["solve", "van_der_pol", *argv]) == 2
    assert message in capsys.readouterr().err


def test_multiple_shooting_refines_whole_shooting_intervals():
    # x' = -2x + u, L = u^2: u = 0 and x = exp(-2t). Heun's local error (2h)^3/6 x_k is largest where x is, so the
    # refined grid is finest at the start; each new shooting interval keeps its S = 2 equal steps.
    tr = MultipleShooting(intervals=4, steps_per_interval=2, integrator=Heun())
    sol = solve(Decay(), tr, SLSQP(), tolerance=1e-4, resimulate=False)
    r = sol.refinement
    assert sol.converged and r["met"] and sol.error_estimate <= 1e-4, r
    assert r["history"][0]["intervals"] == 8 and r["history"][0]["error"] > 1e-3 and len(r["history"]) >= 2
    assert sol.intervals == r["history"][-1]["intervals"] and sol.intervals % 2 == 0
    steps = np.diff(sol.times).reshape(-1, 2)
    np.testing.assert_allclose(steps[:, 0], steps[:, 1], rtol=1e-12)
    assert steps[0, 0] < steps[-1, 0]
    # A decaying problem damps earlier errors: the global error at T is at most the sum of the local ones.
    assert 0 < abs(sol.states[-1, 0] - math.exp(-2.0)) <= sol.interval_errors.sum()


# ---- the hyper-sensitive problem ----------------------------------------------------------------------------------
# J* = 3.3620563 for T = 10000 (GPOPS-II's example hyperSensitive, Patterson & Rao 2014; x(0) = 1, x(T) = 1.5). For
# large T the boundary layers decouple: J = int_0^1 (r - x^3) dx + int_0^1.5 (r + x^3) dx, r = sqrt(x^6 + x^2),
# = 3.3620569 (quadrature), which the published figure matches to 2e-7.
J_PUBLISHED = 3.3620563
TOL = 1e-6


@pytest.fixture(scope="module")
def hyper():
    system = load(SPECS / "hypersensitive.yaml")
    return system, solve(system, HermiteSimpson(intervals=50), tolerance=TOL)


@pytest.mark.slow
def test_refinement_reaches_the_published_hypersensitive_optimum(hyper):
    system, sol = hyper
    r = sol.refinement
    assert sol.converged and r["met"] and sol.accurate, r["reason"]
    assert sol.error_estimate <= TOL
    assert abs(sol.cost - J_PUBLISHED) <= 1e-4 * J_PUBLISHED, sol.cost
    assert abs(sol.simulated_defect[0]) <= 1e-5, sol.simulated_defect  # x(T) = 1.5, re-simulated
    assert abs(sol.simulated_cost - J_PUBLISHED) <= 1e-4 * J_PUBLISHED, sol.simulated_cost
    # The uniform 50-interval grid is far too coarse (h = 200 across layers of width ~1) ...
    first = r["history"][0]
    assert first["intervals"] == 50 and first["error"] > 1e3 * TOL
    assert abs(first["cost"] - J_PUBLISHED) > 0.1 * J_PUBLISHED
    # ... and refinement grades the grid: steps of well under 1 in the layers, the coarse ones kept in between.
    intervals = [h["intervals"] for h in r["history"]]
    # The last grid halves every interval of the one before, whose cost it confirms (the cost's change on halving
    # met the tolerance too; refine.py): 844 -> 1688 intervals, within the default max_intervals = 2000.
    assert intervals == sorted(intervals) and sol.intervals == intervals[-1] == 2 * intervals[-2] <= 2000
    h = np.diff(sol.times[::2])
    assert h[0] < 1.0 and h[-1] < 1.0 and h.max() > 100 * max(h[0], h[-1])
    record = json.loads(json.dumps(sol.record()))
    assert record["intervals"] == sol.intervals and record["refinement"]["met"] is True
    assert [lv["intervals"] for lv in record["refinement"]["history"]] == intervals


@pytest.mark.slow
def test_without_refinement_the_cli_warns(hyper, capsys, tmp_path):
    # The same 50-interval grid as the first level above (its compiled code is reused).
    out = tmp_path / "coarse.json"
    argv = ["solve", str(SPECS / "hypersensitive.yaml"), "--transcription", "hermite_simpson", "--intervals", "50"]
    assert main(argv + ["--json", str(out)]) == 0  # the NLP converged: exit 0, but the accuracy is flagged
    err = capsys.readouterr().err
    assert "myriad: warning: the discretised and re-simulated answers disagree" in err
    rec = json.loads(out.read_text())
    assert rec["intervals"] == 50 and rec["refinement"] is None
    assert abs(rec["simulated_defect"][0]) > 1e-3  # the re-simulated final value misses x(T) = 1.5
    assert rec["agreement"] is False and rec["agreement_gap"] > rec["agreement_tolerance"] == 1e-3


@pytest.mark.slow
def test_a_refinement_limit_is_reported_never_success(hyper, capsys, tmp_path):
    system, _ = hyper
    sol = solve(system, HermiteSimpson(intervals=50), tolerance=TOL, max_intervals=100, resimulate=False)
    r = sol.refinement
    assert sol.converged and not r["met"] and not sol.accurate
    assert "more than max_intervals = 100" in r["reason"] and len(r["history"]) == 1
    out = tmp_path / "limited.json"
    argv = ["solve", str(SPECS / "hypersensitive.yaml"), "--transcription", "hermite_simpson", "--intervals", "50",
            "--tolerance", "1e-6", "--max-refinements", "0", "--json", str(out)]
    assert main(argv) == 1
    captured = capsys.readouterr()
    assert "mesh refinement stopped before meeting the tolerance 1e-06: max_refinements = 0 reached" in captured.err
    rec = json.loads(out.read_text())
    assert rec["converged"] is True and rec["refinement"]["met"] is False
    assert [lv["intervals"] for lv in rec["refinement"]["history"]] == [50] == [rec["intervals"]]
