"""Observation noise without finite state bounds (runtime/learn/dataset.py, ``Sampling.noise_scale``): refused with the
state and the fix under the published unit (the range), measured against each state's spread under ``"spread"``;
implausible noise refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.learn.dataset import Sampling, make_dataset

SPECS = Path(__file__).resolve().parents[3] / "specs"
NOISE = 0.05


@pytest.fixture(scope="module")
def free(tmp_path_factory):
    """Bioreactor with its one state unbounded."""
    spec = tmp_path_factory.mktemp("specs") / "free.yaml"
    text = (SPECS / "bioreactor.yaml").read_text()
    spec.write_text(text.replace("bounds: [0, 1], ", "").replace("name: bioreactor", "name: free"))
    return load(spec)


def _noise(system, noise_scale, u):
    """Exact replays of one control sequence (no perturbation): the observations minus the noise-free states."""
    exact = Sampling(controls="around", spread=0.0, x0_std=0.0, noise_scale=noise_scale)
    around = np.full((exact.intervals + 1, system.n_controls), u)
    clean = make_dataset(system, exact, trajectories=(20, 0, 0), seed=3, around=around).train.states
    noisy = make_dataset(system, Sampling(controls="around", spread=0.0, x0_std=0.0, noise=NOISE,
                                          noise_scale=noise_scale), trajectories=(20, 0, 0), seed=3,
                         around=around).train.states
    return clean, noisy - clean


def test_noise_on_an_unbounded_state_is_refused_with_the_state_and_the_fix(free):
    with pytest.raises(ValueError, match=r"noise=0.05 .* state `x` has lower bound -inf and upper bound inf; give `x` "
                                         r"finite bounds .* noise_scale='spread'"):
        make_dataset(free, Sampling(noise=NOISE))


def test_spread_noise_is_the_fraction_of_each_state_spread(free):
    clean, noise = _noise(free, "spread", u=0.9)  # x rises from 0.5 towards 0.9
    spread = clean.max() - clean.min()
    assert spread > 0.1  # the state moves: the unit is not degenerate
    # 20 x 101 draws: the sample std is within a few percent of NOISE * spread
    np.testing.assert_allclose(noise.std(), NOISE * spread, rtol=0.08)
    assert abs(noise.mean()) < 0.1 * NOISE * spread


def test_range_noise_is_unchanged_by_the_spread_option():
    bounded = load("bioreactor")  # x in [0, 1]: the published unit, the range 1
    clean, noise = _noise(bounded, "range", u=0.5)  # x stays at 0.5, 10 standard deviations from either bound
    np.testing.assert_allclose(clean, 0.5, atol=1e-12)
    np.testing.assert_allclose(noise.std(), NOISE * 1.0, rtol=0.08)


@pytest.mark.parametrize("kw, words", [({"noise": 2.0}, "noise must be at most 1"),
                                       ({"noise_scale": "width"}, "noise_scale 'range' or 'spread'")])
def test_implausible_noise_settings_are_refused(kw, words):
    with pytest.raises(ValueError, match=words):
        Sampling(**kw)
