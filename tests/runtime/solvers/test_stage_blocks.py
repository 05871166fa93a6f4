"""Derivatives by stage (``interior_point.stage_blocks``, issue 32) against JAX's dense transforms.

Mathematics checked, on staged NLPs with path rows, a free final time (a border variable), required final values
(border rows), graded grids and multiple shooting with several steps per shooting interval: the blocks of
``stage_derivatives``, assembled densely, are ``jax.hessian`` of ``sigma F + y^T c`` and ``jax.jacfwd`` of ``c`` to
1e-10 relative, with ``F``, ``c`` and ``grad F`` as evaluated; the padding is exactly zero; the products by stage are
the dense products; one program serves every point and data of the same shapes, and a ``vmap`` over data gives each
member's own blocks; the program's largest array grows linearly in the number of intervals (never n x n).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load
from myriad.runtime.data import default_data
from myriad.runtime.solvers.interior_point.stage_blocks import (
    StageIndex,
    gather_rows,
    gather_vars,
    hess_matvec,
    jac_matvec,
    jac_rmatvec,
    scatter_rows,
    scatter_vars,
    stage_derivatives,
    to_dense,
)
from myriad.runtime.transcriptions import HermiteSimpson
from myriad.runtime.transcriptions.stage_structure import StageStructure

from ...helpers import CompileCounter
from .._stage_cases import VAN_DER_POL, case, random_point

WEIGHT = 0.7  # objective_weight: not 1, so a Hessian missing it shows


def _assert_close(actual, expected, what, rtol=1e-10):
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape, what
    scale = max(np.max(np.abs(expected), initial=0.0), 1e-300)
    assert np.max(np.abs(actual - expected), initial=0.0) <= rtol * scale, what


def _reference(nlp, data, z, y):
    def lagrangian(z_):
        return WEIGHT * nlp.objective(z_, data) + jnp.dot(y, nlp.constraints(z_, data))

    return jax.jit(lambda z_: (nlp.objective(z_, data), nlp.constraints(z_, data), jax.grad(nlp.objective)(z_, data),
                               jax.hessian(lagrangian)(z_), jax.jacfwd(nlp.constraints)(z_, data)))(z)


@functools.partial(jax.jit, static_argnums=1)  # one program: op by op, each small operation compiles on its own
def _dense_and_products(blocks, index, v, w):
    H, J = to_dense(blocks, index)
    return H, J, jac_matvec(blocks, index, v), jac_rmatvec(blocks, index, w), hess_matvec(blocks, index, v)


@pytest.mark.parametrize("name", ["trapezoidal-free-time-graded", "hermite_simpson-free-time", "multiple_shooting-vdp",
                                  "multiple_shooting-free-time-graded"])
def test_the_blocks_are_the_dense_derivatives(name):
    _, _, nlp, data = case(name)
    index = StageIndex.from_structure(nlp.stage_structure)
    z, y = random_point(nlp, data, seed=1)
    f, c, grad_f, blocks = jax.jit(stage_derivatives(nlp.evaluate, index))(z, y, data, WEIGHT)
    f_ref, c_ref, grad_ref, hess_ref, jac_ref = _reference(nlp, data, z, y)
    rng = np.random.default_rng(2)
    v, w = rng.standard_normal(index.n), rng.standard_normal(index.m)
    H, J, Jv, Jw, Hv = _dense_and_products(blocks, index, v, w)
    for actual, expected, what in ((f, f_ref, "F"), (c, c_ref, "c"), (grad_f, grad_ref, "grad F"),
                                   (H, hess_ref, "Hessian"), (J, jac_ref, "Jacobian")):
        _assert_close(actual, expected, what)
    # Padding is exactly zero: a pad variable's rows and columns, a pad row's entries.
    pad_var, pad_row = index.var_index < 0, index.row_index < 0
    h_diag, h_next = np.asarray(blocks.h_diag), np.asarray(blocks.h_next)
    assert not np.any(h_diag[pad_var]) and not np.any(np.swapaxes(h_diag, 1, 2)[pad_var])
    assert not np.any(h_next[pad_var[:-1]]) and not np.any(np.swapaxes(h_next, 1, 2)[pad_var[1:]])
    assert not np.any(np.asarray(blocks.h_border)[pad_var]) and not np.any(np.asarray(blocks.b_core)[:, pad_var])
    for block in (blocks.j_prev, blocks.j_diag, blocks.j_next, blocks.j_border):
        assert not np.any(np.asarray(block)[pad_row])
    assert not np.any(np.asarray(blocks.j_prev)[0]) and not np.any(np.asarray(blocks.j_next)[-1])
    _assert_close(Jv, jac_ref @ v, "J v", 1e-12)
    _assert_close(Jw, jac_ref.T @ w, "J^T y", 1e-12)
    _assert_close(Hv, H @ v, "H v", 1e-12)


def test_the_index_packs_each_stage_in_order_and_round_trips():
    structure = StageStructure(np.array([1, 0, -1, 2, 1, 1, 0]), np.array([2, -1, 1, 1, 0]), 3)
    index = StageIndex.from_structure(structure)
    assert (index.K, index.sv, index.sr, index.nb, index.mb, index.n, index.m) == (3, 3, 2, 1, 1, 7, 5)
    assert np.array_equal(index.var_index, [[1, 6, -1], [0, 4, 5], [3, -1, -1]])
    assert np.array_equal(index.row_index, [[4, -1], [2, 3], [0, -1]])
    assert np.array_equal(index.border_vars, [2]) and np.array_equal(index.border_rows, [1])
    # Colours: the same colour only three stages apart or more (here: never), border variables their own.
    assert np.array_equal(index.colour, [3, 0, 9, 6, 4, 5, 1])
    v, y = np.arange(1.0, 8.0), np.arange(1.0, 6.0)
    vk, yk = gather_vars(index, jnp.asarray(v)), gather_rows(index, jnp.asarray(y))
    assert np.array_equal(vk, [[2, 7, 0], [1, 5, 6], [4, 0, 0]]) and np.array_equal(yk, [[5, 0], [3, 4], [1, 0]])
    assert np.array_equal(scatter_vars(index, vk, jnp.asarray(v[index.border_vars])), v)
    assert np.array_equal(scatter_rows(index, yk, jnp.asarray(y[index.border_rows])), y)


def test_one_program_for_every_point_and_a_batch_over_data():
    system, _, nlp, data = case("hermite_simpson-free-time")
    index = StageIndex.from_structure(nlp.stage_structure)
    fn = jax.jit(stage_derivatives(nlp.evaluate, index))
    (z1, y1), (z2, y2) = random_point(nlp, data, seed=3), random_point(nlp, data, seed=4)
    other = default_data(system, x0=np.array([0.1, -0.1, 0.2, 0.0]))  # its parameters are structural
    jax.block_until_ready(fn(z1, y1, data, WEIGHT))
    with CompileCounter() as counter:
        second = jax.block_until_ready(fn(z2, y2, other, 0.0))
    assert counter.events == []
    # At weight 0 (IPOPT's restoration phase) the Hessian is y^T c's alone; the other x0 is read.
    reference = jax.jit(lambda z_: (jax.hessian(lambda u: jnp.dot(y2, nlp.constraints(u, other)))(z_),
                                    jax.jacfwd(nlp.constraints)(z_, other)))(z2)
    dense = jax.jit(to_dense, static_argnums=1)(second[3], index)
    for actual, expected, what in zip(dense, reference, ("Hessian at weight 0", "Jacobian")):
        _assert_close(actual, expected, what)
    batch = jax.tree.map(lambda a, b: np.stack([np.asarray(a), np.asarray(b)]), data, other)
    batched = jax.jit(jax.vmap(stage_derivatives(nlp.evaluate, index), in_axes=(0, 0, 0, None)))(
        np.stack([z1, z2]), np.stack([y1, y2]), batch, WEIGHT)
    for member, (z, y, d) in enumerate(((z1, y1, data), (z2, y2, other))):
        alone = fn(z, y, d, WEIGHT)
        for got, want in zip(jax.tree.leaves(batched), jax.tree.leaves(alone)):
            _assert_close(got[member], want, "a batch member", 1e-12)


def _largest_array(jaxpr) -> int:
    """The most elements of any value a jaxpr (and the jaxprs inside it) computes."""
    largest = 0
    for eqn in jaxpr.eqns:
        for var in eqn.outvars:
            largest = max(largest, int(np.prod(getattr(var.aval, "shape", ()))))
        for param in eqn.params.values():
            for sub in param if isinstance(param, (list, tuple)) else [param]:
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    largest = max(largest, _largest_array(inner))
    return largest


def test_the_largest_array_grows_linearly_in_the_intervals():
    system = load(VAN_DER_POL)
    data, sizes = default_data(system), {}
    for N in (8, 32):
        nlp = HermiteSimpson(intervals=N).transcribe(system)
        index = StageIndex.from_structure(nlp.stage_structure)
        z, y = random_point(nlp, data)
        jaxpr = jax.make_jaxpr(stage_derivatives(nlp.evaluate, index))(z, y, data, WEIGHT).jaxpr
        sizes[N] = (_largest_array(jaxpr), nlp.n_variables)
    (small, _), (large, n) = sizes[8], sizes[32]
    assert large < n * n / 4, f"an array of {large} elements with n = {n}"
    assert large / small <= 5.0, f"largest array {small} -> {large} for 4x the intervals"  # quadratic: ~16
