"""The shipped reference scores: present, certified and fresh for every shipped system (replayed with today's env),
and the normalised score they define; the command's refusals."""

import copy
import math

import pytest

from myriad.runtime import load
from myriad.runtime.rl import normalized_score, reference_scores
from myriad.runtime.rl.optimum import AGREEMENT_RTOL
from myriad.runtime.rl.reference import stale
from myriad.runtime.systems import NAMES


@pytest.mark.slow
def test_reference_scores_are_fresh_for_every_shipped_system():
    doc = reference_scores()
    assert list(doc["systems"]) == list(NAMES)
    assert stale(doc) == [], "rerun: myriad rl-reference --write"


def test_staleness_is_detected():
    doc = copy.deepcopy(reference_scores())
    doc["systems"]["van_der_pol"]["random"]["cost"] *= 1 + 1e-6
    doc["systems"]["pendulum"]["spec_sha256"] = "0" * 64
    doc["env"]["steps"] = 50
    del doc["systems"]["glucose"]
    problems = stale(doc, names=["van_der_pol", "pendulum"])
    assert any("van_der_pol: random" in p for p in problems) and any("pendulum: spec" in p for p in problems)
    assert any(p.startswith("format/env") for p in problems) and any("glucose" in p for p in problems)


@pytest.mark.parametrize("name", NAMES)
def test_each_record_is_complete_certified_and_the_optimum_beats_the_baselines(name):
    r = reference_scores()["systems"][name]
    system = load(name)
    assert r["spec_sha256"] == system.spec_sha256 and r["sense"] == system.sense and r["system"] == name
    assert r["env"] == {**reference_scores()["env"], "action_bound": r["action_bound"]}
    opt, zero, rand = r["optimal"], r["zero_control"]["cost"], r["random"]["cost"]
    c = opt["certificate"]
    assert c["methods"] == ["ipopt", "interior_point"] and c["agreement"] <= c["tolerance"] == AGREEMENT_RTOL
    assert opt["cost"] == pytest.approx(min(c["costs"].values()), rel=1e-12) and c["start"] in c["starts"]
    assert all(math.isfinite(v) for v in (opt["cost"], zero, rand))
    assert len(opt["controls"]) == 100 and len(opt["controls"][0]) == system.n_controls
    assert r["random"]["episodes"] == 100 and r["random"]["seed"] == 0
    # Scores need J_random > J_opt; the env's own optimum is at least as good as doing nothing (Bioreactor: u = 0
    # is optimal, up to the solvers' residue).
    assert opt["cost"] < rand and opt["cost"] <= zero + 1e-9 * max(1.0, abs(zero))


def test_normalized_score_is_0_at_random_and_100_at_the_optimum():
    r = reference_scores()["systems"]["van_der_pol"]
    assert normalized_score("van_der_pol", r["random"]["cost"]) == pytest.approx(0.0, abs=1e-12)
    assert normalized_score(load("van_der_pol"), r["optimal"]["cost"]) == pytest.approx(100.0)
    mid = 0.5 * (r["random"]["cost"] + r["optimal"]["cost"])
    assert normalized_score("van_der_pol", mid) == pytest.approx(50.0)
    with pytest.raises(KeyError, match="neither a shipped system"):
        normalized_score("double_integrator", 1.0)


def test_the_command_refuses_an_unknown_system(capsys):
    from myriad.runtime.cli import main

    assert main(["rl-reference", "--write", "--systems", "no_such_system"]) == 2
    assert "no_such_system" in capsys.readouterr().err
    assert main(["rl-reference", "no_such_system"]) == 2
    assert "neither a shipped system" in capsys.readouterr().err
    assert main(["rl-reference", "peers/hager"]) == 2  # a free control and no --action-bound: no random policy
    assert "action_bound" in capsys.readouterr().err
    assert main(["rl-reference", "peers/hager", "--steps", "0"]) == 2
    assert "--steps" in capsys.readouterr().err
    assert main(["rl-reference", "peers/hager", "--write"]) == 2
