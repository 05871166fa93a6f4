"""System identification end to end: sample, fit, plan on the model, judge the plan on the true system; the CLI
and its record, plots and argument checks."""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.learn.dataset import Sampling
from myriad.runtime.learn.evaluate import evaluate
from myriad.runtime.learn.models import NeuralODE, Parametric
from myriad.runtime.sysid.run import SysidConfig, failed, run_sysid

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


# ---- exit codes that tell the truth (issue 33) ----------------------------------------------------------------------

def test_a_converging_fit_exits_0_and_an_undertrained_one_exits_1_with_its_reason(tmp_path, capsys):
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    assert main(["sysid", "cancer_treatment", "--json", str(good)]) == 0
    rec = json.loads(good.read_text())
    assert rec["failure"] is None and rec["max_param_error"] == 0.05 and rec["max_gap"] is None
    assert main(["sysid", "cancer_treatment", "--method", "adam", "--epochs", "300", "--json", str(bad)]) == 1
    rec = json.loads(bad.read_text())
    # 300 Adam epochs leave delta 21 % off (no standard errors: the 5 % bound decides)
    assert abs(rec["learned"]["delta"] - 0.45) / 0.45 > 0.2
    assert rec["failure"].startswith("the fit did not find the parameters the data were made with: delta")
    assert rec["message"] == rec["failure"] and "max_param_error" in capsys.readouterr().err


def test_the_verdict_weighs_errors_against_standard_errors_and_the_gap_against_max_gap():
    report = run_sysid("bioreactor", SysidConfig(trajectories=3, sampling=Sampling(intervals=20)))
    assert failed(report) is None
    # 10 % off, as a 1 % fit with a standard error of 0.04 could be (3 SE = 0.12): supported by the data
    off = dataclasses.replace(report, learned={"G": 1.1, "D": 1.0}, standard_errors={"G": 0.04, "D": 0.04})
    assert failed(off) is None
    tight = dataclasses.replace(off, standard_errors={"G": 0.02, "D": 0.02})  # 3 SE = 0.06 < 0.1 > 5 %
    assert "G 1.1 (true 1, 10.0% off, standard error 0.02)" in failed(tight)
    assert failed(dataclasses.replace(tight, unidentifiable=("G",))) is None  # the data cannot tell: exempt
    loose = dataclasses.replace(tight, config=dataclasses.replace(report.config, max_param_error=0.11))
    assert failed(loose) is None
    ev = report.evaluation  # a plan 10 % worse than the optimum on the true system
    worse = dataclasses.replace(report, evaluation=dataclasses.replace(
        ev, achieved_cost=ev.optimum.cost + 0.1 * abs(ev.optimum.cost)))
    assert abs(worse.evaluation.relative_gap - 0.1) < 1e-12 and failed(worse) is None  # no bound by default
    bound = lambda gap: dataclasses.replace(worse, config=dataclasses.replace(report.config, max_gap=gap))  # noqa: E731
    assert failed(bound(0.11)) is None
    assert "10.0% above the optimum" in failed(bound(0.05)) and "more than max_gap 0.05" in failed(bound(0.05))


def test_implausible_noise_is_refused_before_any_work(capsys):
    assert main(["sysid", "cancer_treatment", "--noise", "2"]) == 2
    err = capsys.readouterr().err
    assert "--noise must be a fraction of the state range in [0, 1]" in err and "got 2" in err


def test_noise_on_an_unbounded_state_is_a_usage_error_with_a_route_that_works(tmp_path, capsys):
    spec = tmp_path / "free.yaml"  # bioreactor without its state's bounds
    text = (Path(__file__).resolve().parents[3] / "specs" / "bioreactor.yaml").read_text()
    spec.write_text(text.replace("bounds: [0, 1], ", "").replace("name: bioreactor", "name: free"))
    assert main(["sysid", str(spec), "--noise", "0.05"]) == 2
    err = capsys.readouterr().err
    assert "state `x` has lower bound -inf and upper bound inf" in err and "internal error" not in err
    assert "noise_scale='spread'" in err and "--set sampling.FIELD=VALUE" in err
    out = tmp_path / "r.json"
    assert main(["sysid", str(spec), "--noise", "0.05", "--set", "sampling.noise_scale=spread", "--trajectories",
                 "3", "--json", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert rec["failure"] is None and rec["noise"] == 0.05
    for name in ("G", "D"):  # noisy data: within 3 standard errors of the truth
        assert abs(rec["learned"][name] - 1.0) <= 3 * rec["standard_errors"][name]
