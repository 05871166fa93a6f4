"""NLP solvers against mathematics: small problems with known solutions, built by hand with the NLP dataclass.

Every solver in ``SOLVERS`` runs on every problem of ``PROBLEMS``; results are memoised per (solver, problem) so
that the accuracy, agreement and multiplier tests share one solve. Measured accuracies (z, infinity norm), for the
stated tolerances below: see ``TESTED`` and the report in the solvers' README.
"""

from __future__ import annotations

import dataclasses
import functools
import gc
import weakref
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime.nlp import NLP
from myriad.runtime.solvers import (
    SLSQP,
    SOLVERS,
    AbstractNLPSolver,
    Extragradient,
    InteriorPoint,
    Ipopt,
    constraint_violation,
    constraint_violations,
)
from myriad.runtime.solvers.ipopt import judge
from myriad.runtime.solvers.sparse import HessianColouring, compressed_jacobian_fn, hvp_batch_fn
from myriad.runtime.status import Status

INF = np.inf
NO_DATA = {"params": {}, "x0": np.zeros(1)}


def _unravel(z, data):
    return jnp.zeros(1), z[None, :], jnp.zeros((1, 0))


def _nlp(objective, constraints, c_lower, c_upper, z_lower, z_upper, guess, **kw) -> NLP:
    f64 = lambda a: np.asarray(a, dtype=np.float64)  # noqa: E731
    guess = np.asarray(guess, dtype=np.float64) if not callable(guess) else guess
    return NLP(
        objective=objective,
        constraints=constraints,
        c_lower=f64(c_lower),
        c_upper=f64(c_upper),
        z_lower=f64(z_lower),
        z_upper=f64(z_upper),
        initial_guess=guess if callable(guess) else (lambda data: guess),
        unravel=_unravel,
        **kw,
    )


@dataclasses.dataclass(frozen=True)
class Case:
    """A problem, one instance of its data, and the exact solution (z*, F*, constraint multipliers y*)."""

    nlp: NLP
    data: Any
    z_star: np.ndarray
    f_star: float
    y_star: np.ndarray | None = None
    z_scale: np.ndarray | None = None  # errors in z are measured relative to this


# ---- problems -----------------------------------------------------------------------------------------------------

# Equality-constrained QP: min 1/2 z'Qz + q'z  s.t.  A z = b, with q = params["q"] and b = x0 (data-dependent, as in
# a transcription whose initial state enters the constraints). KKT: [Q A'; A 0] [z; y] = [-q; b].
_rng = np.random.default_rng(1)
_M = _rng.standard_normal((5, 5))
QP_Q, QP_A = _M @ _M.T + np.eye(5), _rng.standard_normal((2, 5))


def qp_nlp() -> NLP:
    Q, A = jnp.asarray(QP_Q), jnp.asarray(QP_A)
    return _nlp(
        lambda z, d: 0.5 * z @ (Q @ z) + d["params"]["q"] @ z,
        lambda z, d: A @ z - d["x0"],
        np.zeros(2), np.zeros(2), np.full(5, -INF), np.full(5, INF), np.zeros(5), name="eq_qp",
    )


def qp_data(q, b):
    return {"params": {"q": np.asarray(q, dtype=np.float64)}, "x0": np.asarray(b, dtype=np.float64)}


def qp_exact(data) -> tuple[np.ndarray, np.ndarray, float]:
    q, b = data["params"]["q"], data["x0"]
    kkt = np.block([[QP_Q, QP_A.T], [QP_A, np.zeros((2, 2))]])
    sol = np.linalg.solve(kkt, np.concatenate([-q, b]))
    z = sol[:5]
    return z, sol[5:], float(0.5 * z @ QP_Q @ z + q @ z)


def rosenbrock(z, data):
    return (1.0 - z[0]) ** 2 + 100.0 * (z[1] - z[0] ** 2) ** 2


# Disc: min (z1 - 2)^2 + (z2 - 1)^2  s.t.  |z|^2 <= r^2 (r = params["r"] < sqrt 5), z in [-5, 5]^2. The solution is the
# projection of (2, 1) onto the disc, z* = r (2, 1) / sqrt 5, F* = (sqrt 5 - r)^2, and from 2 (z - a) + 2 y z = 0
# the multiplier of the active upper bound is y* = sqrt 5 / r - 1 >= 0.
def disc_nlp() -> NLP:
    return _nlp(
        lambda z, d: (z[0] - 2.0) ** 2 + (z[1] - 1.0) ** 2,
        lambda z, d: jnp.stack([z @ z - d["params"]["r"] ** 2]),
        [-INF], [0.0], [-5.0, -5.0], [5.0, 5.0], np.zeros(2), name="disc",
    )


def disc_data(r):
    return {"params": {"r": np.float64(r)}, "x0": np.zeros(1)}


def disc_exact(r):
    return r * np.array([2.0, 1.0]) / np.sqrt(5.0), (np.sqrt(5.0) - r) ** 2, np.array([np.sqrt(5.0) / r - 1.0])


# Hock-Schittkowski 71: min x1 x4 (x1 + x2 + x3) + x3  s.t.  x1 x2 x3 x4 >= 25, |x|^2 = 40, 1 <= x <= 5.
HS71_Z = np.array([1.0, 4.74299963, 3.82114998, 1.37940829])
HS71_F = 17.0140173
HS71_Y = np.array([-0.55229366, 0.16146857])  # IPOPT convention: grad F + J' y = bound multipliers


def hs71_nlp(scale=None) -> NLP:
    """HS71, optionally in variables z = s * x of very different magnitudes, with z_scale = s."""
    s = np.ones(4) if scale is None else np.asarray(scale)
    sj = jnp.asarray(s)

    def objective(z, d):
        x = z / sj
        return x[0] * x[3] * (x[0] + x[1] + x[2]) + x[2]

    def constraints(z, d):
        x = z / sj
        return jnp.stack([jnp.prod(x), x @ x])

    return _nlp(
        objective, constraints, [25.0, 40.0], [INF, 40.0], s * 1.0, s * 5.0, s * np.array([1.0, 5.0, 5.0, 1.0]),
        z_scale=None if scale is None else s, name="hs71" if scale is None else "hs71_scaled",
    )


HS71_SCALE = np.array([1e2, 1.0, 1e-2, 1e3])


def make_cases() -> dict[str, Case]:
    q_data = qp_data([1.0, -2.0, 0.5, 0.0, 1.0], [1.0, 2.0])
    z_qp, y_qp, f_qp = qp_exact(q_data)
    z_disc, f_disc, y_disc = disc_exact(1.5)
    return {
        "eq_qp": Case(qp_nlp(), q_data, z_qp, f_qp, y_qp),
        "rosenbrock": Case(
            _nlp(rosenbrock, None, [], [], [-INF, -INF], [INF, INF], [-1.2, 1.0], name="rosenbrock"),
            NO_DATA, np.ones(2), 0.0,
        ),
        # With z1 <= 0.5: F >= (1 - z1)^2 >= 1/4, attained at z1 = 1/2, z2 = z1^2.
        "rosenbrock_bounded": Case(
            _nlp(rosenbrock, None, [], [], [-INF, -INF], [0.5, INF], [-1.2, 1.0], name="rosenbrock_bounded"),
            NO_DATA, np.array([0.5, 0.25]), 0.25,
        ),
        "hs71": Case(hs71_nlp(), NO_DATA, HS71_Z, HS71_F, HS71_Y),
        "hs71_scaled": Case(hs71_nlp(HS71_SCALE), NO_DATA, HS71_SCALE * HS71_Z, HS71_F, HS71_Y, z_scale=HS71_SCALE),
        "disc": Case(disc_nlp(), disc_data(1.5), z_disc, f_disc, y_disc),
    }


CASES = make_cases()

# The configuration each solver is tested with. SLSQP's tol bounds the objective change, and z converges only like
# its square root where the problem is ill-conditioned: the default tol=1e-9 leaves z 3.2e-6 off on eq_qp and 1.4e-5 on
# Rosenbrock; 1e-11 gives <= 1e-7 on every case (1e-12 is past round-off: the disc then ends in exit mode 8).
TESTED: dict[str, AbstractNLPSolver] = {"ipopt": Ipopt(), "slsqp": SLSQP(tol=1e-11), "extragradient": Extragradient(),
                                        "interior_point": InteriorPoint()}
# (z, F, multipliers) tolerances per solver.
TOLERANCES = {"ipopt": (1e-6, 1e-6, 1e-5), "slsqp": (1e-6, 1e-6, 1e-5), "extragradient": (1e-5, 1e-5, 1e-4),
              "interior_point": (1e-6, 1e-6, 1e-5)}


@functools.cache
def solved(solver_name: str, case_name: str):
    solver, case = TESTED[solver_name], CASES[case_name]
    return solver.solve(case.nlp, case.data)


ALL_PAIRS = [(s, c) for s in SOLVERS for c in CASES]


# ---- accuracy against the exact solutions --------------------------------------------------------------------------


@pytest.mark.parametrize("solver_name, case_name", ALL_PAIRS)
def test_solves_to_the_known_solution(solver_name, case_name):
    case, result = CASES[case_name], solved(solver_name, case_name)
    z_tol, f_tol, y_tol = TOLERANCES[solver_name]
    scale = np.ones_like(case.z_star) if case.z_scale is None else case.z_scale
    assert result.success, result.message
    assert result.status == 0
    assert np.max(np.abs(result.z - case.z_star) / scale) <= z_tol
    assert abs(result.objective - case.f_star) <= f_tol
    assert result.constraint_violation <= 1e-6
    assert result.iterations > 0
    assert result.solve_seconds > 0
    if case.y_star is not None:
        np.testing.assert_allclose(result.multipliers, case.y_star, atol=y_tol)
    else:
        assert result.multipliers is None


@pytest.mark.parametrize("case_name", list(CASES))
def test_the_three_solvers_agree(case_name):
    results = {name: solved(name, case_name) for name in SOLVERS}
    reference = results["ipopt"]
    for name, result in results.items():
        assert abs(result.objective - reference.objective) <= 1e-5, name
        np.testing.assert_allclose(result.z, reference.z, atol=1e-5 * np.max(np.abs(reference.z)), err_msg=name)


@pytest.mark.parametrize("solver_name", list(SOLVERS))
def test_z_scale_is_a_change_of_variables(solver_name):
    # hs71_scaled is HS71 in z = s * x with s spanning 1e-2..1e3 and z_scale = s: in w = z / z_scale it is HS71 again,
    # so a solver that honours z_scale takes the same path (up to the rounding of s * (z / s)).
    plain, scaled = solved(solver_name, "hs71"), solved(solver_name, "hs71_scaled")
    np.testing.assert_allclose(scaled.z / HS71_SCALE, plain.z, atol=1e-7)
    if solver_name != "slsqp":  # SLSQP's line search is sensitive to that rounding (7 vs 14 iterations, same x)
        assert scaled.iterations == plain.iterations


@pytest.mark.parametrize("case_name", ["rosenbrock_box", "disc"])
def test_extragradient_sigmoid_bounds(case_name):
    # The sigmoid acts only on variables with both bounds finite: a box around Rosenbrock's interior minimum, and the
    # disc's box (the active constraint there is the disc, not the box).
    if case_name == "rosenbrock_box":
        case = Case(_nlp(rosenbrock, None, [], [], [-2.0, -2.0], [2.0, 2.0], [-1.2, 1.0]), NO_DATA, np.ones(2), 0.0)
    else:
        case = CASES[case_name]
    result = Extragradient(bounds="sigmoid").solve(case.nlp, case.data)
    assert result.success, result.message
    assert np.max(np.abs(result.z - case.z_star)) <= 1e-5
    assert np.all(result.z >= case.nlp.z_lower) and np.all(result.z <= case.nlp.z_upper)


def test_extragradient_start_scaling_undoes_the_units_of_the_variables():
    # HS71 in z = s * x with s spanning 1e-2..1e3 and *no* z_scale: scaling="guess" takes the magnitudes from the start,
    # which restores HS71's own (well-scaled) problem; with scaling="bounds" there is nothing to scale by, and the same
    # solver exhausts its budget far from the solution and says so.
    nlp = dataclasses.replace(hs71_nlp(HS71_SCALE), z_scale=None, name="hs71_units")
    guess = Extragradient().solve(nlp, NO_DATA)
    assert guess.success, guess.message
    np.testing.assert_allclose(guess.z / HS71_SCALE, HS71_Z, atol=1e-5)
    assert abs(guess.objective - HS71_F) <= 1e-5
    np.testing.assert_allclose(guess.multipliers, HS71_Y, atol=1e-4)
    plain = Extragradient(scaling="bounds").solve(nlp, NO_DATA)
    assert not plain.success and plain.status == 1
    assert np.max(np.abs(plain.z / HS71_SCALE - HS71_Z)) > 1e-2


@pytest.mark.parametrize("case_name", ["eq_qp", "hs71", "disc"])
def test_extragradient_without_start_scaling(case_name):
    # scaling="bounds" (only z_scale) stays a working mode: the known solutions, to the default mode's tolerances.
    case = CASES[case_name]
    result = Extragradient(scaling="bounds").solve(case.nlp, case.data)
    z_tol, f_tol, y_tol = TOLERANCES["extragradient"]
    assert result.success, result.message
    assert np.max(np.abs(result.z - case.z_star)) <= z_tol
    assert abs(result.objective - case.f_star) <= f_tol
    np.testing.assert_allclose(result.multipliers, case.y_star, atol=y_tol)


def test_extragradient_scales_a_steep_objective():
    # The same problem from the origin, where |grad F| = 4000: scaled to 100, plain ascent at a fixed penalty suffices,
    # and the multipliers come back in the unscaled objective's units.
    nlp = _nlp(
        lambda z, d: 1e3 * ((z[0] - 2.0) ** 2 + (z[1] - 1.0) ** 2), lambda z, d: jnp.stack([z[0] + z[1]]),
        [1.0], [1.0], [-INF, -INF], [INF, INF], [0.0, 0.0], name="steep_objective",
    )
    result = Extragradient(penalty_growth=1.0, max_iter=30_000).solve(nlp, NO_DATA)
    assert result.success, result.message
    np.testing.assert_allclose(result.z, [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(result.multipliers, [2000.0], rtol=1e-5)


def test_extragradient_penalty_grows_when_the_violation_stalls():
    # min 1000 |z - (2, 1)|^2 s.t. z1 + z2 = 1: z* = (1, 0) with a large multiplier, y* = 2000. Plain ascent at
    # rho = 1 creeps towards it; growing rho (and the dual step with it) on stalls gets there.
    nlp = _nlp(
        lambda z, d: 1e3 * ((z[0] - 2.0) ** 2 + (z[1] - 1.0) ** 2), lambda z, d: jnp.stack([z[0] + z[1]]),
        [1.0], [1.0], [-INF, -INF], [INF, INF], [0.0, 0.0], name="large_multiplier",
    )
    # Objective scaling off: it would shrink the multiplier to 50 (tested below); here the penalty must do it.
    fixed = Extragradient(penalty_growth=1.0, max_iter=30_000, scale_objective=False).solve(nlp, NO_DATA)
    grown = Extragradient(max_iter=30_000, scale_objective=False).solve(nlp, NO_DATA)
    assert not fixed.success and fixed.status == 1  # iteration limit
    assert grown.success, grown.message
    np.testing.assert_allclose(grown.z, [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(grown.multipliers, [2000.0], rtol=1e-6)


# ---- failures are failures -----------------------------------------------------------------------------------------

# z1 + z2 = 1 cannot hold with both in [0, 0.1].
INFEASIBLE = _nlp(
    lambda z, d: z @ z, lambda z, d: jnp.stack([z[0] + z[1]]), [1.0], [1.0], [0.0, 0.0], [0.1, 0.1], [0.05, 0.05],
    name="infeasible",
)


@pytest.mark.parametrize("solver_name", list(SOLVERS))
def test_infeasible_problem_is_not_a_success(solver_name):
    solver = SOLVERS[solver_name](max_iter=2000) if solver_name == "extragradient" else SOLVERS[solver_name]()
    result = solver.solve(INFEASIBLE, NO_DATA)
    assert not result.success
    assert result.status != 0
    assert result.constraint_violation >= 0.79  # the closest the box gets is z = (0.1, 0.1): violation 0.8
    assert result.message


def test_ipopt_iteration_limit_is_a_failure():
    result = Ipopt(max_iter=2).solve(CASES["hs71"].nlp, NO_DATA)
    assert not result.success
    assert result.solver_code == -1  # Maximum_Iterations_Exceeded
    assert result.status is Status.ITERATION_LIMIT


def test_ipopt_status_mapping():
    assert judge(0, b"ok", 1e-9, 1.0, 1e-6) == (True, "ok")
    # "Acceptable" is only a success when our own violation test passes too.
    assert judge(1, b"acceptable", 1e-7, 1.0, 1e-6)[0]
    success, message = judge(1, b"acceptable", 1e-3, 1.0, 1e-6)
    assert not success and "constr_viol_tol" in message
    assert not judge(0, b"ok", 1e-9, float("nan"), 1e-6)[0]
    for status in (-1, -2, -3, -13, 2, 3, 4, 5, 6):  # 6 = Feasible_Point_Found, also not an optimum
        assert judge(status, b"msg", 0.0, 1.0, 1e-6) == (False, "msg")


def test_constraint_violation_measure():
    nlp = CASES["disc"].nlp  # |z|^2 - r^2 <= 0, z in [-5, 5]^2
    assert constraint_violation(nlp, np.array([0.0, 0.0]), np.array([-1.0])) == 0.0
    assert constraint_violation(nlp, np.array([0.0, 0.0]), np.array([0.3])) == pytest.approx(0.3)
    assert constraint_violation(nlp, np.array([5.5, 0.0]), np.array([0.3])) == pytest.approx(0.5)
    assert constraint_violation(nlp, np.array([np.nan, 0.0]), np.array([0.0])) == float("inf")
    assert constraint_violation(nlp, np.array([0.0, 0.0]), np.array([np.inf])) == float("inf")
    # A batch at once (solve_batch's report): each row's own measure.
    z = np.array([[0.0, 0.0], [0.0, 0.0], [5.5, 0.0], [np.nan, 0.0], [-6.0, 0.0]])
    c = np.array([[-1.0], [0.3], [0.3], [0.0], [-2.0]])
    np.testing.assert_array_equal(constraint_violations(nlp, z, c), [0.0, 0.3, 0.5, np.inf, 1.0])


# ---- compilation is cached per NLP ---------------------------------------------------------------------------------


def counting_qp() -> tuple[NLP, dict]:
    """The QP with a Python side-effect counter in its objective: it counts traces, never runs under jit."""
    counter = {"traces": 0}
    base = qp_nlp()

    def objective(z, d):
        counter["traces"] += 1
        return base.objective(z, d)

    return dataclasses.replace(base, objective=objective), counter


@pytest.mark.parametrize("solver", [Ipopt(), SLSQP(), Extragradient()], ids=lambda s: type(s).__name__)
def test_second_solve_with_new_data_does_not_recompile(solver):
    nlp, counter = counting_qp()
    first_data, second_data = qp_data([1.0, 0, 0, 0, 0], [1.0, 2.0]), qp_data([-3.0, 1.0, 2.0, 0.5, 0], [0.5, -1.0])
    first = solver.solve(nlp, first_data)
    traces = counter["traces"]
    assert traces > 0 and first.compile_seconds > 0
    # Python floats and jax arrays in place of NumPy arrays must map to the same compiled program.
    second_data["params"]["q"] = jnp.asarray(second_data["params"]["q"])
    second = solver.solve(nlp, second_data)
    assert counter["traces"] == traces, "the second solve retraced the objective"
    assert second.compile_seconds == 0.0
    z_star, _, _ = qp_exact(qp_data(np.asarray(second_data["params"]["q"]), second_data["x0"]))
    assert second.success and np.max(np.abs(second.z - z_star)) <= 1e-5


def test_cache_does_not_keep_the_nlp_alive():
    nlp, _ = counting_qp()
    Ipopt(hessian="limited-memory").solve(nlp, qp_data(np.ones(5), [1.0, 2.0]))
    ref = weakref.ref(nlp)
    del nlp
    gc.collect()
    assert ref() is None


# ---- batches -------------------------------------------------------------------------------------------------------


def test_extragradient_batch_equals_single_solves():
    radii = np.linspace(0.5, 2.0, 8)
    nlp = disc_nlp()
    batch = {"params": {"r": radii}, "x0": np.zeros((8, 1))}
    solver = Extragradient()
    results = solver.solve_batch(nlp, batch)
    assert len(results) == 8
    for r, batched in zip(radii, results):
        single = solver.solve(nlp, disc_data(r))
        z_star, f_star, y_star = disc_exact(r)
        assert batched.success and single.success
        assert batched.iterations == single.iterations
        np.testing.assert_allclose(batched.z, single.z, rtol=0, atol=1e-12)
        np.testing.assert_allclose(batched.multipliers, single.multipliers, rtol=0, atol=1e-10)
        assert np.max(np.abs(batched.z - z_star)) <= 1e-5
        assert abs(batched.objective - f_star) <= 1e-5
    # The instances differ: the batch really carried different data.
    assert len({round(res.objective, 6) for res in results}) == 8


def test_extragradient_solve_fn_is_pure_jax():
    nlp, case = disc_nlp(), CASES["disc"]
    solve_fn = Extragradient().solve_fn(nlp)
    z, multipliers, iterations, converged, violation = solve_fn(case.data, np.zeros(2))
    assert bool(converged) and float(violation) <= 1e-6 and int(iterations) > 0
    np.testing.assert_allclose(z, case.z_star, atol=1e-5)
    np.testing.assert_allclose(multipliers, case.y_star, atol=1e-4)


# ---- sparse derivatives --------------------------------------------------------------------------------------------


def chain_nlp(with_sparsity: bool, n_steps: int = 12) -> NLP:
    """An Euler-transcribed pendulum: z = (x_0..x_N (2 each), u_0..u_{N-1}); banded Jacobian and Hessian."""
    h, n_x = 2.0 / n_steps, 2 * (n_steps + 1)

    def split(z):
        return z[:n_x].reshape(n_steps + 1, 2), z[n_x:]

    def objective(z, d):
        x, u = split(z)
        return h * (jnp.sum(x[:-1] ** 2) + jnp.sum(u**2)) + 10.0 * jnp.sum(x[-1] ** 2)

    def constraints(z, d):
        x, u = split(z)
        xdot = jnp.stack([x[:-1, 1], -d["params"]["k"] * jnp.sin(x[:-1, 0]) + u], axis=1)
        return jnp.concatenate([x[0] - d["x0"], (x[1:] - x[:-1] - h * xdot).ravel()])

    m = 2 + 2 * n_steps
    sparsity = None
    if with_sparsity:  # from the structure: x_0 = x0, then each defect touches x_k, x_{k+1} and u_k
        entries = [(0, 0), (1, 1)]
        for k in range(n_steps):
            entries += [(2 + 2 * k, 2 * k + 2), (2 + 2 * k, 2 * k), (2 + 2 * k, 2 * k + 1)]
            entries += [(3 + 2 * k, 2 * k + 3), (3 + 2 * k, 2 * k + 1), (3 + 2 * k, 2 * k), (3 + 2 * k, n_x + k)]
        rows, cols = np.array(entries).T
        sparsity = (rows, cols)
    return _nlp(
        objective, constraints, np.zeros(m), np.zeros(m),
        np.concatenate([np.full(n_x, -INF), -np.ones(n_steps)]), np.concatenate([np.full(n_x, INF), np.ones(n_steps)]),
        lambda d: jnp.concatenate([jnp.tile(d["x0"], n_steps + 1), jnp.zeros(n_steps)]),
        jacobian_sparsity=sparsity, name="chain",
    )


CHAIN_DATA = {"params": {"k": np.float64(1.0)}, "x0": np.array([1.0, 0.0])}


def test_coloured_derivatives_equal_dense_ones():
    nlp = chain_nlp(with_sparsity=True)
    n, m = nlp.n_variables, nlp.n_constraints
    z = np.random.default_rng(4).standard_normal(n)
    rows, cols = nlp.jacobian_sparsity
    # Jitted: op-by-op execution of these vmapped JVPs would dominate the test's time.
    values = jax.jit(compressed_jacobian_fn(nlp.constraints, rows, cols, (m, n)))(z, CHAIN_DATA)
    dense_j = np.asarray(jax.jit(jax.jacfwd(nlp.constraints))(z, CHAIN_DATA))
    np.testing.assert_allclose(values, dense_j[rows, cols], rtol=1e-12, atol=1e-12)
    assert np.count_nonzero(dense_j) == len(rows)  # the pattern is exact, so nothing outside it was dropped

    lam = np.random.default_rng(5).standard_normal(m)
    def lagrangian(z_, lam_):
        return nlp.objective(z_, CHAIN_DATA) + lam_ @ nlp.constraints(z_, CHAIN_DATA)

    dense_h = np.asarray(jax.jit(jax.hessian(lagrangian))(z, lam))
    h_rows, h_cols = np.nonzero(np.tril(np.abs(dense_h) > 0) | np.eye(n, dtype=bool))
    hvps = jax.jit(hvp_batch_fn(jax.grad(lagrangian)))
    colouring = HessianColouring(h_rows, h_cols, n, batch=4)
    h_values = colouring.values(lambda seeds: hvps(z, seeds, lam))
    np.testing.assert_allclose(h_values, dense_h[h_rows, h_cols], rtol=1e-12, atol=1e-12)
    assert colouring.n_colours < n // 4  # banded: a handful of products instead of one per variable


def test_ipopt_sparse_and_dense_jacobians_agree():
    sparse_nlp, dense_nlp = chain_nlp(with_sparsity=True), chain_nlp(with_sparsity=False)
    sparse, dense = Ipopt().solve(sparse_nlp, CHAIN_DATA), Ipopt().solve(dense_nlp, CHAIN_DATA)
    assert sparse.success and dense.success
    np.testing.assert_allclose(sparse.z, dense.z, atol=1e-8)
    np.testing.assert_allclose(sparse.multipliers, dense.multipliers, atol=1e-6)
    # The detected Hessian pattern is banded, far from the dense lower triangle.
    from myriad.runtime.solvers.base import _CACHE

    structure = _CACHE[sparse_nlp][("ipopt", True)].hessian_structure
    n = sparse_nlp.n_variables
    assert len(structure[0]) < n * (n + 1) // 4


# ---- configuration and registry ------------------------------------------------------------------------------------


def test_solver_configs_are_frozen_and_hashable():
    assert Ipopt(options={"mu_strategy": "adaptive"}) == Ipopt(options=(("mu_strategy", "adaptive"),))
    assert len({Ipopt(), Ipopt(), SLSQP(), Extragradient(), Extragradient()}) == 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        Ipopt().tol = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "make, fragment",
    [
        (lambda: Ipopt(hessian="bfgs"), "'exact', 'limited-memory'"),
        (lambda: Extragradient(bounds="barrier"), "'projection', 'sigmoid'"),
        (lambda: Extragradient(step="adam"), "GradientTransformation"),
        (lambda: Extragradient(scaling="rows"), "'guess', 'bounds'"),
        (lambda: SLSQP(tol=0.0), "positive"),
    ],
)
def test_invalid_options_say_what_is_allowed(make, fragment):
    with pytest.raises((ValueError, TypeError), match=fragment):
        make()


def test_ipopt_rejects_unknown_options_by_name():
    with pytest.raises(ValueError, match="no_such_option"):
        Ipopt(options={"no_such_option": 1}).solve(CASES["disc"].nlp, CASES["disc"].data)
