"""InteriorPoint's feasibility restoration phase (runtime/solvers/interior_point/restoration.py).

Wächter & Biegler's (2000) example is the textbook NLP on which a line-search interior point without restoration
fails: from a start with ``x1 < 0`` the linearised constraints and the bounds ``x2, x3 >= 0`` leave no step that the
fraction-to-the-boundary rule allows, so the steps shrink to nothing at an infeasible point (before the restoration
phase the solve ended ``INFEASIBLE`` there). Predator-Prey on collocation and multiple shooting is the transcribed
case (before: the iteration limit, or ``INFEASIBLE``, at costs 4-8 times IPOPT's). A problem with no feasible point
must still end ``INFEASIBLE``, now because the restoration problem converges at a minimiser of the infeasibility.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.data import default_data
from myriad.runtime.integrators import RK4
from myriad.runtime.nlp import NLP
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.status import Status
from myriad.runtime.transcriptions import HermiteSimpson, MultipleShooting, Trapezoidal
from myriad.runtime.transcriptions.base import transcribe

pytestmark = pytest.mark.slow  # not in `make test-fast`: restoration-phase solves on three transcriptions

jax.config.update("jax_enable_x64", True)

INF = np.inf


def _unravel(z, data):
    return jnp.zeros(1), z[None, :], jnp.zeros((1, 0))


@functools.cache
def wachter_biegler() -> NLP:
    """min x1 s.t. x1^2 - x2 + a = 0, x1 - x3 - b = 0, x2, x3 >= 0; the start is data["x0"]."""
    f64 = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731

    def constraints(z, d):
        return jnp.stack([z[0] ** 2 - z[1] + d["params"]["a"], z[0] - z[2] - d["params"]["b"]])

    return NLP(lambda z, d: z[0], constraints, f64([0, 0]), f64([0, 0]), f64([-INF, 0, 0]), f64([INF, INF, INF]),
               lambda d: d["x0"], _unravel, name="wachter_biegler")


def wb_data(a, b, start=(-2.0, 1.0, 1.0)):
    return {"params": {"a": np.float64(a), "b": np.float64(b)}, "x0": np.asarray(start, dtype=np.float64)}


def test_wachter_biegler_example_converges_like_ipopt():
    # a = 1, b = 1/2: the optimum is x = (1/2, 5/4, 0) (x3 on its bound). Without restoration: INFEASIBLE, 20 steps.
    nlp, data = wachter_biegler(), wb_data(1.0, 0.5)
    result, ref = InteriorPoint().solve(nlp, data), Ipopt().solve(nlp, data)
    assert ref.success and result.success, result.message
    np.testing.assert_allclose(result.z, [0.5, 1.25, 0.0], atol=1e-7)
    assert result.objective == pytest.approx(ref.objective, abs=1e-9)
    assert result.iterations <= ref.iterations + 5


def test_gradients_after_restoration():
    # x1* = b while x3 is held at 0, so dF*/db = 1 and dF*/da = 0: the implicit rule at a solution reached through
    # the restoration phase.
    nlp, data = wachter_biegler(), wb_data(1.0, 0.5)
    solve_fn = InteriorPoint().solve_fn(nlp)

    def cost(a, b):
        return solve_fn({"params": {"a": a, "b": b}, "x0": jnp.asarray(data["x0"])}, jnp.asarray(data["x0"])).objective

    grad_a, grad_b = jax.grad(cost, argnums=(0, 1))(jnp.float64(1.0), jnp.float64(0.5))
    assert grad_a == pytest.approx(0.0, abs=1e-6) and grad_b == pytest.approx(1.0, abs=1e-6)


def test_vmapped_batch_with_and_without_restoration_equals_single_solves():
    # Members that restore (a = 1, b = 1/2; a = -1, b = -1) and one that does not (b = -1 from x1 = -1): one program,
    # fixed shapes, each member its own phase.
    nlp = wachter_biegler()
    members = [wb_data(1.0, 0.5), wb_data(-1.0, -1.0), wb_data(1.0, -1.0, (-1.0, 2.0, 3.0))]
    batched = jax.tree.map(lambda *leaves: np.stack(leaves), *members)
    for member, data in zip(InteriorPoint(batch="vmap").solve_batch(nlp, batched), members):
        single = InteriorPoint().solve(nlp, data)
        assert member.success and single.success and member.iterations == single.iterations
        np.testing.assert_allclose(member.z, single.z, rtol=0, atol=1e-10)


def test_a_locally_infeasible_problem_still_ends_infeasible():
    # z1^2 + z2^2 = -1 has no solution; the restoration phase converges at z = 0, the minimiser of the violation.
    f64 = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    nlp = NLP(lambda z, d: (z[0] - 2.0) ** 2 + z[1] ** 2, lambda z, d: jnp.stack([z[0] ** 2 + z[1] ** 2]), f64([-1]),
              f64([-1]), f64([-INF, -INF]), f64([INF, INF]), lambda d: f64([1.0, 1.0]), _unravel, name="sphere")
    result = InteriorPoint().solve(nlp, {"params": {}, "x0": np.zeros(1)})
    assert result.status is Status.INFEASIBLE and not result.success
    assert result.constraint_violation == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(result.z, 0.0, atol=1e-4)
    assert result.iterations < 100


# The cross-check's Hermite-Simpson setting, and coarser grids for its multiple shooting (50 intervals) and
# Trapezoidal(200) (306 and 657 iterations, 15 s and a minute here; README.md has their numbers).
PREDATOR_PREY = {
    "multiple_shooting": lambda: MultipleShooting(intervals=20, steps_per_interval=4, integrator=RK4()),
    "hermite_simpson": lambda: HermiteSimpson(intervals=100),
    "trapezoidal": lambda: Trapezoidal(intervals=50),
}


@pytest.mark.parametrize("name", sorted(PREDATOR_PREY))
def test_predator_prey_on_collocation_and_multiple_shooting_reaches_ipopts_cost(name):
    """The default Newton step (banded for these NLPs). Multiple shooting is degenerate here (the cumulative state
    on its bound, the control on zero for a stretch, multipliers ~1e10): its iterates depend on rounding, and under
    the suite's quick compile options it once stalled at an infeasible point without trying the restoration phase
    (issue 32); it must reach IPOPT's cost under any options."""
    system = load("predator_prey")
    nlp, data = transcribe(system, PREDATOR_PREY[name]()), default_data(system)
    ref, result = Ipopt().solve(nlp, data), InteriorPoint().solve(nlp, data)
    assert ref.success and result.success, result.message
    assert abs(result.objective - ref.objective) <= 1e-8 * abs(ref.objective)
