"""A transcription's fused ``objective_and_constraints`` is the same function as its ``objective`` and ``constraints``.

Solvers build every program (IPOPT's first-order point evaluation, the Lagrangian's Hessian) on the fused form when
a transcription provides it, so a disagreement would silently change the problem being solved.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.integrators import RK4, Heun
from myriad.runtime.transcriptions import MultipleShooting, SingleShooting, Trapezoidal, default_data

# Systems with terminal costs, required final values, final-state bounds, two controls and time dependence.
SYSTEMS = ("bacteria", "rocket_landing", "tumour", "predator_prey", "van_der_pol", "cancer_treatment")
FUSED = {
    "single_shooting": SingleShooting(intervals=40, integrator=Heun()),
    "multiple_shooting": MultipleShooting(intervals=4, steps_per_interval=10, integrator=RK4()),
}


def _random_point(nlp, data, rng):
    """The initial guess moved by up to 10 % of each variable's range (or nominal scale), kept inside the bounds."""
    z = np.asarray(nlp.initial_guess(data), dtype=np.float64)
    lo, hi = nlp.z_lower, nlp.z_upper
    width = np.where(np.isfinite(hi - lo), hi - lo, np.asarray(nlp.z_scale))
    z = z + 0.1 * width * rng.uniform(-1.0, 1.0, z.shape)
    return np.clip(z, lo, hi)


@pytest.mark.slow
@pytest.mark.parametrize("transcription", list(FUSED), ids=list(FUSED))
@pytest.mark.parametrize("name", SYSTEMS)
def test_fused_evaluation_matches_objective_and_constraints(name, transcription):
    system = load(name)
    nlp = FUSED[transcription].transcribe(system)
    assert nlp.objective_and_constraints is not None
    data = default_data(system)
    rng = np.random.default_rng(7)
    lam = rng.standard_normal(nlp.n_constraints)

    def separate(z):
        return nlp.objective(z, data) + jnp.dot(lam, nlp.constraints(z, data))

    def fused(z):
        f, c = nlp.objective_and_constraints(z, data)
        return f + jnp.dot(lam, c)

    both = jax.jit(lambda z: (nlp.objective(z, data), nlp.constraints(z, data), nlp.evaluate(z, data),
                              jax.grad(separate)(z), jax.grad(fused)(z)))
    for _ in range(3):
        z = jnp.asarray(_random_point(nlp, data, rng))
        f, c, (f_fused, c_fused), g, g_fused = both(z)
        assert np.isfinite(f)  # NaNs in a derivative (outside a square root's domain) must match, and do
        np.testing.assert_allclose(f_fused, f, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(c_fused, c, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(g_fused, g, rtol=1e-10, atol=1e-10 * float(jnp.nanmax(jnp.abs(g))))


def test_evaluate_falls_back_to_separate_calls():
    system = load("van_der_pol")
    nlp = Trapezoidal(intervals=5).transcribe(system)
    assert nlp.objective_and_constraints is None
    data = default_data(system)
    z = jnp.asarray(_random_point(nlp, data, np.random.default_rng(0)))
    f, c = nlp.evaluate(z, data)
    assert float(f) == float(nlp.objective(z, data))
    np.testing.assert_array_equal(c, nlp.constraints(z, data))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rocket_landing", "bacteria"])
def test_checkpointed_rollout_has_the_same_values_and_derivatives(name):
    system = load(name)
    data = default_data(system)
    plain, remat = (SingleShooting(intervals=30, checkpoint=flag).transcribe(system) for flag in (False, True))
    lam = np.random.default_rng(3).standard_normal(plain.n_constraints)

    def lagrangian(nlp):
        return lambda z: nlp.objective(z, data) + jnp.dot(lam, nlp.constraints(z, data))

    z = jnp.asarray(_random_point(plain, data, np.random.default_rng(5)))
    v = jnp.asarray(np.random.default_rng(6).standard_normal(z.shape))
    out = [jax.jit(lambda z: (lagrangian(nlp)(z), jax.grad(lagrangian(nlp))(z),
                              jax.jvp(jax.grad(lagrangian(nlp)), (z,), (v,))[1]))(z) for nlp in (plain, remat)]
    for a, b in zip(*out):
        np.testing.assert_allclose(b, a, rtol=1e-11, atol=1e-11 * float(jnp.max(jnp.abs(a))))
