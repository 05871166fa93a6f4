"""The expert from a system-identification dataset file: a trajectory recorded around the true optimum is that optimum
(states to rounding, the same cost), Algorithm 2 learns from it as from the solver's expert, and datasets that cannot
serve as an expert are refused before any work."""

import dataclasses

import numpy as np
import pytest

from myriad.runtime import load, solve
from myriad.runtime.cli import main
from myriad.runtime.e2e import E2EConfig, expert_from_dataset, run_e2e
from myriad.runtime.learn.dataset import Sampling, make_dataset, save_dataset
from myriad.runtime.learn.loop import Stop
from myriad.runtime.solvers import Ipopt
from myriad.runtime.transcriptions import SingleShooting

pytestmark = pytest.mark.slow  # not in `make test-fast`: end-to-end learning from a recorded expert

GRID = SingleShooting(intervals=50)
AROUND = Sampling(controls="around", spread=0.0, x0_std=0.0, intervals=50)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    system = load("cancer_treatment")
    optimum = solve(system, GRID, Ipopt(), resimulate=False)
    dataset = make_dataset(system, AROUND, trajectories=(2, 1, 1), seed=3, around=optimum.controls)
    path = save_dataset(dataset, tmp_path_factory.mktemp("expert") / "cancer.npz")
    return system, optimum, dataset, path


def test_a_recorded_optimum_is_the_optimum(recorded):
    system, optimum, dataset, path = recorded
    for source in (path, dataset):
        expert = expert_from_dataset(source, system, GRID, split="validation", index=0)
        assert expert.converged and expert.solver == "dataset"
        np.testing.assert_array_equal(expert.controls, optimum.controls)
        np.testing.assert_allclose(expert.states, optimum.states, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(expert.times, optimum.times, rtol=0, atol=1e-12)
        assert abs(expert.cost - optimum.cost) <= 1e-12 * abs(optimum.cost)


def test_learning_from_the_file_follows_learning_from_the_solver(recorded):
    system, optimum, _, path = recorded
    config = E2EConfig(iterations=4, reset_every=2)
    from_solver = run_e2e(system, config, transcription=GRID, expert=optimum, progress=False)
    from_file = run_e2e(system, config, transcription=GRID, expert=path, progress=False)
    assert from_file.status is from_solver.status is Stop.COMPLETED
    a, b = np.asarray(from_file.history), np.asarray(from_solver.history)
    np.testing.assert_allclose(a[:, 1], b[:, 1], rtol=1e-8)  # the imitation loss, iteration by iteration
    for name, value in from_solver.learned.items():
        assert abs(from_file.learned[name] - value) <= 1e-8 * abs(value)
    assert abs(from_file.record()["optimal_cost"] - optimum.cost) <= 1e-12 * abs(optimum.cost)


def test_datasets_that_cannot_be_an_expert_are_refused(recorded, tmp_path):
    system, optimum, dataset, path = recorded
    with pytest.raises(ValueError, match="index must be an integer in \\[0, 2\\)"):
        expert_from_dataset(dataset, system, GRID, index=2)
    with pytest.raises(ValueError, match="split must be one of"):
        expert_from_dataset(dataset, system, GRID, split="all")
    with pytest.raises(ValueError, match="uniform shooting grid of as many"):
        expert_from_dataset(dataset, system, SingleShooting(intervals=100))
    with pytest.raises(ValueError, match="spec sha256"):
        expert_from_dataset(path, load("bioreactor"), GRID)
    moved = make_dataset(system, dataclasses.replace(AROUND, x0_std=0.1), trajectories=(1, 0, 0),
                         around=optimum.controls)
    with pytest.raises(ValueError, match="x0_std=0"):
        expert_from_dataset(moved, system, GRID)


def test_cli_refuses_a_bad_expert_file_with_exit_2(recorded, tmp_path, capsys):
    _, _, _, path = recorded
    out = tmp_path / "e2e.json"
    code = main(["e2e", "cancer_treatment", "--expert", str(path), "--intervals", "100", "--json", str(out)])
    assert code == 2 and not out.exists()
    assert "uniform shooting grid" in capsys.readouterr().err
    assert main(["e2e", "cancer_treatment", "--expert", str(tmp_path / "none.npz")]) == 2
