"""Behaviour cloning and DAgger end to end (runtime/imitation/run.py, dagger.py, expert.py, cli.py) on Van der Pol:
5 optimal demonstrations, the policy scored in the env by normalised score; DAgger 2 iterations of 1 rollout.

Sized for the suite (issue 29): one behaviour-cloning fit serves BC's record and DAgger's start (DAgger resumes BC's
finished fit from its checkpoint, the same network), the killed DAgger run is compared with that uninterrupted one,
and determinism is checked on a short fit run twice. The issue's own bar (20 demonstrations, the default DAgger
schedule) is Table E's (bench/imitation_table.py; runtime/imitation/README.md, Measurements)."""

import dataclasses
import json
import shutil

import jax
import numpy as np
import pytest

from myriad.runtime.cli import main
from myriad.runtime.imitation import DaggerConfig, FitConfig, ImitateConfig, run_imitation
from myriad.runtime.imitation.expert import Expert
from myriad.runtime.rl.mpc import MPC
from myriad.runtime.rl.reference import reference_env

jax.config.update("jax_enable_x64", True)
pytestmark = pytest.mark.slow  # whole imitation runs: demonstrations by the interior point, fits, expert labels

BC = ImitateConfig(method="bc", demos=5, seed=0)
DAGGER = dataclasses.replace(BC, method="dagger", dagger=DaggerConfig(iterations=2, rollouts=1))


def _scores(report):
    rec = report.record()
    return {k: rec[k] for k in ("normalized_score", "episode_return", "mismatch", "noise", "dagger_history")}


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    return tmp_path_factory.mktemp("imitate")


@pytest.fixture(scope="module")
def bc(checkpoints):
    return run_imitation("van_der_pol", BC, checkpoint_dir=checkpoints, progress=False)


@pytest.fixture(scope="module")
def dagger(bc, checkpoints):  # resumes BC's finished fit (checkpoints/bc): DAgger starts from BC's own network
    return run_imitation("van_der_pol", DAGGER, checkpoint_dir=checkpoints, resume=True, progress=False)


def test_behaviour_cloning_from_optimal_demonstrations_scores_at_least_80(bc):
    rec = bc.record()
    assert rec["status"] in ("max_epochs", "early_stopping") and not bc.failed
    assert rec["normalized_score"] >= 80.0, rec
    assert rec["mismatch"]["normalized_score"] > 50.0 and rec["noise"]["normalized_score"] > 50.0
    assert rec["method"] == "bc" and rec["demos"] == 5 and rec["seed"] == 0
    assert rec["config"]["start_noise"] == 0.1 and rec["demonstrations_skipped"] == 0


def test_dagger_scores_at_least_behaviour_clonings(bc, dagger):
    rec = dagger.record()
    assert rec["status"] == "completed" and rec["expert_failures"] == 0
    assert rec["expert_labels"] == 1 + 2 * 1 * 100  # the plan from x0, then every visited state
    assert dagger.fit_history == bc.fit_history  # the resumed finished fit: BC's, without another epoch
    assert rec["dagger_history"][0][2] == pytest.approx(-bc.record()["episode_return"], rel=1e-12)  # starts at BC
    assert len(rec["dagger_history"]) == 3 and all(np.isfinite(row[2]) for row in rec["dagger_history"])
    assert rec["normalized_score"] >= bc.record()["normalized_score"]


def test_the_expert_labels_are_the_mpc_planners_solutions():
    """The batched interior point and MPC's IPOPT solve the same planning problem from the same states."""
    env = reference_env("van_der_pol")
    expert, mpc = Expert(env), MPC(env, replan_every=1)
    plan0 = expert.optimal_plan(env.default_params().x0)
    xs = np.asarray(env.default_params().x0) * np.array([[1.0, 1.0], [1.05, 0.95]])
    plans, ok = expert.label(xs, np.array([10, 40]), np.stack([plan0, plan0]))
    assert ok.all()
    for b, k in enumerate((10, 40)):
        reference, _ = mpc.plan(xs[b], k, plan0)
        np.testing.assert_allclose(plans[b, k:], reference[k:], atol=1e-6)
        np.testing.assert_array_equal(plans[b, :k], plan0[:k])


def test_the_same_seed_gives_the_same_record_and_another_seed_another():
    short = dataclasses.replace(BC, seed=1, fit=FitConfig(epochs=15))  # BC's shapes: nothing compiles again
    first, again = (run_imitation("van_der_pol", short, progress=False) for _ in range(2))
    assert _scores(again) == _scores(first) and again.fit_history == first.fit_history
    assert len(first.fit_history) == 15
    other = run_imitation("van_der_pol", dataclasses.replace(short, seed=2), progress=False)
    assert other.fit_history != first.fit_history


def test_a_killed_dagger_run_resumes_losing_at_most_one_iteration(dagger, checkpoints, tmp_path, monkeypatch):
    shutil.copytree(checkpoints / "bc", tmp_path / "bc")  # BC's finished fit: both runs go straight to DAgger
    label, calls = Expert.label, []

    def killed(self, *args):  # dies 10 steps into the second iteration's rollout
        calls.append(1)
        if len(calls) == 1 + 100 + 10:
            raise KeyboardInterrupt
        return label(self, *args)

    monkeypatch.setattr(Expert, "label", killed)
    with pytest.raises(KeyboardInterrupt):
        run_imitation("van_der_pol", DAGGER, checkpoint_dir=tmp_path, resume=True, progress=False)
    monkeypatch.setattr(Expert, "label", label)
    assert json.loads((tmp_path / "dagger" / "checkpoint.json").read_text())["epoch"] == 1
    resumed = run_imitation("van_der_pol", DAGGER, checkpoint_dir=tmp_path, resume=True, progress=False)
    assert _scores(resumed) == _scores(dagger)  # the uninterrupted run's, to the last bit
    assert resumed.counts == dagger.counts  # the expert's count restored: the first iteration was not labelled again


def test_the_command_writes_its_record_and_plots_and_fails_on_a_failed_training(tmp_path, capsys):
    out = tmp_path / "r.json"
    args = ["imitate", "simple_case", "--demos", "3", "--set", "fit.epochs=30", "--json", str(out)]
    assert main([*args, "--plots", str(tmp_path / "plots")]) == 0
    rec = json.loads(out.read_text())
    assert {"normalized_score", "episode_return", "method", "demos", "seed", "status"} <= set(rec)
    assert rec["method"] == "bc" and rec["demos"] == 3 and rec["config"]["fit"]["epochs"] == 30
    assert (tmp_path / "plots" / "loss.png").is_file() and (tmp_path / "plots" / "episode.png").is_file()
    assert main([*args, "--set", "fit.learning_rate=1e300"]) == 1
    assert json.loads(out.read_text())["status"] == "non_finite"
    assert "the training failed" in capsys.readouterr().err


def test_demonstrations_from_a_dataset_and_a_wrong_specs_dataset_refused(tmp_path):
    from myriad.runtime.datasets import collect
    from myriad.runtime.datasets.storage import write_dataset

    episodes = collect("simple_case", "optimal", episodes=3, seed=1)  # actions in [-1, 1]: mapped onto the controls
    path = str(write_dataset(episodes, tmp_path / "data", fmt="npz"))
    assert main(["imitate", "van_der_pol", "--dataset", path, "--demos", "3"]) == 2  # another spec's
    assert main(["imitate", "simple_case", "--dataset", path, "--demos", "5"]) == 2  # too few episodes
    out = tmp_path / "r.json"
    assert main(["imitate", "simple_case", "--dataset", path, "--demos", "3", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["normalized_score"] >= 80.0


def test_with_beta_1_the_rollouts_are_the_experts_closed_loop_which_stays_on_the_optimum():
    """beta = 1: the expert plays every step. From the nominal start with the nominal model, re-solving from a state
    on the optimal trajectory gives the rest of the same plan (the principle of optimality), so the rollout visits
    the optimal trajectory and every label is the optimal plan's control there."""
    from myriad.runtime.imitation.dagger import _Dagger
    from myriad.runtime.imitation.fit import FitConfig, Pairs
    from myriad.runtime.imitation.policy import Policy
    from myriad.runtime.rl.env import play

    env = reference_env("simple_case")
    policy = Policy.of(env, width=8, depth=1)
    net = policy.init(jax.random.PRNGKey(0))
    pairs = Pairs.of(np.zeros((4, 2)), np.zeros((4, 1)))
    config = DaggerConfig(iterations=1, rollouts=2, beta=1.0, start_noise=0.0)
    learner = _Dagger(env, policy, net, pairs, pairs, Expert(env), config, FitConfig(), 0, None, ("", {}))
    obs, labels, weights = learner._label(0)
    optimum = play(env, learner.plan0, env.default_params())
    assert weights.all()
    for e in range(2):
        np.testing.assert_allclose(obs[e * 100:(e + 1) * 100, :1], np.asarray(optimum.states)[:-1], atol=1e-6)
        np.testing.assert_allclose(labels[e * 100:(e + 1) * 100], policy.normalise(learner.plan0), atol=1e-6)


def _episodes(n, bad, info=None):
    """n synthetic episodes of 4 steps (observation e + k, action e), those in ``bad`` with a failed plan and an
    overflowing state (as Bacteria's starts near 0 give)."""
    from myriad.runtime.datasets import Episodes

    obs = np.arange(n, dtype=float)[:, None, None] + np.arange(5.0)[None, :, None] * np.ones((1, 1, 2))
    acts = np.repeat(np.arange(n, dtype=float)[:, None, None], 4, axis=1) / n
    bad = [e for e in bad if e < n]
    obs[bad, 2:, 0] = np.inf
    status = ["not_finite" if e in bad else "converged" for e in range(n)]
    return Episodes(obs, acts, np.zeros((n, 4)), np.zeros((n, 4), bool), np.zeros((n, 4), bool), obs[..., :1],
                    np.where(np.isin(np.arange(n), list(bad)), -np.inf, 0.0), {},
                    {"options": {"normalize_actions": False}, "plan_status": status, **(info or {})})


def test_demonstrations_skip_episodes_whose_plan_failed_and_draw_past_them(monkeypatch):
    """The first `demos` usable episodes of the seed's sequence: a failed plan (non-finite states) is no
    demonstration; more episodes are drawn (episode e is the same whatever their number), and too few is an error."""
    import myriad.runtime.datasets as datasets
    from myriad.runtime.imitation.run import _demonstrations, usable
    from myriad.runtime.loader import load

    assert usable(_episodes(4, {1, 3})).tolist() == [True, False, True, False]
    drawn = []

    def collect(system, policy, *, episodes, **kwargs):
        drawn.append(episodes)
        return _episodes(episodes, {1, 3, 4})

    monkeypatch.setattr(datasets, "collect", collect)
    system = load("simple_case")
    obs, acts, skipped = _demonstrations(system, ImitateConfig(demos=4, seed=0), None, final=False)
    assert drawn == [4, 4 + 2 * 2 + 2] and skipped == 3
    np.testing.assert_array_equal(acts[:, 0, 0] * 10, [0, 2, 5, 6])  # episodes 0, 2, 5, 6 of the longer draw
    assert obs.shape == (4, 4, 2) and np.isfinite(obs).all()
    monkeypatch.setattr(datasets, "collect", lambda system, policy, *, episodes, **kw: _episodes(
        episodes, set(range(1, episodes))))  # four draws (2, 6, 10, 14 episodes), one usable
    with pytest.raises(ValueError, match="only 1 of 14 optimal plans .* converged.*lower --start-noise"):
        _demonstrations(system, ImitateConfig(demos=2, seed=0), None, final=False)


def test_a_dagger_rollout_that_overflows_does_not_make_the_refit_non_finite():
    """Rows of non-finite observations (a rollout past where the dynamics are finite; their labels failed, weight 0)
    are zeroed: a weight of 0 times the network's NaN output would still be NaN."""
    from myriad.runtime.imitation.dagger import _Dagger
    from myriad.runtime.imitation.fit import Pairs
    from myriad.runtime.imitation.policy import Policy

    env = reference_env("simple_case")
    policy = Policy.of(env, width=8, depth=1)
    net = policy.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(0)
    pairs = Pairs.of(rng.normal(size=(20, 2)), rng.uniform(-1, 1, (20, 1)))
    config = DaggerConfig(iterations=1, rollouts=1)
    learner = _Dagger(env, policy, net, pairs, pairs, Expert(env), config, FitConfig(epochs=3), 0, None, ("", {}))
    obs, labels = rng.normal(size=(100, 2)), rng.uniform(-1, 1, (100, 1))
    obs[60:, 0], labels[60:] = np.inf, np.nan
    learner._label = lambda index: (obs.copy(), labels.copy(), np.r_[np.ones(60), np.zeros(40)])
    step = learner.step(0)
    assert step.stop is None, step
    assert np.isfinite(learner.history[-1][1]) and np.isfinite(learner.buffer.obs).all()
    assert learner.buffer.weights[20 + 60:].sum() == 0 and learner.buffer.weights[20:80].all()
