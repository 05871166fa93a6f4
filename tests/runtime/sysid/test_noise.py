"""System identification under a schema 3 spec's declared noise (issue 30 item 4): the datasets' process and
observation noise have the declared laws, the noiseless limit is the kit's dataset, and least squares'
standard errors match the spread of the fitted parameters over repeated datasets (where the i.i.d. ones do not)."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.cli import main
from myriad.runtime.integrators import RK4
from myriad.runtime.learn.dataset import Sampling, make_dataset
from myriad.runtime.learn.models import Parametric
from myriad.runtime.sysid.least_squares import least_squares
from myriad.runtime.sysid.noise import DeclaredNoise, declared_noise, noisy_dataset, residual_covariance
from myriad.runtime.sysid.run import SysidConfig, data_noise, run_sysid
from myriad.runtime.uncertainty.sde import StochasticHeun

SPEC = str(Path(__file__).with_name("noisy_oscillator.yaml"))  # linear: k, c learnable; sigma_v 0.1; std 0.02
N = 50


@pytest.fixture(scope="module")
def system():
    return load(SPEC)


def test_the_declared_noise_is_read_and_none_for_older_specs(system):
    noise = declared_noise(system)
    np.testing.assert_array_equal(noise.process, [0.0, 0.1])
    np.testing.assert_array_equal(noise.observation, [0.02, 0.02])
    assert declared_noise(load("cancer_treatment")) is None
    assert data_noise(system, SysidConfig(declared_noise=False)) is None
    with pytest.raises(ValueError, match="declared_noise=false"):
        data_noise(system, SysidConfig(noise=0.01))
    with pytest.raises(ValueError, match="sampling.integrator"):  # process noise needs Euler or Heun's scheme
        data_noise(system, SysidConfig(sampling=Sampling(integrator=RK4())))


def test_zero_noise_gives_the_kits_dataset(system):
    """The same controls and starts to the bit, the states to rounding (another compiled program: XLA may fuse the
    stochastic Heun step's products and sums otherwise than Heun's)."""
    zero = DeclaredNoise(np.zeros(2), np.zeros(2))
    a = make_dataset(system, Sampling(intervals=N), trajectories=(3, 1, 1), seed=4)
    b = noisy_dataset(system, Sampling(intervals=N), zero, trajectories=(3, 1, 1), seed=4)
    for split in ("train", "validation", "test"):
        np.testing.assert_array_equal(getattr(a, split).controls, getattr(b, split).controls)
        np.testing.assert_allclose(getattr(a, split).states, getattr(b, split).states, rtol=1e-13, atol=1e-13)


def test_the_noise_has_the_declared_covariance(system):
    """The system is linear, so a path minus the noiseless one is the same linear Gaussian process under every
    control: its covariance over 4000 paths matches the linearised Omega (exact here) within 3 standard errors of
    a Gaussian variance, at the start (readings only), mid-way and at the end (process noise accumulated)."""
    noise = declared_noise(system)
    sampling, B = Sampling(intervals=N), 4000
    clean = make_dataset(system, sampling, trajectories=(B, 0, 0), seed=1).train
    noisy = noisy_dataset(system, sampling, noise, trajectories=(B, 0, 0), seed=1).train
    np.testing.assert_array_equal(clean.controls, noisy.controls)
    e = (noisy.states - clean.states).reshape(B, -1)
    omega = np.asarray(residual_covariance(
        {k: jnp.asarray(v) for k, v in (("k", 2.0), ("c", 0.5))}, system.default_params(jnp.float64),
        jnp.linspace(0.0, 5.0, N + 1), jnp.asarray(clean.states[:1, 0]), jnp.asarray(clean.controls[:1]),
        jnp.ones((1, N + 1, 2)), jnp.asarray(noise.process), jnp.asarray(noise.observation),
        model=Parametric(system), scheme=StochasticHeun()))[0]
    assert abs(e.mean(axis=0)).max() < 4 * np.sqrt(np.diag(omega).max() / B)
    for node in (0, N // 2, N):
        for i in range(2):
            j = 2 * node + i
            var, exact = e[:, j].var(ddof=1), omega[j, j]
            assert abs(var - exact) <= 3 * exact * np.sqrt(2 / (B - 1)), (node, i, var, exact)
    assert omega[2 * N + 1, 2 * N + 1] > 5 * 0.02**2  # the process noise dominates at the end


@pytest.mark.slow  # ~12 s: the compilations (sampling, the fit, Omega), then 160 fits warm
def test_standard_errors_match_the_spread_over_repeated_datasets(system):
    """160 datasets (seeds 0..159) of 4 trajectories: the standard deviation of the fitted k and c against the RMS
    of the reported standard errors, within 3 of the sample standard deviation's relative standard error
    1/sqrt(2 (R - 1)) = 0.056 (over 1000 seeds the ratios were 1.031 and 0.991); the i.i.d. Gauss-Newton errors of
    the same fits (the first 16) are several times too small (ratio about 5)."""
    noise, model, R = declared_noise(system), Parametric(system), 160
    fits, errors, iid = [], [], []
    for seed in range(R):
        data = noisy_dataset(system, Sampling(intervals=N), noise, trajectories=(4, 0, 0), seed=seed)
        fit = least_squares(model, data, noise=noise)
        assert fit.converged, fit.message
        fits.append([fit.theta["k"], fit.theta["c"]])
        errors.append([fit.standard_errors["k"], fit.standard_errors["c"]])
        if seed < 16:  # the same fit (from its solution), without the declared noise: i.i.d. errors
            naive = least_squares(model, data, theta0=fit.theta, fit_starts=True)
            iid.append([naive.standard_errors["k"], naive.standard_errors["c"]])
    spread = np.std(fits, axis=0, ddof=1)
    ratio = spread / np.sqrt(np.mean(np.square(errors), axis=0))
    assert np.all(abs(ratio - 1) <= 3 / np.sqrt(2 * (R - 1))), ratio
    assert np.all(spread / np.sqrt(np.mean(np.square(iid), axis=0)) > 3)
    assert np.all(abs(np.mean(fits, axis=0) - [2.0, 0.5]) < 4 * spread / np.sqrt(R))


def test_multiple_shooting_gives_no_standard_errors_under_declared_noise(system):
    noise = declared_noise(system)
    data = noisy_dataset(system, Sampling(intervals=N), noise, trajectories=(3, 0, 0), seed=0)
    fit = least_squares(Parametric(system), data, noise=noise, method="multiple_shooting")
    assert all(np.isnan(v) for v in fit.standard_errors.values()) and "single shooting" in fit.message


@pytest.mark.slow  # a whole experiment: the data, the fit, the true optimum and the plan
def test_run_sysid_uses_the_declared_noise(system):
    report = run_sysid(system, SysidConfig(trajectories=6, sampling=Sampling(intervals=N)), progress=False)
    rec = report.record()
    assert rec["declared_noise"] == {"process": [0.0, 0.1], "observation": [0.02, 0.02]}
    assert report.converged and rec["failure"] is None, rec["message"]
    for name in ("k", "c"):  # noisy data: not exact, but within the reported errors
        err = abs(report.learned[name] - report.true[name])
        assert 1e-6 < err < 4 * report.standard_errors[name], (name, err, report.standard_errors)


def test_cli_refuses_the_kits_noise_on_top_of_the_declared_one(capsys):
    assert main(["sysid", SPEC, "--noise", "0.01"]) == 2
    assert "declared_noise=false" in capsys.readouterr().err
