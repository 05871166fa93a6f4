"""Datasets on disk (runtime/datasets/storage.py and the ``myriad dataset`` command): Minari loads what we write and
its episodes are ours, bit for bit; the same seed writes the same bytes; a write is atomic and never overwrites; the
provenance recovers the env; our loader refuses another spec or env version."""

import hashlib
import json
import os

import minari
import numpy as np
import pytest

from myriad.runtime import cli
from myriad.runtime.datasets import collect
from myriad.runtime.datasets.storage import dataset_id, load_dataset, write_dataset
from myriad.runtime.loader import load

SYSTEM = "van_der_pol"


@pytest.fixture(scope="module")
def eps():
    return collect(SYSTEM, "random", episodes=3, seed=0)


@pytest.fixture(scope="module")
def written(eps, tmp_path_factory):
    out = tmp_path_factory.mktemp("datasets")
    return out, write_dataset(eps, out), write_dataset(eps, out, fmt="npz")


def _digests(folder):
    return {os.path.relpath(os.path.join(root, f), folder): hashlib.sha256(open(os.path.join(root, f), "rb").read())
            .hexdigest() for root, _, files in os.walk(folder) for f in files}


def test_minari_loads_the_dataset_and_its_episodes_are_ours(eps, written, monkeypatch):
    out, path, _ = written
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    dataset = minari.load_dataset(dataset_id(SYSTEM, "random"))
    assert dataset.total_episodes == 3 and dataset.total_steps == 300
    for e, episode in enumerate(dataset.iterate_episodes()):
        for field in ("observations", "actions", "rewards", "terminations", "truncations"):
            np.testing.assert_array_equal(getattr(episode, field), getattr(eps, field)[e])
        np.testing.assert_array_equal(episode.infos["state"], eps.states[e])
    meta = dataset.storage.metadata
    # ref_max_score is the env's optimum: no episode of any policy returns more (random ones far less).
    assert meta["ref_min_score"] < meta["ref_max_score"] and eps.returns.max() < meta["ref_max_score"]
    normalised = minari.get_normalized_score(dataset, eps.returns)
    assert np.all(normalised < 0.5)
    env = dataset.recover_environment()
    assert env.spec.id == "myriad/VanDerPol-v0" and env.unwrapped.core.options.normalize_actions
    prov = meta["myriad"]
    assert prov["spec_sha256"] == load(SYSTEM).spec_sha256 and prov["seed"] == 0 and prov["policy"] == "random"
    assert hashlib.sha256(prov["spec_text"].encode()).hexdigest() == prov["spec_sha256"]


def test_the_env_minari_recovers_replays_an_episode(eps, written, monkeypatch):
    out, _, _ = written
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    env = minari.load_dataset(dataset_id(SYSTEM, "random")).recover_environment()
    env.reset(seed=0)
    total = sum(env.step(a)[1] for a in eps.actions[0].astype(np.float32))
    # The Gymnasium env takes float32 actions (its space): the return agrees to float32's resolution.
    np.testing.assert_allclose(total, eps.returns[0], rtol=1e-5)


def test_our_loader_reads_both_formats_and_refuses_another_spec_or_env_version(eps, written, tmp_path):
    _, path, npz = written
    for where in (path, npz):
        back, meta = load_dataset(where, SYSTEM)
        for field in ("observations", "actions", "rewards", "terminations", "truncations", "states", "returns"):
            np.testing.assert_array_equal(getattr(back, field), getattr(eps, field))
        assert meta["env_version"] == 0 and back.info["policy"] == "random"
        with pytest.raises(ValueError, match=r"van_der_pol \(spec sha256 .*not of pendulum"):
            load_dataset(where, "pendulum")
    copy = tmp_path / "old"
    os.system(f"cp -r {path} {copy}")
    data = copy / "data" / "metadata.json"
    doc = json.loads(data.read_text())
    doc["myriad"]["env_version"] = 99
    data.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="env version 99; this myriad reads .*env version 0"):
        load_dataset(copy)


def test_the_same_seed_writes_the_same_bytes(eps, written, tmp_path):
    out, _, _ = written
    again = collect(SYSTEM, "random", episodes=3, seed=0)
    write_dataset(again, tmp_path)
    write_dataset(again, tmp_path, fmt="npz")
    assert _digests(tmp_path) == _digests(out)
    assert len(_digests(out)) == 5  # two namespace files, the HDF5 data, its metadata, the .npz: no temp left


def test_a_write_never_overwrites_and_a_failed_one_leaves_nothing(eps, written, tmp_path, monkeypatch):
    out, _, _ = written
    for fmt in ("minari", "npz"):
        with pytest.raises(FileExistsError, match="exists"):
            write_dataset(eps, out, fmt=fmt)

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(minari, "create_dataset_from_buffers", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        write_dataset(eps, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_the_command_writes_a_dataset_minari_loads_and_refuses_to_overwrite(tmp_path, monkeypatch, capsys):
    argv = ["dataset", SYSTEM, "--policy", "random", "--episodes", "2", "--seed", "5", "--start-noise", "0.1",
            "--out", str(tmp_path)]
    assert cli.main(argv) == 0
    assert "minari.load_dataset('myriad/van_der_pol/random-v0')" in capsys.readouterr().out
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    dataset = minari.load_dataset("myriad/van_der_pol/random-v0")
    assert dataset.total_episodes == 2 and dataset.storage.metadata["myriad"]["perturb"]["start"] == 0.1
    assert cli.main(argv) == 2
    assert "exists (never overwritten)" in capsys.readouterr().err


def test_the_command_exits_1_naming_episodes_whose_plan_failed(capsys):
    from myriad.runtime.datasets.cli import _solver_warnings

    assert _solver_warnings({"plan_status": ["converged", "converged"]}) == 0
    assert _solver_warnings({"plan_status": ["converged", "iteration_limit"]}) == 1
    assert "episodes [1] did not converge (iteration_limit)" in capsys.readouterr().err
    assert _solver_warnings({"replan_failures": [0, 2]}) == 1 and "episodes [1]" in capsys.readouterr().err


@pytest.mark.parametrize(("extra", "words"), [
    (["--episodes", "0"], "--episodes must be a positive integer"),
    (["--env", '{"steps": 0}'], "--env"),
    (["--env", '{"no_such_option": 1}'], "--env"),
    (["--env", '{"start_noise": 0.1}'], "--start-noise"),
    (["--name", "a/b"], "--name"),
    (["--param-noise", "1.5"], "--param-noise"),
])
def test_the_command_refuses_bad_arguments_before_any_work(tmp_path, capsys, extra, words):
    assert cli.main(["dataset", SYSTEM, "--out", str(tmp_path), *extra]) == 2
    assert words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # a spec that does not ship: its reference scores are computed (item 1) and its env registered
def test_a_dataset_of_a_spec_that_does_not_ship(tmp_path, monkeypatch):
    monkeypatch.setenv("MYRIAD_RL_REFERENCE_CACHE", str(tmp_path / "reference"))
    spec = "specs/peers/lotka_volterra_fishing.yaml"
    argv = ["dataset", spec, "--policy", "optimal", "--episodes", "5", "--out", str(tmp_path)]
    assert cli.main(argv) == 0
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    dataset = minari.load_dataset("myriad/lotka_volterra_fishing/optimal-v0")
    returns = np.array([e.rewards.sum() for e in dataset.iterate_episodes()])
    np.testing.assert_allclose(100 * minari.get_normalized_score(dataset, returns), 100.0, atol=0.5)
    env = dataset.recover_environment()
    assert env.spec.id.startswith("myriad-spec/LotkaVolterraFishing-")
    back, _ = load_dataset(tmp_path / "myriad/lotka_volterra_fishing/optimal-v0", spec)
    np.testing.assert_array_equal(back.returns, returns)
