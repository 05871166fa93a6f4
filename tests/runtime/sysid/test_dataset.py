"""System-identification datasets: sampling statistics, the true dynamics, determinism, bounds, files on disk."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from myriad.runtime import Adaptive, load, simulate
from myriad.runtime.atomic import atomic_open, atomic_write_text
from myriad.runtime.learn import dataset as dataset_module
from myriad.runtime.learn.dataset import Sampling, Trajectories, load_dataset, make_dataset, save_dataset

SPECS = Path(__file__).resolve().parents[3] / "specs"


def _all(d):
    return [d.times, *d.train, *d.validation, *d.test]


def _same_bits(a, b):
    return all(x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes() for x, y in zip(a, b))


@pytest.fixture(scope="module")
def cancer():
    return make_dataset("cancer_treatment", trajectories=(6, 2, 2), seed=0)


@pytest.fixture(scope="module")
def vdp_walk():
    # van der Pol: u in [-0.75, 1], an asymmetric range (1.75) so a formula using u_max or |u_min| alone fails.
    return make_dataset("van_der_pol", Sampling(spread=0.02), trajectories=(50, 0, 0), seed=3)


@pytest.fixture(scope="module")
def vdp_uniform():
    return make_dataset("van_der_pol", Sampling(controls="uniform"), trajectories=(20, 0, 0), seed=5)


def test_shapes_and_identity(cancer):
    s = load("cancer_treatment")
    assert (cancer.n_train, cancer.n_validation, cancer.n_test, cancer.intervals) == (6, 2, 2, 100)
    assert cancer.train.controls.shape == (6, 101, 1) and cancer.test.states.shape == (2, 101, 1)
    assert all(a.dtype == np.float64 and not a.flags.writeable for a in _all(cancer))
    np.testing.assert_allclose(cancer.times, np.linspace(0, 20, 101), rtol=0, atol=0)
    assert (cancer.system, cancer.spec_sha256, cancer.seed) == (s.name, s.spec_sha256, 0)
    assert (cancer.n_states, cancer.n_controls, cancer.horizon) == (1, 1, 20.0)
    # a dataset is rebuilt (and re-checked) by dataclasses.replace, e.g. to merge datasets in sequence
    both = dataclasses.replace(cancer, train=Trajectories(*(np.concatenate([a, a]) for a in cancer.train)))
    assert both.n_train == 12 and not both.train.states.flags.writeable
    with pytest.raises(ValueError, match="NaN"):
        dataclasses.replace(cancer, train=Trajectories(cancer.train.controls, cancer.train.states * np.nan))


def test_same_seed_same_bits_other_seed_other_bits(cancer):
    again = make_dataset("cancer_treatment", trajectories=(6, 2, 2), seed=0)
    assert _same_bits(_all(cancer), _all(again))
    other = make_dataset("cancer_treatment", trajectories=(6, 2, 2), seed=1)
    assert not np.array_equal(cancer.train.controls, other.train.controls)
    assert not np.array_equal(cancer.train.states[:, 0], other.train.states[:, 0])


def test_random_walk_steps_have_std_spread_times_range(vdp_walk):
    lo, hi = -0.75, 1.0
    u = vdp_walk.train.controls[..., 0]
    assert u.min() >= lo and u.max() <= hi
    s = 0.02 * (hi - lo)
    d = np.diff(u, axis=1)
    inside = (u[:, :-1] > lo) & (u[:, :-1] < hi) & (u[:, 1:] > lo) & (u[:, 1:] < hi)  # steps the clip left alone
    assert inside.sum() > 4000
    assert abs(d[inside].std() / s - 1) < 0.05, (d[inside].std(), s)
    assert abs(d[inside].mean()) < 4 * s / np.sqrt(inside.sum())
    # u_0 ~ U(u_min, u_max): spread over the whole range
    assert u[:, 0].min() < lo + 0.15 * (hi - lo) and u[:, 0].max() > hi - 0.15 * (hi - lo)


def test_noise_free_states_are_the_true_rollout(cancer, vdp_walk):
    for name, d in (("cancer_treatment", cancer), ("van_der_pol", vdp_walk)):
        system = load(name)
        a = system.arrays()
        for split in (d.train, d.validation, d.test):
            for u, x in zip(split.controls[:5], split.states[:5]):
                sim = simulate(system, u, x0=x[0])
                np.testing.assert_allclose(x, np.asarray(sim.states), rtol=0, atol=1e-12)
        starts = d.train.states[:, 0]
        assert np.all(starts >= a["x_lower"]) and np.all(starts <= a["x_upper"])
        assert not np.allclose(starts, a["x0"])  # perturbed (x0_std = 0.1)


def test_uniform_controls_are_iid_over_the_whole_range(vdp_uniform):
    lo, hi = -0.75, 1.0
    u = vdp_uniform.train.controls[..., 0]
    assert u.min() >= lo and u.max() <= hi
    assert u.max() > hi - 0.02 * (hi - lo)  # the published code's factor 0.75 would cap it at 0.75
    assert abs(u.mean() - (lo + hi) / 2) < 4 * (hi - lo) / np.sqrt(12 * u.size)
    lag1 = np.corrcoef(u[:, :-1].ravel(), u[:, 1:].ravel())[0, 1]
    assert abs(lag1) < 0.1


def test_smoothing_is_the_published_kernel_twice(vdp_uniform):
    smooth = make_dataset("van_der_pol", Sampling(controls="uniform", smooth=True), trajectories=(20, 0, 0), seed=5)
    kernel = np.array([0.15286624, 0.22292994, 0.24840764, 0.22292994, 0.15286624])  # as published (8 digits)
    expected = vdp_uniform.train.controls.copy()
    for _ in range(2):
        for i in range(expected.shape[0]):
            expected[i, :, 0] = np.convolve(np.pad(expected[i, :, 0], 2, mode="edge"), kernel, mode="valid")
    np.testing.assert_allclose(smooth.train.controls, expected, rtol=0, atol=1e-7)
    assert smooth.train.controls.min() >= -0.75 and smooth.train.controls.max() <= 1.0


def test_around_stays_near_the_given_controls():
    t = np.linspace(0, 20, 101)
    given = 1.0 + 0.5 * np.sin(t)  # within [0, 2]; 1-D is accepted for one control
    d = make_dataset("cancer_treatment", Sampling(controls="around", spread=0.01), trajectories=(8, 1, 1),
                     around=given)
    dev = d.train.controls[..., 0] - given
    s = 0.01 * 2.0
    assert 0 < np.abs(dev).max() < 5 * s
    assert abs(dev.std() / s - 1) < 0.1
    assert d.train.controls.min() >= 0 and d.train.controls.max() <= 2
    with pytest.raises(ValueError, match="around"):
        make_dataset("cancer_treatment", Sampling(controls="around"))
    with pytest.raises(ValueError, match="around"):
        make_dataset("cancer_treatment", around=given)
    with pytest.raises(ValueError, match=r"shape \(101, 1\)"):
        make_dataset("cancer_treatment", Sampling(controls="around"), around=given[:50])


def test_adaptive_integrator_option():
    class Linear(type(load("cancer_treatment"))):  # x' = u - x: exact node to node under a piecewise-linear u
        dynamics = staticmethod(lambda x, u, t, p: u - x)

    d = make_dataset(Linear(), Sampling(integrator=Adaptive(), intervals=20), trajectories=(3, 0, 0), seed=2)
    assert d.sampling.integrator == Adaptive() and d.intervals == 20
    u, x = d.train.controls[..., 0], d.train.states[..., 0]
    h = 1.0
    slope = (u[:, 1:] - u[:, :-1]) / h  # on a step, x(s) = (x_k - u_k + slope) e^{-s} + u_k - slope + slope s
    exact_next = (x[:, :-1] - u[:, :-1] + slope) * np.exp(-h) + u[:, 1:] - slope
    np.testing.assert_allclose(x[:, 1:], exact_next, rtol=0, atol=1e-8)
    heun_next = x[:, :-1] + h / 2 * ((u[:, :-1] - x[:, :-1]) + (u[:, 1:] - (x[:, :-1] + h * (u[:, :-1] - x[:, :-1]))))
    assert np.abs(heun_next - exact_next).max() > 1e-3  # so Heun (h = 1) would have failed the check above


def test_save_load_round_trip_is_exact(cancer, tmp_path):
    path = save_dataset(cancer, tmp_path / "sub" / "data.npz")
    assert sorted(p.name for p in path.parent.iterdir()) == ["data.json", "data.npz"]  # no temp files left
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["system"] == "cancer_treatment" and side["seed"] == 0 and side["version"] == 1
    assert side["sampling"]["integrator"] == {"label": "heun", "fields": {}}
    assert side["sampling"]["spread"] == 0.05 and side["shapes"]["train_states"] == [6, 101, 1]
    for system in (None, "cancer_treatment", load("cancer_treatment")):
        back = load_dataset(path, system)
        assert _same_bits(_all(cancer), _all(back))
        assert (back.system, back.spec_sha256, back.seed, back.sampling) == (
            cancer.system, cancer.spec_sha256, cancer.seed, cancer.sampling)
    sampling = Sampling(controls="uniform", x0_relative=True, noise=0.5, smooth=True, integrator=Adaptive(rtol=1e-6))
    assert Sampling.from_record(json.loads(json.dumps(sampling.record()))) == sampling


def test_loading_with_another_spec_names_both_hashes(cancer, tmp_path, monkeypatch):
    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path / "cache"))
    path = save_dataset(cancer, tmp_path / "data.npz")
    text = (SPECS / "cancer_treatment.yaml").read_text()
    assert "value: 0.3," in text
    (tmp_path / "cancer_treatment.yaml").write_text(text.replace("value: 0.3,", "value: 0.31,", 1))
    changed = load(tmp_path / "cancer_treatment.yaml")
    assert changed.spec_sha256 != cancer.spec_sha256
    with pytest.raises(ValueError) as err:
        load_dataset(path, changed)
    assert cancer.spec_sha256 in str(err.value) and changed.spec_sha256 in str(err.value)
    with pytest.raises(ValueError) as err:
        load_dataset(path, "pendulum")
    msg = str(err.value)
    assert "'cancer_treatment'" in msg and "'pendulum'" in msg and load("pendulum").spec_sha256 in msg


def test_corrupt_files_are_refused(cancer, tmp_path):
    path = save_dataset(cancer, tmp_path / "data.npz")
    arrays = dict(np.load(path))

    def rewrite(**changes):
        np.savez(path, **{**arrays, **changes})

    states = arrays["train_states"].copy()
    states[1, 5, 0] = np.nan
    rewrite(train_states=states)
    with pytest.raises(ValueError, match="NaN"):
        load_dataset(path)
    rewrite(test_states=arrays["test_states"][:1])
    with pytest.raises(ValueError, match="sidecar says"):
        load_dataset(path)
    rewrite(train_states=arrays["train_states"] + 1e-9)
    with pytest.raises(ValueError, match="not the ones"):
        load_dataset(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(FileNotFoundError):
        load_dataset(path)
    with pytest.raises(ValueError, match=".npz"):
        save_dataset(cancer, tmp_path / "data.bin")


def test_missing_bounds_are_refused_before_any_work(tmp_path, monkeypatch):
    def no_work(*args, **kwargs):
        raise AssertionError("generation started before the bounds were checked")

    monkeypatch.setattr(dataset_module, "_generate", no_work)
    for controls in ("random_walk", "uniform"):
        with pytest.raises(ValueError, match="control `u` has lower bound -inf and upper bound inf"):
            save_dataset(make_dataset("simple_case", Sampling(controls=controls)), tmp_path / "d.npz")
    with pytest.raises(ValueError, match=r"noise=0.1 .* state `S` has upper bound inf"):
        make_dataset("epidemic", Sampling(noise=0.1))
    assert list(tmp_path.iterdir()) == []
    # the relative start spread needs a range only where x0 = 0
    scales = dataset_module.sampling_scales(load("pendulum"), Sampling(x0_std=0.1, x0_relative=True))
    np.testing.assert_allclose(scales[1], [0.2 * np.pi, 1.6])
    scales = dataset_module.sampling_scales(load("harvest"), Sampling(x0_std=0.1, x0_relative=True))
    np.testing.assert_allclose(scales[1], [0.04])


def test_blow_up_is_reported_with_a_count():
    base = type(load("cancer_treatment"))

    class Explodes(base):
        dynamics = staticmethod(lambda x, u, t, p: 10.0 * x**2)  # blows up at t ~ 0.1

    with pytest.raises(ValueError, match=r"4 of 4 generated trajectories are not finite \(train\[0\].*spread"):
        make_dataset(Explodes(), trajectories=(2, 1, 1))


@pytest.mark.parametrize("kwargs, field", [
    ({"controls": "walk"}, "controls"), ({"spread": -0.1}, "spread"), ({"x0_std": float("nan")}, "x0_std"),
    ({"noise": True}, "noise"), ({"intervals": 0}, "intervals"), ({"intervals": 10.0}, "intervals"),
    ({"integrator": "heun"}, "integrator"), ({"smooth": 1}, "smooth"),
])
def test_sampling_validation(kwargs, field):
    with pytest.raises(ValueError, match=f"Sampling: {field}"):
        Sampling(**kwargs)


def test_sizes_and_seed_validation():
    for kwargs in ({"trajectories": (0, 1, 1)}, {"trajectories": (1, -1, 1)}, {"trajectories": (1, 1)},
                   {"seed": -1}, {"seed": 1.5}):
        with pytest.raises(ValueError):
            make_dataset("cancer_treatment", **kwargs)


def test_atomic_write_leaves_old_file_or_new_one(tmp_path):
    target = tmp_path / "f.txt"
    atomic_write_text(target, "old")
    with pytest.raises(RuntimeError):
        with atomic_open(target) as f:
            f.write(b"partial")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["f.txt"]
    with pytest.raises(RuntimeError):
        with atomic_open(tmp_path / "new.txt") as f:
            raise RuntimeError("interrupted")
    assert [p.name for p in tmp_path.iterdir()] == ["f.txt"]
    atomic_write_text(target, "new")
    assert target.read_text() == "new"
