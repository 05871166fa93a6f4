"""The end-to-end learner as the third imitation method (runtime/imitation/e2e.py, ``--method e2e``): Cancer
Treatment's r and delta recovered from 3 optimal demonstrations through the planner, the learnt model's plan scored
like BC's and DAgger's policies, the kit's checkpoints and resume, and the refusals before any work."""

import dataclasses
import json

import jax
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.e2e import E2EConfig
from myriad.runtime.imitation import ImitateConfig, run_imitation
from myriad.runtime.imitation.e2e import PlanPolicy, check_starts, expert_of, learn_end_to_end
from myriad.runtime.imitation.run import demonstrations
from myriad.runtime.rl.reference import reference_env
from myriad.runtime.transcriptions import SingleShooting

jax.config.update("jax_enable_x64", True)

# The default E2EConfig: implicit, interior point, 300 iterations. Demonstrations from x0: 3 or 20 are one trajectory.
E2E = ImitateConfig(method="e2e", demos=3, seed=0)
# What every method's record holds (test_imitate.py's BC and DAgger records: these, DAgger's expert counts too).
RECORD = {"system", "spec_sha256", "method", "demos", "seed", "status", "message", "normalized_score",
          "episode_return", "mismatch", "noise", "seconds", "fit_epochs", "dagger_history", "config",
          "demonstrations_skipped"}


@pytest.fixture(scope="module")
def cancer():
    return load("cancer_treatment")


@pytest.fixture(scope="module")
def e2e(cancer):
    return run_imitation(cancer, E2E, progress=False)


@pytest.mark.slow
def test_e2e_from_optimal_demonstrations_recovers_the_parameters_and_scores_at_least_80(e2e):
    rec = e2e.record()
    assert rec["status"] == "completed" and not e2e.failed, rec["message"]
    learned, true = rec["e2e"]["learned"], rec["e2e"]["true"]
    assert set(learned) == set(true) == {"r", "delta"}  # the spec's guesses are 0.1 and 0.75: far off
    for name in true:
        assert abs(learned[name] - true[name]) <= 0.015 * true[name], (name, learned, true)
    assert rec["normalized_score"] >= 80.0 and rec["e2e"]["counts"]["implicit"] == 300
    assert rec["e2e"]["plan_status"] == "converged"  # the learnt parameters' plan on the env's own problem
    # An open-loop plan observes nothing: its noise score is its nominal one; mismatch plays it in another env.
    assert rec["noise"]["normalized_score"] == rec["normalized_score"]
    assert np.isfinite(rec["mismatch"]["normalized_score"])
    assert set(rec) == RECORD | {"e2e"} and rec["method"] == "e2e" and rec["demos"] == 3 and rec["seed"] == 0
    assert rec["config"]["start_noise"] == 0.0 and rec["config"]["e2e"]["iterations"] == 300
    assert set(rec["seconds"]) == {"demonstrations", "e2e", "score"}
    json.dumps(rec, allow_nan=False)


@pytest.mark.slow
def test_a_resumed_run_continues_bit_for_bit_from_the_kits_checkpoint(cancer, tmp_path):
    env = reference_env(cancer)
    obs, controls = demonstrations(cancer, E2E, final=True)  # E2E's demonstrations: their solve compiled already
    config = dataclasses.replace(E2E.e2e, iterations=4, checkpoint_every=2)
    run = lambda c, **kw: learn_end_to_end(cancer, env, obs, controls, c, progress=False, **kw)  # noqa: E731
    whole = run(config)
    run(dataclasses.replace(config, iterations=2), checkpoint_dir=tmp_path)  # stopped after 2 of 4 iterations
    assert json.loads((tmp_path / "checkpoint.json").read_text())["epoch"] == 2
    resumed = run(config, checkpoint_dir=tmp_path, resume=True)
    assert resumed.report.learned == whole.report.learned and resumed.report.history == whole.report.history
    np.testing.assert_array_equal(resumed.plan, whole.plan)


def test_a_spec_without_learnable_parameters_is_refused_before_any_work(capsys, monkeypatch):
    import myriad.runtime.imitation.run as run

    def never(*args, **kwargs):
        raise AssertionError("demonstrations collected before the refusal")

    monkeypatch.setattr(run, "demonstrations", never)
    assert main(["imitate", "simple_case", "--method", "e2e"]) == 2
    err = capsys.readouterr().err
    assert "simple_case declares no learnable parameters" in err and "learnable: true" in err
    assert "e2e.model=node" in err
    with pytest.raises(ValueError, match="no learnable parameters"):
        run_imitation("simple_case", ImitateConfig(method="e2e"), progress=False)


def test_e2e_demonstrations_start_at_the_specs_x0_and_perturbed_starts_are_refused(cancer):
    assert ImitateConfig(method="e2e").starts == 0.0 and ImitateConfig().starts == 0.1
    assert ImitateConfig(method="e2e", start_noise=0.2).starts == 0.2  # given: kept (and refused below)
    # The method's default applies until start_noise is set: replacing the method changes it.
    assert dataclasses.replace(ImitateConfig(), method="e2e").starts == 0.0
    assert dataclasses.replace(ImitateConfig(method="e2e"), method="dagger").starts == 0.1
    assert dataclasses.replace(ImitateConfig(start_noise=0.05), method="e2e").starts == 0.05
    x0 = np.asarray(cancer.x0)
    obs = np.zeros((3, 11, cancer.n_states + 1))
    obs[:, 0, :-1] = x0
    check_starts(cancer, obs)
    obs[1, 0, 0] += 1e-3 * max(abs(x0[0]), 1.0)
    with pytest.raises(ValueError, match="spec's x0.*--start-noise 0"):
        check_starts(cancer, obs, "the demonstrations")


def test_held_actions_become_node_controls_exact_for_a_linear_control(cancer):
    """The env holds u_k over [t_k, t_k+1); the planner interpolates node controls linearly. A linear control's
    held actions (its values at the midpoints) give back its node values exactly."""
    N, T = 10, float(cancer.horizon)
    t = np.linspace(0.0, T, N + 1)
    line = lambda s: 0.2 + 0.3 * s / T  # noqa: E731
    held = line(0.5 * (t[:-1] + t[1:]))[None, :, None]
    obs = np.zeros((1, N + 1, cancer.n_states + 1))
    obs[:, :, :-1] = np.asarray(cancer.x0)
    expert = expert_of(cancer, obs, held, SingleShooting(intervals=N))
    np.testing.assert_allclose(expert.controls[1:-1, 0], line(t[1:-1]), rtol=0, atol=1e-15)
    assert expert.controls.shape == (N + 1, 1) and expert.converged and np.isfinite(expert.cost)


def test_a_plan_as_a_policy_plays_the_step_its_time_to_go_names():
    policy, plan = PlanPolicy(steps=4, horizon=2.0), np.arange(8.0).reshape(4, 2)
    to_go = 2.0 * (4 - np.arange(4)) / 4  # the env's T - t_k at steps 0..3
    obs = np.stack([np.full(4, 7.0), to_go + 1e-12], axis=-1)
    np.testing.assert_array_equal(np.asarray(policy.control(plan, obs)), plan)


def test_the_e2e_settings_are_flags_of_the_command():
    from myriad.runtime import cli
    from myriad.runtime.configs import from_args

    args = cli._parser().parse_args(["imitate", "cancer_treatment", "--method", "e2e", "--set", "e2e.iterations=7",
                                     "--set", "e2e.optimizer=0.05"])
    config = from_args(ImitateConfig, args)
    assert config.e2e == dataclasses.replace(E2E.e2e, iterations=7, optimizer=0.05) and config.starts == 0.0
    assert isinstance(config.e2e, E2EConfig)  # the kit's configuration, checked by it:
    assert cli.main(["imitate", "cancer_treatment", "--method", "e2e", "--set", "e2e.loss=plans"]) == 2


@pytest.mark.slow
def test_a_dataset_starting_elsewhere_or_on_another_grid_is_refused_before_any_learning(tmp_path, capsys):
    from myriad.runtime.datasets import Perturbation, collect
    from myriad.runtime.datasets.storage import write_dataset
    from myriad.runtime.rl.env import EnvOptions

    # Random policies: the refusals look at the starts and the grid only, so no plan need be solved for them.
    episodes = collect("cancer_treatment", "random", episodes=2, seed=0, perturb=Perturbation(start=0.1))
    path = str(write_dataset(episodes, tmp_path / "data", fmt="npz"))
    assert main(["imitate", "cancer_treatment", "--method", "e2e", "--dataset", path, "--demos", "2"]) == 2
    err = capsys.readouterr().err
    assert f"--dataset {path}" in err and "spec's x0" in err and "--start-noise 0" in err
    coarse = collect("cancer_treatment", "random", episodes=1, seed=0, options=EnvOptions(steps=50))
    path = str(write_dataset(coarse, tmp_path / "coarse", fmt="npz"))  # the plan is scored on the env's 100 steps
    assert main(["imitate", "cancer_treatment", "--method", "e2e", "--dataset", path, "--demos", "1"]) == 2
    assert "episodes of 50 steps" in capsys.readouterr().err
