"""System identification end to end: sample, fit, plan on the model, judge the plan on the true system; the CLI
and its record, plots and argument checks."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.learn.evaluate import evaluate
from myriad.runtime.learn.models import NeuralODE, Parametric
from myriad.runtime.sysid.run import SysidConfig, run_sysid

pytestmark = pytest.mark.slow  # not in `make test-fast`: whole system-identification runs and the CLI

RECORD_KEYS = ("system", "model", "learned", "true", "standard_errors", "achieved_cost", "achieved_defect",
               "optimal_cost", "optimal_defect", "train_seconds", "seed", "converged")


def test_parametric_least_squares_recovers_the_parameters_and_the_optimum():
    report = run_sysid("cancer_treatment", SysidConfig(model="parametric"))
    assert report.converged, report.record()["message"]
    for name, value in report.learned.items():
        assert abs(value - report.true[name]) <= 1e-6 * abs(report.true[name]), name
    rec = report.record()
    assert all(k in rec for k in RECORD_KEYS)
    # Planning on the recovered model is planning on the true one: the same cost on the true system.
    assert abs(rec["achieved_cost"] - rec["optimal_cost"]) <= 1e-3 * abs(rec["optimal_cost"])
    json.dumps(rec)  # JSON-ready


def test_evaluation_at_the_true_parameters_matches_the_optimum_and_reports_defects():
    system = load("van_der_pol")
    model = Parametric(system)
    ev = evaluate(model, model.true_params())
    assert ev.converged and abs(ev.relative_gap) < 1e-9
    assert len(ev.achieved_defect) == 2 and ev.max_achieved_defect < 1e-6
    # At the (wrong) guesses the plan is judged on the true system: worse than the optimum, never better.
    guess = evaluate(model, model.init_params(), optimum=ev.optimum)
    assert guess.achieved_cost >= ev.optimum.cost - 1e-9 or guess.max_achieved_defect > 1e-6


def test_a_failed_plan_is_reported_not_hidden():
    # A model whose vector field is zero cannot take Van der Pol from x0 = (0, 1) to the required x(T) = (0, 0):
    # the plan on it must fail, and the evaluation must say so.
    system = load("van_der_pol")
    model = NeuralODE(system, hidden=(4,), activation="tanh")
    theta = model.init_params(jax.random.key(0))
    theta = {"net": jax.tree.map(jnp.zeros_like, theta["net"]),
             "norm": {**theta["norm"], "dx_mean": jnp.zeros_like(theta["norm"]["dx_mean"])}}
    assert np.all(np.asarray(model.vector_field(jnp.ones(2), jnp.ones(1), 0.0, theta, system.default_params())) == 0)
    ev = evaluate(model, theta)
    assert not ev.plan.converged and not ev.converged
    assert "planning on the learned model failed" in ev.message and ev.max_achieved_defect > 0.5


def test_cli_sysid_writes_json_and_plots(tmp_path):
    out, plots = tmp_path / "r.json", tmp_path / "plots"
    rc = main(["sysid", "van_der_pol", "--json", str(out), "--plots", str(plots)])
    assert rc == 0
    rec = json.loads(out.read_text())
    assert all(k in rec for k in RECORD_KEYS) and rec["converged"]
    assert abs(rec["learned"]["a"] - rec["true"]["a"]) <= 1e-6 * abs(rec["true"]["a"])
    for name in ("trajectories.png", "vector_field.png"):
        assert (plots / name).stat().st_size > 10_000
    assert not list(tmp_path.glob(".*.tmp")) and not list(plots.glob(".*.tmp"))  # atomic writes left nothing


def test_cli_sysid_checks_its_arguments_before_any_work(tmp_path, capsys):
    assert main(["sysid", "van_der_pol", "--resume"]) == 2
    assert main(["sysid", "van_der_pol", "--epochs", "0"]) == 2
    assert main(["sysid", "van_der_pol", "--model", "node", "--method", "least_squares"]) == 2
    assert main(["sysid", "simple_case"]) == 2
    assert main(["sysid", "van_der_pol", "--json", str(tmp_path / "missing" / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "--resume needs --checkpoint" in err and "declares no learnable parameters" in err
    assert not (tmp_path / "missing").exists()
