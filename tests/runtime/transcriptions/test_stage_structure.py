"""The stage structure of the staged transcriptions (issue 32): every variable and row in the stage the convention
says, and the promise that makes a block-banded Newton step exact.

Mathematics checked, on every staged transcription with path rows, a free final time, graded grids and multiple
shooting with several steps per shooting interval: the declared Jacobian pattern and the true Jacobian (forward
mode) couple no core row to a core variable more than one stage away; the Hessian of F + y^T c (``jax.hessian``,
random y, random z inside the bounds) couples no two core variables more than one stage apart; each stage's equality
rows have full row rank in the stage's own variables (what the block factorisation pivots on); a structure that is
wrong by one variable's stage is caught, naming the entry.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime.transcriptions import SingleShooting
from myriad.runtime.transcriptions.stage_structure import BORDER, StageStructure

from .._stage_cases import BRYSON_DENHAM, CASES, KEEP_OUT, case, random_point


def _true_derivatives(nlp, data, z, y):
    """The constraint Jacobian and the Hessian of F + y^T c, dense, by JAX's own transforms."""
    lagrangian = lambda z_: nlp.objective(z_, data) + jnp.dot(y, nlp.constraints(z_, data))  # noqa: E731
    jac, hess = jax.jit(lambda z_: (jax.jacfwd(nlp.constraints)(z_, data), jax.hessian(lagrangian)(z_)))(z)
    return np.asarray(jac), np.asarray(hess)


@pytest.mark.parametrize("name", list(CASES))
def test_the_structure_describes_the_nlp(name):
    system, transcription, nlp, data = case(name)
    st = nlp.stage_structure
    assert isinstance(st, StageStructure)
    assert (st.n_variables, st.n_constraints) == (nlp.n_variables, nlp.n_constraints)
    # One stage per node (collocation) or shooting node (multiple shooting), x_0 given: K = intervals + 1.
    assert st.n_stages == transcription.intervals + 1
    # The border: a free final time (the last variable), and the required final values' rows (after the defects).
    assert np.array_equal(np.flatnonzero(st.var_stage == BORDER), [nlp.n_variables - 1] if system.free_horizon else [])
    defects = transcription.intervals * system.n_states
    assert np.array_equal(np.flatnonzero(st.row_stage == BORDER), defects + np.arange(int(system.final_mask.sum())))
    # Every stage holds variables; defect j (between nodes j and j + 1) is in stage j + 1.
    assert np.array_equal(np.unique(st.var_stage[st.var_stage >= 0]), np.arange(st.n_stages))
    assert np.array_equal(st.row_stage[:defects], np.repeat(np.arange(1, st.n_stages), system.n_states))
    st.check_jacobian(*nlp.jacobian_sparsity)


@pytest.mark.parametrize("name", list(CASES))
def test_the_true_derivatives_keep_the_band(name):
    _, _, nlp, data = case(name)
    st = nlp.stage_structure
    z, y = random_point(nlp, data)
    jac, hess = _true_derivatives(nlp, data, z, y)
    if CASES[name][0] != BRYSON_DENHAM:  # linear dynamics and path row, u^2 / 2: a diagonal Hessian
        assert np.count_nonzero(hess) > nlp.n_variables  # a real check: the Hessian is not diagonal here
    st.check_jacobian(*np.nonzero(jac))
    st.check_hessian(*np.nonzero(hess))
    # What a block factorisation pivots on: each stage's equality rows, in the stage's own variables, full row rank.
    equality = nlp.c_lower == nlp.c_upper
    for k in range(st.n_stages):
        rows = np.flatnonzero((st.row_stage == k) & equality)
        block = jac[np.ix_(rows, np.flatnonzero(st.var_stage == k))]
        assert np.linalg.matrix_rank(block) == rows.size, f"stage {k}'s equality rows are rank deficient"


def test_a_wrong_stage_is_named():
    _, _, nlp, data = case("hermite_simpson-free-time")
    st = nlp.stage_structure
    z, y = random_point(nlp, data)
    _, hess = _true_derivatives(nlp, data, z, y)
    # u_0 (the first control, after the N n node states) moved to the last stage: defect 0 still reads it.
    M, n = st.n_stages - 1, 4
    moved = st.var_stage.copy()
    moved[M * n] = M
    wrong = StageStructure(moved, st.row_stage, st.n_stages)
    with pytest.raises(ValueError, match=rf"row 0 \(stage 1\) and variable {M * n} \(stage {M}\)"):
        wrong.check_jacobian(*nlp.jacobian_sparsity)
    with pytest.raises(ValueError, match=r"variable \d+ \(stage \d\) and variable \d+ \(stage \d\)"):
        wrong.check_hessian(*np.nonzero(hess))
    with pytest.raises(ValueError, match="there are"):
        st.check_jacobian(np.array([nlp.n_constraints]), np.array([0]))


@pytest.mark.parametrize("var_stage, row_stage, n_stages, message", [
    (np.array([0, 1, 2]), np.array([1]), 2, r"var_stage\[2\] = 2 is not a stage"),
    (np.array([0, -2]), np.array([1]), 2, r"var_stage\[1\] = -2"),
    (np.array([0.0, 1.0]), np.array([1]), 2, "integer stages"),
    (np.array([[0, 1]]), np.array([1]), 2, "flat array"),
    (np.array([0, 1]), np.array([1]), 0, "n_stages must be a positive integer"),
])
def test_bad_structures_are_refused(var_stage, row_stage, n_stages, message):
    with pytest.raises(ValueError, match=message):
        StageStructure(var_stage, row_stage, n_stages)


def test_single_shooting_has_no_stage_structure():
    from myriad.runtime import load

    assert SingleShooting(intervals=6).transcribe(load(KEEP_OUT)).stage_structure is None
