"""Test systems with declared uncertainty: the schema 3 specs in ./specs/ as compiled, and subclasses of them that
set schema 3's class attributes otherwise (another noise level, a malformed declaration, none at all)."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from myriad.runtime import load
from myriad.runtime.uncertainty import distributions as D

SPECS = Path(__file__).resolve().parent / "specs"

# specs/four_parameters.yaml's declaration, one parameter per distribution: k uniform, c normal, g lognormal,
# m choice (a test checks that the compiler wrote these).
FOUR = {
    "uncertain_params": ("k", "c", "g", "m"),
    "uncertain_kinds": ("uniform", "normal", "lognormal", "choice"),
    "uncertain_args": ((1.5, 2.5), (0.5, 0.1), (0.0, 0.25), (0.5, 1.0, 2.0)),
}


@functools.cache
def declared(spec: str, **attrs):
    """The system of ``specs/<spec>.yaml`` with the class attributes ``attrs`` (tuples, hashable: cached, so
    the same declaration is the same class and its env the same static jit argument)."""
    base = type(load(SPECS / f"{spec}.yaml"))
    return type(base.__name__ + "Declared", (base,), dict(attrs))()


def plain(spec: str):
    """The spec's system with nothing uncertain and no noise (schema 3's defaults)."""
    return declared(spec, uncertain_params=(), uncertain_kinds=(), uncertain_args=(), process_noise=(),
                    observation_noise=())


def four_parameters(**extra):
    """The damped oscillator with its four parameters uncertain (FOUR), as compiled, or with ``extra``
    attributes."""
    return declared("four_parameters", **extra) if extra else load(SPECS / "four_parameters.yaml")


def ornstein_uhlenbeck():
    """dx = (-theta x + u) dt + sigma dW, theta = 2, sigma = 1, x(0) = 1, T = 1 (schema 3's process noise)."""
    return load(SPECS / "ornstein_uhlenbeck.yaml")


def assert_moments(draws, kinds, args, widen=1.0):
    """Each column's mean and variance within 3 standard errors of the exact ones (the variance's standard error
    sqrt((mu4 - sigma^4) / M) from the exact fourth central moment)."""
    draws = np.asarray(draws)
    m = draws.shape[0]
    for j, (kind, a) in enumerate(zip(kinds, args)):
        x = draws[:, j]
        mean, sd = D.mean(kind, a, widen), D.std(kind, a, widen)
        assert abs(x.mean() - mean) <= 3 * sd / math.sqrt(m), (kind, x.mean(), mean)
        se_var = math.sqrt((D.fourth_central_moment(kind, a, widen) - sd ** 4) / m)
        assert abs(x.var(ddof=1) - sd ** 2) <= 3 * se_var, (kind, x.var(ddof=1), sd ** 2)


def ou_moments(theta, sigma, x0, T, n=None, scheme=None):
    """Mean and variance of x(T) for dx = -theta x dt + sigma dW, x(0) = x0: exact (n None), else of ``scheme``
    ("euler_maruyama" or "heun") on n steps, in closed form. Both schemes are linear here:
    x_{k+1} = R x_k + c sigma dW_k, with R = 1 - theta h, c = 1 (Euler-Maruyama) and R = 1 - theta h +
    (theta h)^2 / 2, c = 1 - theta h / 2 (stochastic Heun), so E x_n = R^n x0 and Var x_n = c^2 sigma^2 h
    (1 - R^(2n)) / (1 - R^2)."""
    if n is None:
        return x0 * math.exp(-theta * T), sigma ** 2 * -math.expm1(-2 * theta * T) / (2 * theta)
    h = T / n
    R, c = (1 - theta * h, 1.0) if scheme == "euler_maruyama" else (1 - theta * h + (theta * h) ** 2 / 2,
                                                                      1 - theta * h / 2)
    return x0 * R ** n, c * c * sigma ** 2 * h * sum(R ** (2 * i) for i in range(n))


def assert_mean_and_variance(x, mean, var):
    """The sample mean and variance of ``x`` within 3 standard errors of ``mean`` and ``var`` (the variance's from
    the sample's fourth central moment)."""
    x = np.asarray(x, np.float64)
    m, d = x.size, x - x.mean()
    assert abs(x.mean() - mean) <= 3 * x.std() / math.sqrt(m), (x.mean(), mean, x.std() / math.sqrt(m))
    se = math.sqrt((np.mean(d ** 4) - np.mean(d ** 2) ** 2) / m)
    assert abs(x.var(ddof=1) - var) <= 3 * se, (x.var(ddof=1), var, se)
