"""Least squares for parametric models: exact recovery from noise-free data, honest standard errors on noisy data,
unidentifiable parameters reported (never a confident number), statuses, one compilation, and bad input refused."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.learn.dataset import Sampling, make_dataset
from myriad.runtime.learn.models import NeuralODE, Parametric
from myriad.runtime.status import Status
from myriad.runtime.sysid import least_squares as ls_module
from myriad.runtime.sysid.least_squares import LeastSquaresResult, least_squares

pytestmark = pytest.mark.slow  # not in `make test-fast`: least-squares fits of shipped systems

N = 50  # a coarser grid than the published 100 keeps the suite fast; the data and the fit use the same one


def _data(name, seed=0, **sampling):
    system = load(name)
    return Parametric(system), make_dataset(system, Sampling(intervals=N, **sampling), trajectories=(10, 3, 3),
                                            seed=seed)


def _true(model):
    return {k: float(v) for k, v in model.true_params().items()}


@pytest.fixture(scope="module")
def bioreactor():
    return _data("bioreactor")


@pytest.mark.parametrize("name, method", [
    ("cancer_treatment", "single_shooting"),  # r x log(1/x) - delta u x
    ("bioreactor", "single_shooting"),  # G u x - D x^2
    ("glucose", "single_shooting"),  # two states, three rates
    ("bacteria", "single_shooting"),  # r x + A u x - B u^2 exp(-x)
])
def test_noise_free_data_recovers_every_parameter(name, method):
    model, data = _data(name)
    res = least_squares(model, data, method=method)
    assert isinstance(res, LeastSquaresResult) and isinstance(res.status, Status)
    assert res.status is Status.CONVERGED and res.converged, res.message
    assert set(res.theta) == set(model.system.learnable) and res.unidentifiable == ()
    true = _true(model)
    for k, v in true.items():
        assert abs(res.theta[k] - v) <= 1e-6 * abs(v), (k, res.theta[k], v)
        assert 0 <= res.standard_errors[k] <= 1e-6 * abs(v)  # sigma^2 ~ 0 on exact data
    assert res.theta != {k: float(v) for k, v in model.init_params().items()}  # it moved from the guesses
    assert res.residual_norm < 1e-8 and res.dof == res.n_obs - len(true)
    assert res.n_obs == 10 * N * model.system.n_states  # nodes k >= 1 of the 10 training trajectories
    assert np.all(np.diff(res.singular_values) <= 0) and res.singular_values[-1] > 0


@pytest.mark.parametrize("name", ["bioreactor", "van_der_pol"])
def test_noisy_data_true_values_within_three_standard_errors(name):
    model, data = _data(name, seed=1, noise=0.01)
    res = least_squares(model, data)  # noisy data: the starts are fitted and clipped observations dropped
    assert res.status is Status.CONVERGED, res.message
    assert res.starts is not None and res.starts.shape == data.train.states[:, 0].shape
    assert res.sigma2 > 0
    for k, v in _true(model).items():
        se = res.standard_errors[k]
        assert 0 < se < 0.2 * abs(v), (k, se)
        assert abs(res.theta[k] - v) <= 3 * se, (k, res.theta[k], v, se)
        assert res.theta[k] != v


def test_a_local_minimum_is_not_reported_as_converged():
    # Mountain car from the spec's guesses: single shooting stalls far from the data (noise-free, so a converged fit
    # must fit them); multiple shooting, each window from an observed state, finds the parameters.
    model, data = _data("mountain_car")
    stuck = least_squares(model, data)
    assert stuck.status is Status.NOT_CONVERGED and not stuck.converged
    assert "noise-free" in stuck.message and "multiple_shooting" in stuck.message
    res = least_squares(model, data, method="multiple_shooting")
    assert res.status is Status.CONVERGED, res.message
    assert res.theta == pytest.approx(_true(model), rel=1e-6)


def test_invisible_parameters_are_reported_unidentifiable():
    # Bacteria: x' = r x + A u x - B u^2 exp(-x). Under zero control, A and B never act: only r is identifiable.
    system = load("bacteria")
    data = make_dataset(system, Sampling(controls="around", spread=0.0, intervals=N), seed=0,
                        around=np.zeros(N + 1))
    assert np.all(data.train.controls == 0)
    res = least_squares(Parametric(system), data)
    assert set(res.unidentifiable) == {"A", "B"}, res.message
    assert math.isnan(res.standard_errors["A"]) and math.isnan(res.standard_errors["B"])
    assert np.isnan(res.covariance[1:]).all() and np.isnan(res.covariance[:, 1:]).all()
    assert "the data cannot identify: A, B" in res.message
    assert abs(res.theta["r"] - 1.0) <= 1e-6 and math.isfinite(res.standard_errors["r"])
    assert np.sum(res.singular_values < 1e-8 * res.singular_values[0]) == 2


def test_parameters_seen_only_in_combination_are_unidentifiable():
    # Pendulum: omega' = -(3/40) (g / l) sin(theta) + (3/20) u / (l^2 m): three parameters, two combinations.
    model, data = _data("pendulum")
    res = least_squares(model, data, method="multiple_shooting")
    assert set(res.unidentifiable) == {"g", "m", "l"}, res.message
    assert all(math.isnan(se) for se in res.standard_errors.values())
    assert "the data cannot identify: g, m, l" in res.message
    th = res.theta  # what the data do determine is recovered
    assert th["g"] / th["l"] == pytest.approx(10.0, rel=1e-6)
    assert th["l"] ** 2 * th["m"] == pytest.approx(1.0, rel=1e-6)


def test_status_iteration_limit_and_theta0(bioreactor):
    model, data = bioreactor
    res = least_squares(model, data, max_steps=2)
    assert res.status is Status.ITERATION_LIMIT and not res.converged and res.steps == 2
    start = {"G": 0.9, "D": 1.1}
    near = least_squares(model, data, theta0=start)
    assert near.status is Status.CONVERGED
    assert near.theta == pytest.approx(_true(model), rel=1e-6)


def test_compiled_once_per_configuration(bioreactor):
    model, data = bioreactor
    least_squares(model, data)
    size = ls_module._solve._cache_size()
    _, other = _data("bioreactor", seed=5)  # new data, same shapes
    res = least_squares(model, other, theta0={"G": 1.5})
    assert res.converged and ls_module._solve._cache_size() == size


def test_non_finite_start_is_reported():
    model, data = _data("bacteria")
    res = least_squares(model, data, theta0={"B": 200.0})  # -B u^2 exp(-x) drives x to -inf
    assert res.status is Status.NOT_FINITE and not res.converged
    assert "not finite on trajectories" in res.message
    assert all(math.isnan(se) for se in res.standard_errors.values())


def test_bad_input_is_refused(bioreactor):
    model, data = bioreactor
    with pytest.raises(ValueError, match="dataset is of system 'bioreactor' but the model is of 'mould_fungicide'"):
        least_squares(Parametric(load("mould_fungicide")), data)
    with pytest.raises(ValueError, match="spec"):
        least_squares(model, dataclasses.replace(data, spec_sha256="0" * 64))
    with pytest.raises(ValueError, match="Parametric model's scalar parameters, not a NeuralODE"):
        least_squares(NeuralODE(model.system), data)
    with pytest.raises(ValueError, match="not the model's"):
        least_squares(model, data, theta0={"K": 1.0})
    with pytest.raises(ValueError, match="method must be one of"):
        least_squares(model, data, method="collocation")
    with pytest.raises(ValueError, match="window"):
        least_squares(model, data, method="multiple_shooting", window=N + 1)
    with pytest.raises(ValueError, match="fit_starts"):
        least_squares(model, data, method="multiple_shooting", fit_starts=True)
    with pytest.raises(ValueError, match="scale"):
        least_squares(model, data, scale=-1.0)
