"""Robust plans (runtime/uncertainty/robust.py, issue 30 item 2), float64: one scenario at the nominal values is the
nominal problem; mean, worst and CVaR agree with closed forms and with CasADi's independent scenario problem; the
robust plan does no worse than the nominal one under fresh draws; S scenarios are one compiled program."""

from __future__ import annotations

import functools
import json
import logging
import math
import re
from pathlib import Path

import jax
import jax.monitoring
import numpy as np
import pytest

from myriad.runtime import load, solve
from myriad.runtime.data import default_data
from myriad.runtime.integrators import RK4
from myriad.runtime.simulate import simulate
from myriad.runtime.solve import transcribe
from myriad.runtime.solve_config import SolveConfig
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.transcriptions import (
    TRANSCRIPTIONS,
    ForwardBackwardSweep,
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
)
from myriad.runtime.uncertainty import distributions as D
from myriad.runtime.uncertainty import robust as R

from ... import helpers

EXAMPLE = Path(__file__).resolve().parents[2] / "compiler" / "schema3" / "uncertain_oscillator.yaml"
TIGHT = Ipopt(tol=1e-12)

# J_s = J0 + T c_s whatever the control (c enters the running cost alone), so every robust objective has a closed
# form: with c in {0, 1, 3} and T = 2, mean J0 + 8/3, worst J0 + 6, CVaR_1/2 J0 + 14/3 (the worst half of the mass:
# 3 with weight 1/3 and 1 with weight 1/6, over 1/2). tests/compiler/test_schema3.py's problem with a path row
# (convex: one optimum).
ADDITIVE = """\
schema: 3
name: additive
title: Additive uncertainty
description: A cost offset c that no control can change.
parameters:
  c: {value: 1.0, uncertain: {choice: [0.0, 1.0, 3.0]}}
states:
  x: {initial: 1}
controls:
  u: {bounds: [-1, 1]}
dynamics:
  x: -x + u
cost:
  sense: minimize
  running: x**2 + u**2 + c
path_constraints:
  floor: {expression: x, bounds: [0.5, .inf], description: active from t ~ 0.5 on}
horizon: 2
scenarios: [{c: 0.0}, {c: 1.0}, {c: 3.0}]
"""


# A free final time with an uncertain weight that no state depends on: every scenario's states are the same, so the
# worst-case plan is the nominal one at w = 3 and the mean plan the nominal one at w = 2 (the cost is linear in w),
# on every transcription. The force never reaches its bounds: min T + w int u^2 is smooth with one optimum
# (continuous: T* = (36 w)^(1/4)); with a bang-bang control (w = 0.1, |u| <= 1) single shooting's worst-case plan
# stopped at another KKT point (2.766146 against 2.766138), as trapezoidal's mean plan did under a speed limit.
FREE_TIME = """\
schema: 3
name: free_time_weights
title: Free time, uncertain weight
description: Minimum time plus an uncertain weight on the force.
parameters:
  w: {value: 2.0, uncertain: {choice: [1.0, 3.0]}}
states:
  x1: {initial: 0, final: 1}
  x2: {initial: 0, final: 0}
controls:
  u: {bounds: [-10, 10]}
dynamics:
  x1: x2
  x2: u
cost:
  sense: minimize
  running: 1 + w*u**2
horizon: {free: true, guess: 2.5, bounds: [0.1, 10]}
scenarios: [{w: 1.0}, {w: 3.0}]
robust: {objective: worst}
"""


@functools.cache
def oscillator(**attrs):
    """The example spec's system, or a subclass with other schema 3 class attributes (tuples: cached, so one class
    per declaration and its compiled programs shared)."""
    base = load(EXAMPLE)
    return type(type(base).__name__ + "Variant", (type(base),), dict(attrs))() if attrs else base


@pytest.fixture(scope="module")
def additive(tmp_path_factory):
    path = tmp_path_factory.mktemp("robust") / "additive.yaml"
    path.write_text(ADDITIVE, encoding="utf-8")
    return load(path)


def test_robust_value_closed_forms():
    J = [0.0, 1.0, 3.0]
    assert R.robust_value(J, "mean") == pytest.approx(4 / 3)
    assert R.robust_value(J, "worst") == 3.0
    assert R.robust_value(J, "cvar", 0.5) == pytest.approx(7 / 3)  # (3 (1/3) + 1 (1/6)) / (1/2)
    assert R.robust_value(J, "cvar", 1e-12) == pytest.approx(4 / 3)  # alpha -> 0: the mean
    assert R.robust_value(J, "cvar", 0.7) == pytest.approx(3.0)  # the worst third covers the tail
    with pytest.raises(ValueError, match="0 < alpha < 1"):
        R.robust_value(J, "cvar", 1.0)


@pytest.mark.parametrize("transcription", [Trapezoidal(intervals=20), SingleShooting(intervals=20),
                                           HermiteSimpson(intervals=10)], ids=lambda t: t.label)
def test_one_scenario_at_the_nominal_values_is_the_nominal_solve(transcription):
    """With IPOPT's default tolerance (the CLI's): the same NLP in other variables' order, the same optimum."""
    system = oscillator(scenarios=((2.0, 0.5),))
    plan = solve(system, transcription, Ipopt(), resimulate=False)
    nominal = solve(system, transcription, Ipopt(), resimulate=False, nominal=True)
    assert plan.converged and nominal.converged and nominal.robust is None
    assert abs(plan.cost - nominal.cost) <= 1e-10, (plan.cost, nominal.cost)
    np.testing.assert_allclose(plan.controls, nominal.controls, atol=1e-6)
    assert plan.robust["scenarios"] == [{"params": {"k": 2.0, "c": 0.5}, "cost": pytest.approx(nominal.cost,
                                                                                                 abs=1e-10)}]


def test_the_shared_entries_are_the_controls():
    """Every transcription's shared entries are exactly its control values: moving them moves unravel's controls
    one for one, and there are as many as unravel has control values."""
    system, data = oscillator(), default_data(oscillator())
    for cls in TRANSCRIPTIONS.values():
        tr = cls.on_grid(10)
        shared, private = R.shared_entries(system, tr)
        nlp = transcribe(system, tr)
        z = np.asarray(nlp.initial_guess(data))
        _, _, u = nlp.unravel(z, data)
        bumped = z.copy()
        bumped[shared] += 0.25
        _, _, moved = nlp.unravel(bumped, data)
        assert shared.size == np.size(u) and shared.size + private.size == z.size, tr.label
        np.testing.assert_allclose(np.asarray(moved) - np.asarray(u), 0.25, atol=1e-12, err_msg=tr.label)


def test_additive_closed_forms(additive):
    """mean, worst and CVaR of J0 + 2 c_s (module comment), and each scenario's cost, on trapezoidal collocation."""
    tr = Trapezoidal(intervals=20)
    nominal = solve(additive, tr, TIGHT, params={"c": 0.0}, resimulate=False, nominal=True)
    J0 = nominal.cost
    for objective, alpha, offset in (("mean", None, 8 / 3), ("worst", None, 6.0), ("cvar", 0.5, 14 / 3)):
        sol = R.solve_robust(additive, tr, TIGHT, objective=objective, alpha=alpha, resimulate=False)
        assert sol.converged, (objective, sol.message)
        assert sol.cost == pytest.approx(J0 + offset, abs=1e-8), objective
        assert [s["cost"] for s in sol.robust["scenarios"]] == pytest.approx([J0, J0 + 2, J0 + 6], abs=1e-8)
        assert sol.path_violation <= 1e-8 and sol.scenario_states[:, :, 0].min() >= 0.5 - 1e-8
    # A start in the transcription's variables (the nominal plan) is copied to every scenario.
    z0 = tr.sample(additive, lambda t: np.interp(t, nominal.times, nominal.states[:, 0])[:, None],
                   lambda t: np.interp(t, nominal.times, nominal.controls[:, 0])[:, None])
    warm = R.solve_robust(additive, tr, TIGHT, objective="cvar", alpha=0.5, z0=z0, resimulate=False)
    assert warm.converged and warm.cost == pytest.approx(J0 + 14 / 3, abs=1e-8)


@pytest.mark.slow  # a forward-mode Jacobian compiled for each of eight NLPs (jitted: eager was 16 s, jitted 1.5 s)
def test_the_jacobian_pattern_covers_every_nonzero(additive):
    """At a random point, every non-zero of the scenario NLP's Jacobian (forward mode) lies in its pattern, on every
    transcription, with path rows; mean (the transcription's rows alone) and CVaR (its epigraph rows read t and
    xi_s: worst's read t alone)."""
    data = R.scenario_batch(additive)
    rng = np.random.default_rng(0)
    for cls in TRANSCRIPTIONS.values():
        for objective, alpha in (("mean", None), ("cvar", 0.5)):
            nlp = R.scenario_nlp(additive, cls.on_grid(5), 3, objective, alpha)
            w = np.asarray(nlp.initial_guess(data)) + 0.1 * rng.standard_normal(nlp.n_variables)
            jac = np.asarray(jax.jit(jax.jacfwd(nlp.constraints))(w, data))
            pattern = np.ones(jac.shape, bool) if nlp.jacobian_sparsity is None else np.zeros(jac.shape, bool)
            if nlp.jacobian_sparsity is not None:
                pattern[nlp.jacobian_sparsity] = True
            assert not np.any((jac != 0) & ~pattern), (cls.label, objective)


@pytest.mark.slow  # three IPOPT solves of each side (~15 s on a loaded 2-core machine)
def test_objectives_agree_with_casadis_scenario_problem():
    pytest.importorskip("casadi")
    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import scenario_trapezoidal

    system, cs, N = oscillator(), export_file(EXAMPLE), 20
    for objective, alpha in (("mean", None), ("worst", None), ("cvar", 0.5)):
        problem = scenario_trapezoidal(cs, N, objective=objective, alpha=alpha)
        ref = problem.opti.solve()
        sol = R.solve_robust(system, Trapezoidal(intervals=N), TIGHT, objective=objective, alpha=alpha,
                             resimulate=False)
        assert sol.converged, (objective, sol.message)
        assert sol.cost == pytest.approx(float(ref.value(problem.J)), abs=1e-6), objective
        assert [s["cost"] for s in sol.robust["scenarios"]] == pytest.approx(
            [float(ref.value(J)) for J in problem.costs], abs=1e-6), objective
        np.testing.assert_allclose(sol.controls[:, 0], np.asarray(ref.value(problem.U)).ravel(), atol=1e-4)


@pytest.mark.slow  # five solves
def test_the_plans_cost_no_less_than_each_scenarios_own_optimum():
    """One control for all scenarios can do no better than each scenario's own optimal control (the wait-and-see
    bound): each scenario cost of a plan >= that scenario's optimum, so mean >= their mean and worst >= their max;
    strictly here, since the scenarios' optimal controls differ."""
    system, tr = oscillator(), Trapezoidal(intervals=20)
    own = [solve(system, tr, TIGHT, params={"k": k, "c": c}, nominal=True, resimulate=False).cost
           for k, c in system.scenarios]
    for objective, bound in (("mean", np.mean(own)), ("worst", max(own))):
        sol = R.solve_robust(system, tr, TIGHT, objective=objective, resimulate=False)
        costs = [s["cost"] for s in sol.robust["scenarios"]]
        assert all(J >= J_own - 1e-9 for J, J_own in zip(costs, own)), (objective, costs, own)
        assert sol.cost > bound + 1e-4, (objective, sol.cost, bound)


def expected_costs(system, controls, draws):
    """Each plan's cost (RK4 on its grid) in every drawn parameter set, one vmapped program."""
    names = D.uncertain_spec(system)[0]

    @jax.jit
    def costs(u):
        def one(theta):
            params = {name: theta[i] for i, name in enumerate(names)}
            return simulate(system, u, params, None, RK4()).cost
        return jax.vmap(one)(draws)

    return [np.asarray(costs(np.asarray(u))) for u in controls]


@pytest.mark.slow  # two solves and 4000 simulations
def test_the_robust_plan_beats_the_nominal_one_out_of_sample():
    """On the example spec (k ~ U[1.5, 2.5], c ~ N(0.5, 0.05)), the mean plan over its three scenarios has the lower
    expected cost under 2000 fresh draws (not the planning scenarios); paired on the same draws."""
    system, tr = oscillator(), Trapezoidal(intervals=40)
    robust = solve(system, tr, resimulate=False)
    nominal = solve(system, tr, resimulate=False, nominal=True)
    assert robust.converged and nominal.converged
    draws = D.sample(system, jax.random.PRNGKey(2026), 2000)
    r, n = expected_costs(system, (robust.controls, nominal.controls), draws)
    diff = r - n
    se = diff.std(ddof=1) / math.sqrt(diff.size)
    print(f"expected cost: robust {r.mean():.6f} +- {r.std(ddof=1) / math.sqrt(r.size):.1e}, nominal "
          f"{n.mean():.6f} +- {n.std(ddof=1) / math.sqrt(n.size):.1e}, paired difference {diff.mean():.2e} +- {se:.1e}")
    assert diff.mean() <= 0.0


@pytest.mark.slow  # three solves on each of the four transcriptions
def test_a_free_final_time_on_every_transcription(tmp_path):
    path = tmp_path / "free_time_weights.yaml"
    path.write_text(FREE_TIME, encoding="utf-8")
    system = load(path)
    for cls in TRANSCRIPTIONS.values():
        tr = cls.on_grid(20)
        worst = solve(system, tr, TIGHT, resimulate=False)
        mean = R.solve_robust(system, tr, TIGHT, objective="mean", resimulate=False)
        at_three = solve(system, tr, TIGHT, params={"w": 3.0}, nominal=True, resimulate=False)
        nominal = solve(system, tr, TIGHT, nominal=True, resimulate=False)  # w = 2, the mean of the scenarios
        assert worst.converged and mean.converged, tr.label
        assert worst.cost == pytest.approx(at_three.cost, abs=1e-8), tr.label
        assert worst.final_time == pytest.approx(at_three.final_time, abs=1e-6), tr.label
        assert mean.cost == pytest.approx(nominal.cost, abs=1e-8), tr.label
        assert worst.final_time == pytest.approx(108 ** 0.25, rel=2e-2), tr.label  # the continuous T*, w = 3


class CompileCounter(helpers.CompileCounter):
    """tests/helpers.py's counter that also names each compiled program (JAX's compile log)."""

    def __init__(self):
        super().__init__()
        self.names: list[str] = []
        self._handler = logging.Handler()
        self._handler.emit = self._record

    def _record(self, record):
        match = re.match(r"Compiling jit\((\w+)\)", record.getMessage())
        if match:
            self.names.append(match.group(1))

    def __enter__(self):
        logging.getLogger("jax").addHandler(self._handler)
        jax.config.update("jax_log_compiles", True)
        return super().__enter__()

    def __exit__(self, *exc):
        jax.config.update("jax_log_compiles", False)
        logging.getLogger("jax").removeHandler(self._handler)
        super().__exit__(*exc)


def _drawn(S: int):
    """The example's class with S drawn scenarios (no explicit ones), a class of its own: nothing compiled shared."""
    return oscillator(scenarios=(), robust_objective="mean", robust_samples=S, robust_seed=S)


# The programs of a robust solve with IPOPT: its point and Hessian-vector products, the scenario NLP's initial
# guess, the scenario costs and the trajectories (the rest are small eager operations, once per shape).
PROGRAMS = ("point", "hvps", "initial_guess", "objective", "trajectory")


@pytest.mark.slow  # four solves, one of 64 scenarios (~8 s on a loaded 2-core machine)
def test_sixty_four_scenarios_compile_as_many_programs_as_two():
    """A solve at S = 2 and one at S = 64 (fresh classes) compile each of the NLP's programs once, and about as many
    programs in all (a warm-up at S = 3 compiles the eager operations that do not depend on S)."""
    tr, solver = Trapezoidal(intervals=8), Ipopt(tol=1e-8)
    counts, sols = {}, {}
    solve(_drawn(3), tr, solver, resimulate=False)
    for S in (2, 64):
        with CompileCounter() as counter:
            sols[S] = solve(_drawn(S), tr, solver, resimulate=False)
        counts[S] = len(counter.events)
        assert sorted(n for n in counter.names if n in PROGRAMS) == sorted(PROGRAMS), (S, counter.names)
    assert sols[64].converged and len(sols[64].robust["scenarios"]) == 64
    assert sols[64].scenario_states.shape == (64, 9, 2)
    # Not 64 of anything: the named programs once each (above); besides them, a few eager operations whose shapes
    # hold S compile anew at a new S (15 against 19 in a fresh process, 2 apart after other tests warmed them).
    assert counts[64] - counts[2] <= 6 and counts[64] <= 25, counts
    with CompileCounter() as counter:  # and a second solve of the same shapes compiles nothing
        again = solve(_drawn(64), tr, solver, resimulate=False)
    assert counter.events == [] and again.cost == pytest.approx(sols[64].cost, rel=1e-12)


@pytest.mark.parametrize("transcription", [
    HermiteSimpson(intervals=8),
    pytest.param(MultipleShooting(intervals=4), marks=pytest.mark.slow),  # its rollouts compile for ~5 s
], ids=lambda t: t.label)
def test_every_direct_transcription_plans_and_resimulates(transcription):
    system = oscillator()
    sol = solve(system, transcription)
    assert sol.converged, sol.message
    rec = json.loads(json.dumps(sol.record()))
    rob = rec["robust"]
    assert rob["objective"] == "mean" and rob["alpha"] is None and len(rob["scenarios"]) == 3
    assert rec["cost"] == pytest.approx(np.mean([s["cost"] for s in rob["scenarios"]]), rel=1e-12)
    assert [s["params"] for s in rob["scenarios"]] == [{"k": 1.5, "c": 0.45}, {"k": 2.0, "c": 0.5},
                                                       {"k": 2.5, "c": 0.55}]
    assert rec["simulated_cost"] == pytest.approx(np.mean([s["simulated_cost"] for s in rob["scenarios"]]))
    assert rob["nominal_cost"] == pytest.approx(rob["scenarios"][1]["simulated_cost"], rel=1e-12)  # k, c nominal
    assert sol.agreement_gap < 0.05


@pytest.mark.slow  # the interior point's dense program compiles for ~25 s on a loaded machine
def test_the_interior_point_solves_the_scenario_nlp_densely(additive):
    tr = Trapezoidal(intervals=10)
    ref = R.solve_robust(additive, tr, TIGHT, objective="worst", resimulate=False)
    sol = R.solve_robust(additive, tr, InteriorPoint(), objective="worst", resimulate=False)
    assert sol.converged and sol.cost == pytest.approx(ref.cost, abs=1e-7)


def test_refusals():
    system = oscillator()
    with pytest.raises(ValueError, match="direct transcription"):
        solve(system, ForwardBackwardSweep())
    with pytest.raises(ValueError, match="mesh refinement of a robust plan"):
        solve(system, Trapezoidal(intervals=8), tolerance=1e-4)
    with pytest.raises(ValueError, match=r"params: k is uncertain.*nominal=True"):
        solve(system, Trapezoidal(intervals=8), params={"k": 2.1})
    with pytest.raises(ValueError, match="no stage-wise derivatives"):  # the interior point's dense step only
        solve(system, SingleShooting(intervals=8), InteriorPoint(kkt="riccati"), resimulate=False)
    assert SolveConfig(nominal=True).nominal and not SolveConfig().nominal
    with pytest.raises(ValueError, match="nominal must be true or false"):
        SolveConfig(nominal="yes")


def test_the_cli_writes_the_robust_record(tmp_path):
    from myriad.runtime.cli import main

    out = tmp_path / "plan.json"
    assert main(["solve", str(EXAMPLE), "--transcription", "trapezoidal", "--intervals", "8", "--json",
                 str(out)]) in (0, 1)
    rec = json.loads(out.read_text())
    assert rec["robust"]["objective"] == "mean" and len(rec["robust"]["scenarios"]) == 3
    assert rec["cost"] == pytest.approx(np.mean([s["cost"] for s in rec["robust"]["scenarios"]]), rel=1e-12)
    assert main(["solve", str(EXAMPLE), "--transcription", "trapezoidal", "--intervals", "8", "--nominal",
                 "--json", str(out)]) in (0, 1)
    assert "robust" not in json.loads(out.read_text())
