"""The interior point's block-tridiagonal Newton step (``interior_point.banded``) against dense linear algebra.

The factorisation eliminates the stages of ``K = [H + D_x, A^T; A, -D_c]`` in order and reads ``K``'s inertia from
the eigenvalues of the pivot blocks (Sylvester's law). Checked: on random stage-banded matrices with border variables
and rows, padding and a shuffled variable order, the counted inertia is ``np.linalg.eigvalsh``'s, for definite and
indefinite Hessians and for the restoration phase's row weights, and a solve is ``np.linalg.solve``'s; at real NLP
points the accepted ``delta_w`` and the step are the dense method's (``kkt.py``: the null-space method, also exact);
whole solves take the dense path's iterations to its cost, and the same shapes compile once.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from myriad.runtime.data import ProblemData
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.solvers.base import ScaledProblem
from myriad.runtime.solvers.interior_point import kkt, stage_blocks
from myriad.runtime.solvers.interior_point.banded import Banded
from myriad.runtime.solvers.interior_point.problem import Layout

from ...helpers import CompileCounter
from .._stage_cases import case, random_point

jax.config.update("jax_enable_x64", True)


def _random_structure(seed, K=6, border_vars=1, border_rows=1):
    """Stages of variables (1-3 a stage, stage 0 with one) and rows (at most the stage's variables), a border, all
    in a shuffled order; and random H, J that keep the band."""
    rng = np.random.default_rng(seed)
    var_stage = np.concatenate([[0]] + [[k] * rng.integers(2, 4) for k in range(1, K)] + [[-1] * border_vars])
    row_stage = np.concatenate([[k] * rng.integers(1, 3) for k in range(1, K)] + [[-1] * border_rows])
    var_stage, row_stage = rng.permutation(var_stage), rng.permutation(row_stage)
    n, m = var_stage.size, row_stage.size
    near = lambda a, b: (a[:, None] < 0) | (b[None, :] < 0) | (np.abs(a[:, None] - b[None, :]) <= 1)  # noqa: E731
    h = rng.standard_normal((n, n)) * near(var_stage, var_stage)
    h = 0.5 * (h + h.T)
    j = rng.standard_normal((m, n)) * near(row_stage, var_stage)
    return var_stage, row_stage, K, h, j


def _blocks(var_stage, row_stage, K, h, j):
    """The stage blocks of ``(H, J)``: the colour seeds' derivatives of ``(x^T H x / 2, J x)``."""
    index = stage_blocks.StageIndex.from_stages(var_stage, row_stage, K)
    evaluate = lambda x, data: (0.5 * x @ (jnp.asarray(h) @ x), jnp.asarray(j) @ x)  # noqa: E731
    fn = stage_blocks.stage_derivatives(evaluate, index)
    _, _, _, blocks = jax.jit(fn)(jnp.zeros(h.shape[0]), jnp.zeros(j.shape[0]), None, 1.0)
    return index, blocks


def _inertia(matrix):
    """By LAPACK's Bunch-Kaufman LDL^T (SciPy): exact for the badly scaled matrices too, where the eigenvalues of
    the whole matrix would lose the small ones to ``eps ||K||``."""
    _, d, _ = scipy.linalg.ldl(matrix)
    lam = np.linalg.eigvalsh(d)  # 1x1 and 2x2 blocks
    tol = 1e-12 * np.abs(lam).max()
    return int((lam > tol).sum()), int((lam < -tol).sum()), int((np.abs(lam) <= tol).sum())


@pytest.mark.parametrize("seed, border", [(0, 1), (1, 1), (2, 0)])  # border: a variable and a row, or none
# H + shift I: definite enough, indefinite (wrong inertia), or with every third Sigma at 1e10 (a variable at its
# bound: the blocks' rows then have eigenvalues ~ -1e-10 beside 1e10)
@pytest.mark.parametrize("shift", [3.0, -1.0, 1e10])
@pytest.mark.parametrize("weighted", [False, True])  # main phase (delta_c) or restoration (row weights)
def test_inertia_and_solve_are_the_dense_ones(seed, border, shift, weighted):
    var_stage, row_stage, K, h, j = _random_structure(seed, border_vars=border, border_rows=border)
    index, blocks = _blocks(var_stage, row_stage, K, h, j)
    n, m = h.shape[0], j.shape[0]
    rng = np.random.default_rng(100 + seed)
    sigma = rng.uniform(0.0, 1.0, n) + (np.where(np.arange(n) % 3 == 0, shift, 3.0) if shift > 1e3 else shift)
    row_diag = rng.uniform(0.5, 2.0, m) if weighted else np.full(m, 1e-6)
    banded = Banded(index, n, m)
    factors, inertia = jax.jit(lambda b, s, d: banded.factor(b, *banded._diagonals(s, 0.0, d)))(
        blocks, jnp.asarray(sigma), jnp.asarray(row_diag))
    dense = np.block([[h + np.diag(sigma), j.T], [j, -np.diag(row_diag)]])
    want = _inertia(dense)
    assert (int(inertia.positive) - int(banded.var_pad.sum()), int(inertia.negative) - int(banded.row_pad.sum()),
            int(inertia.zero)) == want
    r1, r2 = rng.standard_normal(n), rng.standard_normal(m)
    dx, dl = jax.jit(banded.solve)(factors, None, jnp.asarray(r1), jnp.asarray(r2))
    exact = np.linalg.solve(dense, np.concatenate([r1, r2]))
    np.testing.assert_allclose(np.concatenate([dx, dl]), exact, rtol=1e-9, atol=1e-9 * np.abs(exact).max())
    # The factors alone, before the refinement: a wrong factor hides behind a step that refines it.
    once = np.concatenate(jax.jit(lambda f, a, b: banded._join(*banded._solve_stages(f, *banded._split(a, b))))(
        factors, jnp.asarray(r1), jnp.asarray(r2)))
    # (to ~cond(K) eps: 1e-7 here, 1e-5 where Sigma spans 1e10; the one refinement step of every solve, above,
    # brings both to 1e-9)
    tol = 1e-7 if shift < 1e3 else 1e-5
    np.testing.assert_allclose(once, exact, rtol=tol, atol=tol * np.abs(exact).max())


@pytest.mark.parametrize("name", ["hermite_simpson-free-time", "multiple_shooting-vdp", "trapezoidal-path"])
def test_delta_w_and_step_are_the_dense_methods_at_nlp_points(name):
    """At a random point of a real NLP (slacks, border rows, a free final time), the banded inertia correction
    accepts the dense (null-space) method's ``delta_w`` and solves for the same step."""
    _, _, nlp, data = case(name)
    problem = ScaledProblem.from_nlp(nlp)
    banded, dense = Layout(problem, "banded"), Layout(problem, "dense")
    z, y = random_point(nlp, data)
    w = jnp.asarray(z / problem.scale)
    x = jnp.concatenate([w, jnp.zeros(banded.n_s)])
    rng = np.random.default_rng(3)
    sig = jnp.asarray(rng.uniform(0.0, 1.0, banded.n_x))
    r1, r2 = jnp.asarray(rng.standard_normal(banded.n_x)), jnp.asarray(rng.standard_normal(banded.m))

    def step(layout, method):
        f, c, gf, jc, h = layout.derivatives(w, jnp.asarray(y), data, 1.0)
        sigma, rows = layout.scaling(gf, jc)
        pt = layout.point(x, f, c, gf, jc, h, sigma, rows)
        factors, delta_w, ok = method.factorize_with_inertia(pt.hess, sig, pt.jac, 0.1, 0.0, r1)
        return delta_w, ok, method.solve(factors, pt.jac, r1, r2)

    dw_b, ok_b, (dx_b, dl_b) = jax.jit(lambda: step(banded, banded.banded))()
    dw_d, ok_d, (dx_d, dl_d) = jax.jit(lambda: step(dense, kkt))()
    assert bool(ok_b) and bool(ok_d)
    assert float(dw_b) == pytest.approx(float(dw_d), rel=1e-12, abs=0.0)
    scale = float(jnp.max(jnp.abs(jnp.concatenate([dx_d, dl_d]))))
    np.testing.assert_allclose(np.concatenate([dx_b, dl_b]), np.concatenate([dx_d, dl_d]), atol=1e-8 * scale)


@pytest.mark.slow  # two interior-point programs
def test_a_solve_takes_the_dense_paths_iterations_to_its_cost():
    """Path rows, slacks, a free final time and required final values (border rows and variable)."""
    _, _, nlp, data = case("hermite_simpson-free-time")
    z0 = nlp.initial_guess(data)
    outs = {kkt_: jax.jit(InteriorPoint(kkt=kkt_).pure_solve(nlp))(data, z0) for kkt_ in ("dense", "banded")}
    dense, banded = outs["dense"], outs["banded"]
    assert int(dense.status) == int(banded.status) == 0
    # The two factorisations round differently (stage pivots against a null-space basis): some steps apart over a
    # solve of ~60 iterations with a restoration phase (58 against 62 here, 58 against 68 on the fresh Debian root's
    # build), as IPOPT's own iteration counts differ between linear solvers.
    assert abs(int(banded.iterations) - int(dense.iterations)) <= max(2, 0.2 * int(dense.iterations))
    assert float(banded.objective) == pytest.approx(float(dense.objective), rel=1e-10)


def test_one_compile_for_the_same_shapes():
    """A second solve with other data reuses the program (vdp's initial state moved)."""
    _, _, nlp, data = case("trapezoidal-vdp")
    solver = InteriorPoint(kkt="banded")
    fn = jax.jit(solver.pure_solve(nlp))
    z0 = nlp.initial_guess(data)
    with CompileCounter() as counter:
        first = fn(data, z0)
        second = fn(data._replace(x0=data.x0 * 1.01), z0)
    assert len(counter.events) == 1
    assert int(first.status) == int(second.status) == 0
    assert float(first.objective) != float(second.objective)


@pytest.mark.slow  # two interior-point programs
def test_a_vmapped_batch_is_its_members_solved_alone():
    """``solve_batch(batch="vmap")`` of a collocation NLP vmaps the banded step: each member takes its own solve's
    iterations to its optimum."""
    _, _, nlp, data = case("trapezoidal-vdp")
    solver = InteriorPoint(batch="vmap")
    assert solver.kkt_method(nlp, vmapped=True) == "banded"
    x0 = np.asarray(data.x0) * np.array([[1.0], [0.9], [1.1]])
    params = {k: np.full(3, float(v)) for k, v in data.params.items()}
    batch = solver.solve_batch(nlp, ProblemData(params, x0))
    fn = jax.jit(solver.pure_solve(nlp))
    for member, x in zip(batch, x0):
        alone = fn(data._replace(x0=jnp.asarray(x)), nlp.initial_guess(data))
        assert member.success and int(alone.status) == 0 and member.iterations == int(alone.iterations)
        np.testing.assert_allclose(member.z, alone.z, rtol=0, atol=1e-9 * float(np.max(np.abs(alone.z))))
    assert len({round(m.objective, 6) for m in batch}) == 3


def test_banded_is_refused_without_a_stage_structure():
    from myriad.runtime import load, solve
    from myriad.runtime.transcriptions import SingleShooting

    with pytest.raises(ValueError, match="no stage structure"):
        solve(load("specs/van_der_pol.yaml"), transcription=SingleShooting(intervals=8),
              solver=InteriorPoint(kkt="banded"))


def _tridiagonal(k, s, a, seed, shift):
    """Random symmetric blocks (the leading ``a`` rows shifted by ``shift``, the rest by -0.1) and couplings, and
    the dense matrix."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((k, s, s))
    d = 0.5 * (d + np.swapaxes(d, 1, 2))
    d[:, :a, :a] += shift * np.eye(a)
    d[:, a:, a:] -= 0.1 * np.eye(s - a)
    e = 0.3 * rng.standard_normal((k - 1, s, s))
    dense = np.zeros((k * s, k * s))
    for i in range(k):
        dense[i * s:(i + 1) * s, i * s:(i + 1) * s] = d[i]
        if i < k - 1:
            dense[i * s:(i + 1) * s, (i + 1) * s:(i + 2) * s] = e[i]
            dense[(i + 1) * s:(i + 2) * s, i * s:(i + 1) * s] = e[i].T
    return d, e, dense


@pytest.mark.parametrize("k", [10, 50, 203])  # sequential, and partitioned with a padded last chunk
@pytest.mark.parametrize("shift", [5.0, -0.5])  # each block's own inertia (3, 2), or not
def test_partitioned_elimination_counts_and_solves(k, shift):
    from myriad.runtime.solvers.interior_point import tridiagonal

    d, e, dense = _tridiagonal(k, 5, 3, k, shift)
    factors, counts = jax.jit(lambda d_, e_: tridiagonal.factor(d_, e_, 3))(d, e)
    assert tuple(int(c) for c in counts) == _inertia(dense)
    r = np.random.default_rng(1).standard_normal((k, 5))
    x = jax.jit(tridiagonal.solve)(factors, jnp.asarray(r))
    exact = np.linalg.solve(dense, r.reshape(-1)).reshape(k, 5)
    np.testing.assert_allclose(x, exact, rtol=1e-9, atol=1e-9 * np.abs(exact).max())


def test_auto_takes_the_structure_each_nlp_has():
    """``kkt="auto"``: banded for collocation and multiple shooting, Riccati for long single shooting (a single solve
    or a vmapped batch), dense for the published single-shooting grids."""
    from myriad.runtime.transcriptions import HermiteSimpson, MultipleShooting, SingleShooting, Trapezoidal

    system = case("trapezoidal-vdp")[0]
    solver = InteriorPoint()
    for transcription in (Trapezoidal(intervals=8), HermiteSimpson(intervals=8), MultipleShooting(intervals=8)):
        nlp = transcription.transcribe(system)
        assert solver.kkt_method(nlp) == "banded" and solver.kkt_method(nlp, vmapped=True) == "banded"
        if jax.default_backend() == "cpu":  # the hang in solver.batch_strategy's docstring
            assert solver.batch_strategy(nlp) == "map"
    short, long = (SingleShooting(intervals=n).transcribe(system) for n in (100, 300))
    assert solver.kkt_method(short) == "dense" and solver.kkt_method(long) == "riccati"
    assert solver.kkt_method(short, vmapped=True) == "riccati"
    assert InteriorPoint(kkt="dense").kkt_method(long) == "dense"
