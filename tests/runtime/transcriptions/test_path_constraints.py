"""Path constraints in every direct transcription and with every NLP solver (schema 2).

Mathematics checked: Bryson-Denham's second-order state constraint x <= l (J* = 4 / (9 l) = 4 for l = 1/9) in every
direct transcription, met at every node; the Rayleigh problem with the mixed constraint u + x1 / 6 <= 0
(J* = 44.8044433, Betts 2010, example 4.6) met at every node and midpoint; the keep-out disc with a bounded power in
free time against the independent CasADi transcription (``compiler/casadi_opti.py``) on the same grid; SLSQP and
extragradient agree with IPOPT and respect the rows; the rows come last, point-major, divided by their scale.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.data import default_data
from myriad.runtime.solve import solve
from myriad.runtime.solvers import SLSQP, Extragradient, Ipopt
from myriad.runtime.transcriptions import HermiteSimpson, MultipleShooting, SingleShooting, Trapezoidal
from myriad.runtime.transcriptions.base import transcribe

SCHEMA2 = "tests/compiler/schema2"
L = 1.0 / 9.0  # Bryson-Denham's wall

# Betts (2010), "Practical Methods for Optimal Control and Estimation Using Nonlinear Programming", 2nd ed., example
# 4.6 (after Maurer & Augustin 2001): the Rayleigh problem with the mixed constraint, F* = 44.8044433 as the book
# gives it. (The figure 44.7113 sometimes quoted did not reproduce: Hermite-Simpson converges to 44.80444 here.)
RAYLEIGH_OPTIMUM = 44.8044433
_RAYLEIGH = """schema: 2
name: rayleigh_mixed
title: Rayleigh problem with a mixed control-state constraint
description: Damp a Rayleigh oscillator (a tunnel-diode circuit) with a voltage bounded by the current.
source: Betts (2010), example 4.6; Maurer & Augustin (2001)
states:
  x1: {initial: -5, description: electric current}
  x2: {initial: -5, description: its rate}
controls:
  u: {description: voltage}
dynamics:
  x1: x2
  x2: -x1 + x2*(1.4 - 0.14*x2**2) + 4*u
cost:
  sense: minimize
  running: u**2 + x1**2
horizon: 4.5
path_constraints:
  mixed: {expression: u + x1/6, bounds: [-.inf, 0], description: the mixed control-state constraint}
"""


@pytest.fixture(scope="module")
def bryson_denham():
    return load(f"{SCHEMA2}/bryson_denham.yaml")


def _bryson_denham_solution():
    """The analytic optimum for l <= 1/6: a cubic arc to the wall, x = l on [3l, 1 - 3l], the mirror arc back."""
    def arc(s):  # s = distance in time from the nearer end, clipped to the arc's length 3l
        r = 1.0 - np.minimum(s, 3 * L) / (3 * L)
        return L * (1.0 - r**3), r**2, -2.0 / (3 * L) * r

    def states(t):
        t = np.asarray(t, dtype=np.float64)
        x, v, _ = arc(np.minimum(t, 1.0 - t))
        return np.stack([x, np.where(t <= 0.5, v, -v)], axis=1)

    def controls(t):
        t = np.asarray(t, dtype=np.float64)
        return arc(np.minimum(t, 1.0 - t))[2][:, None]

    return states, controls


@pytest.mark.parametrize("method", [SingleShooting(intervals=100), MultipleShooting.on_grid(20),
                                    Trapezoidal(intervals=200), HermiteSimpson(intervals=20)],
                         ids=lambda m: m.label)
@pytest.mark.slow
def test_bryson_denham_optimum_with_the_wall_met_at_every_node(bryson_denham, method):
    sol = solve(bryson_denham, method, Ipopt(), resimulate=False)
    assert sol.converged
    assert abs(sol.cost - 4.0) <= 1e-3 * 4.0, sol.cost  # measured 7.6e-6 (HS) to 4.6e-4 (multiple shooting)
    # The rows hold at every point unravel returns (Hermite-Simpson: midpoints too), to the solver's tolerance.
    assert sol.path_violation <= Ipopt().constr_viol_tol
    assert np.max(sol.states[:, 0]) <= L + Ipopt().constr_viol_tol
    assert np.max(sol.states[:, 0]) >= L - 1e-3  # and the wall is touched: the constraint is active


def test_path_rows_come_last_point_major_and_scaled(bryson_denham):
    """At the analytic solution the wall rows are x(t_p) / l (scale: the finite bound l), after every other row."""
    states, controls = _bryson_denham_solution()
    for method in (SingleShooting(intervals=12), MultipleShooting(intervals=3, steps_per_interval=4),
                   Trapezoidal(intervals=12), HermiteSimpson(intervals=12)):
        nlp = transcribe(bryson_denham, method)
        data = default_data(bryson_denham)
        z = jnp.asarray(method.sample(bryson_denham, states, controls))
        rows, (times, xs, _) = jax.jit(lambda z, d: (nlp.constraints(z, d), nlp.unravel(z, d)))(z, data)
        points = np.asarray(times).size  # nodes (and Hermite-Simpson's midpoints)
        assert points == (25 if method.label == "hermite_simpson" else 13)
        np.testing.assert_allclose(np.asarray(rows)[-points:], np.asarray(xs)[:, 0] / L, rtol=1e-14, atol=1e-14)
        np.testing.assert_array_equal(nlp.c_upper[-points:], 1.0)
        assert np.all(np.isneginf(nlp.c_lower[-points:]))
        assert not np.any(np.isinf(nlp.c_lower[:-points]))  # the rows before are the equalities (and none else here)


@pytest.mark.slow
def test_rayleigh_mixed_constraint_at_every_node_and_midpoint(tmp_path):
    spec = tmp_path / "rayleigh_mixed.yaml"
    spec.write_text(_RAYLEIGH)
    system = load(str(spec))
    sol = solve(system, HermiteSimpson(intervals=50), Ipopt(tol=1e-10), resimulate=False)
    assert sol.converged
    assert abs(sol.cost - RAYLEIGH_OPTIMUM) <= 1e-4 * RAYLEIGH_OPTIMUM, sol.cost  # measured 2.3e-5 (N = 100: 1e-6)
    g = sol.controls[:, 0] + sol.states[:, 0] / 6.0  # the 101 nodes and midpoints
    assert g.size == 101 and np.max(g) <= Ipopt().constr_viol_tol and sol.path_violation == max(np.max(g), 0.0)
    assert np.sum(g > -1e-6) >= 5  # an active arc, not a constraint that happens to be slack


@pytest.mark.slow
def test_keep_out_disc_in_free_time_agrees_with_casadi_on_the_same_grid():
    pytest.importorskip("casadi")
    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import trapezoidal

    path = f"{SCHEMA2}/keep_out_zone.yaml"
    problem = trapezoidal(export_file(path), intervals=20)
    ref = problem.opti.solve()
    T_ref, J_ref, X_ref = float(ref.value(problem.T)), float(ref.value(problem.J)), np.asarray(ref.value(problem.X))
    sol = solve(load(path), Trapezoidal(intervals=20), Ipopt(tol=1e-10), resimulate=False)
    assert sol.converged and sol.path_violation <= 1e-9
    assert abs(sol.final_time - T_ref) <= 1e-6 * T_ref and abs(sol.cost - J_ref) <= 1e-6 * J_ref  # measured 1e-8
    # The problem is symmetric in x <-> y: the two solvers may pass the disc on either side.
    mirror = X_ref[[1, 0, 3, 2]]
    assert min(np.abs(sol.states.T - X_ref).max(), np.abs(sol.states.T - mirror).max()) <= 1e-5
    disc = (sol.states[:, 0] - 1.0) ** 2 + (sol.states[:, 1] - 1.0) ** 2
    assert disc.min() >= 0.25 - 1e-9 and disc.min() <= 0.25 + 1e-6  # the disc is touched, never entered


@pytest.mark.slow
def test_slsqp_and_extragradient_respect_the_rows_and_agree_with_ipopt(bryson_denham):
    reference = solve(bryson_denham, Trapezoidal(intervals=20), Ipopt(tol=1e-10), resimulate=False)
    slsqp = solve(bryson_denham, Trapezoidal(intervals=20), SLSQP(), resimulate=False)
    assert reference.converged and slsqp.converged
    assert abs(slsqp.cost - reference.cost) <= 1e-8 * reference.cost and slsqp.path_violation <= 1e-8
    # Two-sided rows (the keep-out problem's power) and a free T: measured 1.6e-12 apart in cost, 1e-7 in T.
    keep_out = load(f"{SCHEMA2}/keep_out_zone.yaml")
    ip = solve(keep_out, Trapezoidal(intervals=12), Ipopt(tol=1e-10), resimulate=False)
    sq = solve(keep_out, Trapezoidal(intervals=12), SLSQP(), resimulate=False)
    assert ip.converged and sq.converged and sq.path_violation <= 1e-8
    assert abs(sq.cost - ip.cost) <= 1e-8 * ip.cost and abs(sq.final_time - ip.final_time) <= 1e-5
    # Extragradient (first order) on a coarse grid: measured 44165 iterations, cost 5.7e-7 off, violation 1.1e-7.
    coarse = solve(bryson_denham, Trapezoidal(intervals=10), Ipopt(tol=1e-10), resimulate=False)
    eg = solve(bryson_denham, Trapezoidal(intervals=10), Extragradient(), resimulate=False)
    assert eg.converged, eg.message
    assert abs(eg.cost - coarse.cost) <= 1e-4 * coarse.cost and eg.path_violation <= 1e-6


def test_cli_solves_a_schema2_spec_and_reports_final_time_and_path_violation(tmp_path, capsys):
    out = tmp_path / "bd.json"
    code = main(["solve", f"{SCHEMA2}/bryson_denham.yaml", "--transcription", "trapezoidal", "--intervals", "20",
                 "--json", str(out)])
    assert code == 0, capsys.readouterr()
    assert "path constraints (wall): largest violation over the nodes" in capsys.readouterr().out
    record = json.loads(out.read_text())
    assert record["final_time"] == 1.0 and 0.0 <= record["path_violation"] <= Ipopt().constr_viol_tol
    assert abs(record["cost"] - 4.083041766) < 1e-6  # the N = 20 discretised optimum (SLSQP and IPOPT above)
