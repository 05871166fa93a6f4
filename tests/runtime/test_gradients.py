"""Gradients as a tested contract: derivatives of rollouts, simulations and transcribed NLPs against finite
differences.

``jax.test_util.check_grads`` compares JAX's forward (JVP) and reverse (VJP) derivatives, along a random direction,
with central differences, and at order 2 also the four second-order compositions (fwd-over-fwd, rev-over-fwd,
fwd-over-rev as in Hessian-vector products, rev-over-rev). Everything runs in float64 with ``eps = 1e-6`` (truncation
error ~1e-12, rounding ~1e-10 relative) against ``rtol = 1e-6`` and ``atol = 1e-9``: the worst check here uses 2 % of
its tolerance, while a dynamics whose tangent is off by a relative 1e-4, or that drops one parameter's or x0's
derivative, fails the rollout and transcription checks (tried by hand with a wrong ``custom_jvp``). NOTE:
``check_grads`` multiplies both tolerances by the number of elements of each output leaf, so outputs are kept small
(short grids).

Derivatives are taken with respect to the problem data, ``params`` (the spec's ``dict[str, Array]``, differentiated
as a whole pytree) and ``x0``, and with respect to the NLP's decision vector ``z``. Three shipped systems of different
structure: Van der Pol (two states, polynomial, required final values), Cancer Treatment (one state, logarithmic
growth, a free final state with bounds) and Cart-Pole (four states, trigonometric and rational, four parameters).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from myriad.runtime import load, simulate
from myriad.runtime.data import ProblemData, default_data
from myriad.runtime.integrators import INTEGRATORS, Adaptive, DormandPrince, Heun, rollout, rollout_with_cost
from myriad.runtime.transcriptions import (
    TRANSCRIPTIONS,
    HermiteSimpson,
    MultipleShooting,
    SingleShooting,
    Trapezoidal,
)

jax.config.update("jax_enable_x64", True)

EPS = 1e-6  # central differences: truncation ~ eps^2, rounding ~ 1e-16 / eps
RTOL = 1e-6
ATOL = 1e-9


@dataclasses.dataclass(frozen=True)
class Case:
    """A shipped system and a short rollout over [0, span] on which its trajectory stays moderate for every
    fixed-step integrator (on Van der Pol's full 10 s horizon, 10 steps overflow with all four and 16 with all but
    RK4)."""

    name: str
    span: float
    steps: int
    amplitude: float  # the control's swing around the middle of its bounds, as a fraction of their width


CASES = {
    "van_der_pol": Case("van_der_pol", span=4.0, steps=12, amplitude=0.3),
    "cancer_treatment": Case("cancer_treatment", span=20.0, steps=12, amplitude=0.3),
    "cartpole": Case("cartpole", span=2.0, steps=12, amplitude=0.1),
}
SYSTEMS = list(CASES)

# Every fixed-step integrator in the registry (a new one is covered by registering it); the adaptive ones have their
# own tests below (diffrax's here, Dormand-Prince's forward mode in test_integrators.py).
FIXED_STEP = {name: cls for name, cls in INTEGRATORS.items() if cls.fixed_step}


def smooth_controls(system, span: float, steps: int, amplitude: float) -> jnp.ndarray:
    """(steps + 1, m) control values inside the bounds: a sine around the middle of each control's range."""
    lo, hi = np.asarray(system.u_lower, dtype=np.float64), np.asarray(system.u_upper, dtype=np.float64)
    assert np.all(np.isfinite(lo) & np.isfinite(hi)), system.name
    t = np.linspace(0.0, span, steps + 1)[:, None]
    phase = np.arange(system.n_controls)[None, :] + 0.3
    frac = 0.5 + amplitude * np.sin(2.0 * np.pi * t / span + phase)
    return jnp.asarray(lo + (hi - lo) * frac)


def assert_moderate(tree, bound: float = 1e3):
    """The point where derivatives are checked is finite and not blown up (which would make the check vacuous)."""
    for leaf in jax.tree.leaves(tree):
        leaf = np.asarray(leaf)
        assert np.all(np.isfinite(leaf)) and np.max(np.abs(leaf), initial=0.0) < bound, leaf


@functools.cache
def problem(name: str):
    system = load(name)
    return system, default_data(system)


def rollout_fn(name: str, integrator, with_cost: bool):
    """(params, x0) -> the rollout on the case's grid: states, or (states, accumulated cost)."""
    system, _ = problem(name)
    case = CASES[name]
    controls = smooth_controls(system, case.span, case.steps, case.amplitude)
    h = case.span / case.steps

    @jax.jit
    def f(params, x0):
        dynamics = lambda x, u, t: system.dynamics(x, u, t, params)  # noqa: E731
        if not with_cost:
            return rollout(integrator, dynamics, x0, 0.0, h, controls)
        cost = lambda x, u, t: system.running_cost(x, u, t, params)  # noqa: E731
        return rollout_with_cost(integrator, dynamics, cost, x0, 0.0, h, controls)

    return f


# ---- rollouts --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("integrator", sorted(FIXED_STEP))
@pytest.mark.parametrize("name", SYSTEMS)
def test_rollout_with_cost_gradients(name, integrator):
    """d(states, cost)/d(params, x0), forward and reverse, for every fixed-step integrator."""
    _, data = problem(name)
    f = rollout_fn(name, FIXED_STEP[integrator](), with_cost=True)
    assert_moderate(f(data.params, data.x0))
    check_grads(f, (data.params, data.x0), order=1, modes=("fwd", "rev"), eps=EPS, rtol=RTOL, atol=ATOL)


# Full second-order checks compile the four fwd/rev compositions of the scan: kept to the two cheapest integrators
# (Heun is also single shooting's); the Hessian-vector products through RK4 are checked via multiple shooting below.
@pytest.mark.parametrize("integrator", ["euler", "heun"])
def test_rollout_second_order(integrator):
    """Second derivatives of the plain rollout (fwd-over-fwd, rev-over-fwd, fwd-over-rev, rev-over-rev)."""
    _, data = problem("cancer_treatment")
    f = rollout_fn("cancer_treatment", FIXED_STEP[integrator](), with_cost=False)
    assert_moderate(f(data.params, data.x0))
    check_grads(f, (data.params, data.x0), order=2, modes=("fwd", "rev"), eps=EPS, rtol=RTOL, atol=ATOL)


def test_nested_params_pytree_through_a_rollout():
    """``params`` may be any pytree (a learned model's): a nested dict with a matrix leaf is differentiated whole."""
    system, data = problem("van_der_pol")
    case = CASES["van_der_pol"]
    controls = smooth_controls(system, case.span, case.steps, case.amplitude)
    h = case.span / case.steps

    @jax.jit
    def f(params, x0):
        # The spec's dynamics plus a small learned linear correction.
        dynamics = lambda x, u, t: system.dynamics(x, u, t, params["spec"]) + params["W"] @ x  # noqa: E731
        cost = lambda x, u, t: system.running_cost(x, u, t, params["spec"]) + params["w"] * jnp.sum(x**2)  # noqa: E731
        return rollout_with_cost(Heun(), dynamics, cost, x0, 0.0, h, controls, checkpoint=True)

    params = {"spec": dict(data.params), "W": 0.05 * jnp.eye(system.n_states, k=1), "w": jnp.asarray(0.1)}
    x0 = jnp.asarray([0.1, 0.9])
    assert_moderate(f(params, x0))
    check_grads(f, (params, x0), order=1, modes=("fwd", "rev"), eps=EPS, rtol=RTOL, atol=ATOL)
    grads = jax.grad(lambda p: f(p, x0)[1][-1])(params)
    assert jax.tree.structure(grads) == jax.tree.structure(params)
    assert all(np.any(np.asarray(g) != 0) for g in jax.tree.leaves(grads))


# ---- simulate ------------------------------------------------------------------------------------------------------


def simulate_fn(name: str, integrator, steps: int, amplitude: float = 0.3):
    """(params, x0) -> simulate's states, costs and defect (zero where the final state is free: NaNs there would make
    every finite difference NaN)."""
    system, _ = problem(name)
    controls = smooth_controls(system, float(system.horizon), steps, amplitude)

    def f(params, x0):
        sim = simulate(system, controls, params, x0, integrator=integrator)
        defect = jnp.where(jnp.isnan(sim.defect), 0.0, sim.defect)
        return sim.states, sim.cost, sim.running_cost, sim.terminal_cost, defect

    return f


def test_simulate_heun_gradients():
    """simulate() with the published setting's integrator, on the full horizon (20 steps)."""
    _, data = problem("van_der_pol")
    f = simulate_fn("van_der_pol", Heun(), steps=20)
    assert_moderate(f(data.params, data.x0))
    check_grads(f, (data.params, data.x0), order=1, modes=("fwd", "rev"), eps=EPS, rtol=RTOL, atol=ATOL)


@pytest.mark.slow
def test_simulate_adaptive_reverse_mode():
    """The adaptive (diffrax) integrator differentiates in reverse mode; its tolerance (rtol 1e-8) limits agreement
    with finite differences to about 1e-7 relative (measured below 6e-8 here), hence the looser rtol."""
    _, data = problem("van_der_pol")
    f = simulate_fn("van_der_pol", Adaptive(), steps=5)
    assert_moderate(f(data.params, data.x0))
    check_grads(f, (data.params, data.x0), order=1, modes=("rev",), eps=EPS, rtol=1e-5, atol=1e-8)


def test_dormand_prince_reverse_mode_raises():
    """The re-simulation's Dormand-Prince loop has no reverse mode (a while loop): it raises, never a silent zero."""
    _, data = problem("van_der_pol")
    f = simulate_fn("van_der_pol", DormandPrince(), steps=5)
    with pytest.raises(ValueError, match="Reverse-mode differentiation does not work"):
        jax.grad(lambda x0: f(data.params, x0)[1])(data.x0)


def test_simulate_adaptive_forward_mode_raises():
    """Forward mode is not supported (diffrax's checkpointed adjoint is a custom_vjp): it raises, never a silent zero.
    jax.jacfwd and jax.hessian (forward over reverse) fail the same way."""
    _, data = problem("van_der_pol")
    f = simulate_fn("van_der_pol", Adaptive(), steps=5)
    tangent = jax.tree.map(jnp.ones_like, (data.params, data.x0))
    with pytest.raises(TypeError, match="forward-mode autodiff"):
        jax.jvp(f, (data.params, data.x0), tangent)


# ---- transcriptions ------------------------------------------------------------------------------------------------


def small(transcription: str, name: str):
    """A small grid of a registered direct transcription (a new one needs an entry here: a test checks).

    Van der Pol's single shooting needs 20 Heun steps over its 10 s horizon: with 10, 12 or 16 the rollout from the
    transcription's own initial guess overflows (objective inf or NaN)."""
    grids = {
        "single_shooting": SingleShooting(intervals=20 if name == "van_der_pol" else 10),
        "multiple_shooting": MultipleShooting(intervals=4, steps_per_interval=3),
        "trapezoidal": Trapezoidal(intervals=8),
        "hermite_simpson": HermiteSimpson(intervals=6),
    }
    return grids[transcription]


def test_every_transcription_is_covered():
    for label, cls in TRANSCRIPTIONS.items():
        assert type(small(label, "cartpole")) is cls


@functools.cache
def nlp_at(name: str, transcription: str, seed: int = 0):
    """The NLP and a point near its initial guess, moved off special values (bounds, straight lines) by 1 % of the
    nominal scale."""
    system, data = problem(name)
    nlp = small(transcription, name).transcribe(system)
    z0 = np.asarray(nlp.initial_guess(data), dtype=np.float64)
    scale = np.ones_like(z0) if nlp.z_scale is None else np.asarray(nlp.z_scale)
    z = jnp.asarray(z0 + 1e-2 * scale * np.random.default_rng(seed).standard_normal(z0.shape))
    return nlp, z


def nlp_functions(nlp):
    """(z, params, x0) -> (objective, constraints), with the data a plain pytree argument."""

    def f(z, params, x0):
        d = ProblemData(params, x0)
        c = nlp.constraints(z, d) if nlp.constraints is not None else jnp.zeros(0)
        return nlp.objective(z, d), c

    return f


@pytest.mark.parametrize("transcription", sorted(TRANSCRIPTIONS))
@pytest.mark.parametrize("name", SYSTEMS)
def test_transcription_gradients(name, transcription):
    """d(objective, constraints)/d(z, params, x0), forward and reverse, near the initial guess.

    One check over all three arguments: its random direction moves z, every parameter and x0 at once, so a wrong
    derivative with respect to any of them changes the compared products (by far more than the tolerance)."""
    _, data = problem(name)
    nlp, z = nlp_at(name, transcription)
    f = jax.jit(nlp_functions(nlp))
    assert_moderate(f(z, data.params, data.x0), bound=1e4)
    check_grads(f, (z, data.params, data.x0), order=1, modes=("fwd", "rev"), eps=EPS, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("transcription", sorted(TRANSCRIPTIONS))
def test_lagrangian_hessian_vector_products(transcription):
    """The second derivative a solver uses: forward-over-reverse Hessian-vector products of the Lagrangian
    F(z) + y . c(z) in z (IPOPT's exact Hessian), checked as the JVP of the gradient against its finite differences."""
    name = "van_der_pol"
    _, data = problem(name)
    nlp, z = nlp_at(name, transcription)
    f = nlp_functions(nlp)
    y = jnp.asarray(np.random.default_rng(1).standard_normal(nlp.n_constraints))

    @jax.jit
    def gradient(z):
        return jax.grad(lambda z_: (lambda F, c: F + y @ c)(*f(z_, data.params, data.x0)))(z)

    assert_moderate(gradient(z), bound=1e4)
    check_grads(gradient, (z,), order=1, modes=("fwd",), eps=EPS, rtol=RTOL, atol=ATOL)
