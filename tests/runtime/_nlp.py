"""Shared helpers of the transcription tests: an independent SciPy SLSQP solve of an NLP, and a convergence
order fitted to errors on refined grids."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize


def _evaluator(nlp, data):
    """One jitted function z -> (F, dF/dz, c, dc/dz), memoised on the last z (SLSQP asks for them separately)."""

    def all_of(z):
        F, g = jax.value_and_grad(nlp.objective)(z, data)
        if nlp.constraints is None:
            return F, g, jnp.zeros(0), jnp.zeros((0, z.shape[0]))
        return F, g, nlp.constraints(z, data), jax.jacfwd(nlp.constraints)(z, data)

    compiled = jax.jit(all_of)
    cache = {}

    def at(z):
        key = np.asarray(z, dtype=np.float64).tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = [np.asarray(v) for v in compiled(jnp.asarray(z, dtype=jnp.float64))]
        return cache[key]

    return at


def _solve(nlp, data):
    """SLSQP on the NLP as given (equalities where c_lower == c_upper, one-sided rows for finite bounds)."""
    at = _evaluator(nlp, data)
    eq = np.flatnonzero(nlp.c_lower == nlp.c_upper)
    lo = np.flatnonzero((nlp.c_lower != nlp.c_upper) & np.isfinite(nlp.c_lower))
    hi = np.flatnonzero((nlp.c_lower != nlp.c_upper) & np.isfinite(nlp.c_upper))
    cons = []
    if eq.size:
        cons.append({"type": "eq", "fun": lambda z: at(z)[2][eq] - nlp.c_lower[eq], "jac": lambda z: at(z)[3][eq]})
    if lo.size:
        cons.append({"type": "ineq", "fun": lambda z: at(z)[2][lo] - nlp.c_lower[lo], "jac": lambda z: at(z)[3][lo]})
    if hi.size:
        cons.append({"type": "ineq", "fun": lambda z: nlp.c_upper[hi] - at(z)[2][hi], "jac": lambda z: -at(z)[3][hi]})
    bounds = [
        (None if not np.isfinite(a) else a, None if not np.isfinite(b) else b) for a, b in zip(nlp.z_lower, nlp.z_upper)
    ]
    res = scipy.optimize.minimize(
        lambda z: float(at(z)[0]),
        np.asarray(nlp.initial_guess(data)),
        jac=lambda z: at(z)[1],
        constraints=cons,
        bounds=bounds,
        method="SLSQP",
        options={"ftol": 1e-14, "maxiter": 500},
    )
    assert res.success, res.message
    return res.x, at


def _slope(ns, errors):
    return float(np.polyfit(np.log(1.0 / np.asarray(ns, dtype=float)), np.log(errors), 1)[0])
