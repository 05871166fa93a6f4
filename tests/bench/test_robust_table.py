"""The robust table on a system with a closed form (tests/runtime/uncertainty/specs/uncertain_gain.yaml: x' = b u,
cost w u^2 + (x(T) - 1)^2, b ~ U(0.5, 1.5)): the nominal and robust plans' expected costs within 3 standard errors
of the exact ones, the robust plan below the nominal one, MPC run; bad input is exit 2."""

import json
from pathlib import Path

import jax
import numpy as np
import pytest

from bench import robust_table as rt
from myriad.runtime import load
from myriad.runtime.uncertainty.scenarios import scenario_values

SPEC = str(Path(__file__).resolve().parents[1] / "runtime" / "uncertainty" / "specs" / "uncertain_gain.yaml")
W = 0.1


def expected(v):  # E J(v) = (w + E b^2) v^2 - 2 E b v + 1 under U(0.5, 1.5)
    return (W + 1.0 + 1.0 / 12.0) * v * v - 2.0 * v + 1.0


@pytest.mark.slow  # about 15 s under load: IPOPT's and MPC's programs compiled
def test_a_row_has_the_closed_form_expected_costs(tmp_path):
    out, md = tmp_path / "robust.json", tmp_path / "robust.md"
    assert rt.main(["--systems", SPEC, "--steps", "3", "--samples", "0", "--draws", "1000", "--mpc-episodes", "2",
                    "--seed", "5", "--json", str(out), "--markdown", str(md)]) == 0
    row = json.loads(out.read_text())["rows"][0]
    with jax.enable_x64(True):
        planning = scenario_values(load(SPEC))[:, 0]  # the spec's 16 planning draws (robust_seed 0)
    v_nominal, v_robust = 1.0 / (W + 1.0), planning.mean() / (W + (planning ** 2).mean())
    for key, v in (("nominal_plan", v_nominal), ("robust_plan", v_robust)):
        s = row[key]
        assert s["converged"] and s["n"] == 1000 and abs(s["mean"] - expected(v)) <= 3 * s["se"], (key, s)
    assert abs(row["nominal_plan"]["at_nominal"] - (1.0 - v_nominal)) < 1e-9  # J(v; 1) = w v^2 + (v - 1)^2 = 1 - v
    diff = row["robust_minus_nominal"]
    assert abs(diff["mean"] - (expected(v_robust) - expected(v_nominal))) <= 3 * diff["se"] and diff["mean"] < 0
    assert row["mpc"]["n"] == 2 and np.isfinite(row["mpc"]["mean"]) and row["scenarios"] == 16
    text = md.read_text()
    assert "| uncertain_gain | b uniform [0.5, 1.5] | 16 |" in text and "at or below the nominal plan" in text


def test_bad_input_is_exit_2(capsys):
    assert rt.main(["--systems", "epidemic"]) == 2
    assert "declares no uncertain parameters" in capsys.readouterr().err
    assert rt.main(["--draws", "10", "--mpc-episodes", "20"]) == 2
    err = capsys.readouterr().err
    assert "--mpc-episodes" in err, err
