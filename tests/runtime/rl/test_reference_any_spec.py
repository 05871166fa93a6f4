"""Reference scores for a spec that does not ship (a copy of the peer problem Catalyst Mixing written as a new file):
the env's optimum certified by two methods, checked against an independent fine-grid solve of the continuous
problem and by replaying it in the env; the cache and its key; the normalised score's two ends."""

import json
from pathlib import Path

import jax
import numpy as np
import pytest

from myriad.runtime import load, solve
from myriad.runtime.rl import (
    CertificationError,
    EnvOptions,
    normalized_score,
    optimum,
    play,
    reference,
    reference_record,
)
from myriad.runtime.transcriptions import HermiteSimpson

PEER = Path(__file__).parents[3] / "specs" / "peers" / "catalyst_mixing.yaml"


def _copy(folder: Path, name: str = "catalyst_copy", edit: tuple[str, str] | None = None) -> Path:
    """The peer's spec as a new file named ``name`` (a spec that does not ship), optionally with one text edit."""
    text = PEER.read_text().replace("name: catalyst_mixing", f"name: {name}")
    if edit is not None:
        assert edit[0] in text
        text = text.replace(*edit)
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return path


@pytest.fixture(autouse=True)
def _fresh_memo(monkeypatch):
    monkeypatch.setattr(reference, "_memo", {})


def test_a_changed_spec_or_setting_is_a_new_key_and_the_rest_are_not(tmp_path):
    spec = _copy(tmp_path)
    key = reference.cache_key(spec)
    (tmp_path / "elsewhere").mkdir()
    assert reference.cache_key(_copy(tmp_path / "elsewhere")) == key  # the content names the key, not the place
    edited = _copy(tmp_path, "catalyst_edited", edit=("10*x2 - x1", "9*x2 - x1"))
    changed = [reference.cache_key(edited)] + [reference.cache_key(spec, EnvOptions(**o)) for o in (
        {"steps": 50}, {"integrator": "rk4"}, {"substeps": 2}, {"penalty": 10.0}, {"action_bound": 3.0})]
    assert len({key, *changed}) == 1 + len(changed)
    # Not part of the control problem a cost measures: the action map, a time limit, random starts.
    for o in ({"normalize_actions": False}, {"max_steps": 10}, {"start_noise": 0.1}):
        assert reference.cache_key(spec, EnvOptions(**o)) == key


def test_the_cache_is_written_once_and_then_read_without_solving(tmp_path, monkeypatch):
    spec = _copy(tmp_path)
    calls = []

    def counting_compute(target, options=None):  # the record's shape; the solve itself is the slow tests'
        calls.append(options)
        env = reference.reference_env(target, options)
        return {"system": target.name, "spec_sha256": target.spec_sha256, "env": reference.env_settings(env),
                "optimal": {"cost": -2.0}, "random": {"cost": 3.0}}

    monkeypatch.setattr(reference, "compute", counting_compute)
    first = reference_record(spec, cache_dir=tmp_path / "cache")
    assert len(calls) == 1 and (tmp_path / "cache" / f"{reference.cache_key(spec)}.json").is_file()
    monkeypatch.setattr(reference, "_memo", {})  # a new process: only the file remains
    assert reference_record(spec, cache_dir=tmp_path / "cache") == first and len(calls) == 1
    reference_record(spec, EnvOptions(steps=50), cache_dir=tmp_path / "cache")
    assert len(calls) == 2 and calls[1].steps == 50
    assert len(list((tmp_path / "cache").iterdir())) == 2  # no temporary file left behind (atomic writes)
    # A file at the key that is not this spec's record (hand-edited, truncated) is computed again and replaced.
    path = tmp_path / "cache" / f"{reference.cache_key(spec)}.json"
    path.write_text('{"spec_sha256": "0"}')
    monkeypatch.setattr(reference, "_memo", {})
    assert reference_record(spec, cache_dir=tmp_path / "cache") == first and len(calls) == 3
    assert json.loads(path.read_text()) == first


def test_a_shipped_system_in_the_default_env_reads_the_shipped_file(monkeypatch):
    monkeypatch.setattr(reference, "compute", lambda *a, **k: pytest.fail("solved a shipped system's default record"))
    assert reference_record("van_der_pol") is reference.reference_scores()["systems"]["van_der_pol"]
    assert reference_record("van_der_pol", EnvOptions(normalize_actions=False, start_noise=0.2))["env"]["steps"] == 100


def test_a_free_control_without_an_action_bound_is_refused_before_solving(monkeypatch):
    monkeypatch.setattr(reference, "compute", lambda *a, **k: pytest.fail("solved"))
    with pytest.raises(ValueError, match="action_bound"):
        reference_record("peers/hager")


# ---- the certified optimum (one solve per module: about 40 s on the 2-core machine) ----------------------------


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    folder = tmp_path_factory.mktemp("spec")
    spec = _copy(folder)
    reference._memo.clear()
    return spec, reference_record(spec, cache_dir=folder / "cache"), folder / "cache"


@pytest.mark.slow
def test_the_certificate_is_two_converged_methods_that_agree(solved):
    _, r, _ = solved
    c = r["optimal"]["certificate"]
    assert c["methods"] == ["ipopt", "interior_point"] and c["agreement"] <= c["tolerance"] == optimum.AGREEMENT_RTOL
    scale = max(abs(r["optimal"]["cost"]), abs(r["random"]["cost"] - r["optimal"]["cost"]))
    assert abs(c["costs"]["ipopt"] - c["costs"]["interior_point"]) <= 1e-6 * scale
    assert r["optimal"]["cost"] == pytest.approx(min(c["costs"].values()), rel=1e-12)  # batched replay: ulps
    assert r["env"] == {"version": 0, "steps": 100, "integrator": "heun", "substeps": 1, "penalty": 100.0,
                        "hold": "zero-order", "action_bound": None}


@pytest.mark.slow
def test_the_optimum_is_within_one_percent_of_a_fine_grid_solve_of_the_continuous_problem(solved):
    spec, r, _ = solved
    fine = solve(load(spec), HermiteSimpson(intervals=200), resimulate=False)
    assert fine.converged
    assert abs(r["optimal"]["cost"] - fine.cost) <= 0.01 * abs(fine.cost)
    assert abs(fine.cost - (-0.0480556)) <= 1e-4 * 0.0480556  # COPS' optimum: the fine solve is the continuous one


@pytest.mark.slow
def test_the_env_replays_the_certified_cost_and_scores_it_100(solved):
    spec, r, cache = solved
    env = reference.reference_env(spec)
    episode = play(env, np.asarray(r["optimal"]["controls"]), env.default_params())
    assert abs(float(episode.cost) - r["optimal"]["cost"]) <= 1e-8 * max(1.0, abs(r["optimal"]["cost"]))
    # The Gymnasium-facing env (actions normalised to [-1, 1]) gives the same return for the same controls.
    normed = reference.Env(env.system, EnvOptions())
    lo, hi = normed.control_bounds
    actions = 2.0 * (np.asarray(r["optimal"]["controls"]) - lo) / (hi - lo) - 1.0
    assert float(play(normed, actions, env.default_params()).cost) == pytest.approx(float(episode.cost), abs=1e-12)
    reference._memo.update({reference.cache_key(spec): reference_record(spec, cache_dir=cache)})
    assert normalized_score(spec, float(episode.cost)) == pytest.approx(100.0, abs=1e-6)


@pytest.mark.slow
def test_a_random_policy_scores_0(solved):
    spec, r, cache = solved
    reference._memo.update({reference.cache_key(spec): r})
    assert normalized_score(spec, r["random"]["cost"]) == pytest.approx(0.0, abs=1e-6)
    # Independent draws (another generator, 400 episodes): 0 within five standard errors.
    env = reference.reference_env(spec)
    lo, hi = env.control_bounds
    us = lo + np.random.default_rng(7).uniform(size=(400, env.options.steps, env.action_size)) * (hi - lo)
    costs = np.asarray(jax.vmap(lambda u: play(env, u, env.default_params()).cost)(us))
    se = 100.0 * np.std(costs) / np.sqrt(costs.size) / (r["random"]["cost"] - r["optimal"]["cost"])
    assert abs(normalized_score(spec, float(np.mean(costs)))) <= 5 * se


@pytest.mark.slow
def test_the_cache_hit_returns_the_record_without_solving(solved, monkeypatch):
    spec, r, cache = solved
    monkeypatch.setattr(reference, "compute", lambda *a, **k: pytest.fail("solved again"))
    assert reference_record(spec, cache_dir=cache) == r


@pytest.mark.slow
def test_a_disagreement_beyond_the_tolerance_is_an_error(solved, monkeypatch):
    spec, _, _ = solved
    solve_one = optimum._solve

    def interior_point_off_by_1e_5(env, solver, start):  # as if it had stopped in another local minimum
        controls, result, cost = solve_one(env, solver, start)
        return controls, result, cost * (1 + 1e-5) if isinstance(solver, optimum.InteriorPoint) else cost

    monkeypatch.setattr(optimum, "_solve", interior_point_off_by_1e_5)
    with pytest.raises(CertificationError, match="disagree"):
        reference.compute(spec)


def test_a_schema_3_specs_reference_env_is_its_nominal_problem():
    """Scores normalise against the nominal optimum: the reference env neither draws the uncertain parameters nor
    adds noise, whatever the options ask, and those options are not part of the key."""
    spec = Path(__file__).parents[3] / "tests" / "compiler" / "schema3" / "uncertain_oscillator.yaml"
    asked = EnvOptions(widen=2.0, process_noise_scale=3.0, observation_noise_scale=3.0)
    env = reference.reference_env(spec, asked)
    assert not env.randomized and env.process_sigma is None and env.observation_std is None
    assert reference.cache_key(spec, asked) == reference.cache_key(spec)
