r"""The Lagrangian's Hessian and the constraint Jacobian of a staged NLP as blocks by stage, and their derivatives.

A transcription that is a chain of stages (:class:`~myriad.runtime.transcriptions.stage_structure.StageStructure`)
has a block-tridiagonal Hessian and a block-banded Jacobian, plus a border of a few variables (a free final time)
and rows (terminal fixed values) that couple to everything:

.. math::
    H = \begin{pmatrix} D_0 & U_0 & & B_0 \\ U_0^T & D_1 & \ddots & \vdots \\ & \ddots & \ddots & B_{K-1} \\
        B_0^T & \cdots & B_{K-1}^T & H_{bb} \end{pmatrix},\qquad
    J_{\text{row stage } k} = (\,P_k \mid D_k \mid N_k\,) \text{ on stages } k-1, k, k+1,\ \text{plus the border.}

:class:`StageBlocks` holds those blocks, padded to ``sv`` variables and ``sr`` rows per stage (zeros at padding);
:class:`StageIndex` is where each block's entries sit in ``z`` and ``c`` (static host arrays). The derivatives
(:func:`stage_derivatives`) take ``3 sv + nb`` forward-over-reverse directions instead of ``n``: a core variable
``(k, i)`` shares its colour ``(k mod 3) sv + i`` with the ``i``-th variable of every third stage, which no row and
no Hessian entry ever sees together (they are at least three stages apart), so each product with a colour's seed
reads off one block column of every stage. Cost linear in the number of stages; nothing ``n x n`` is ever formed.
The interface is /work/coord/stages_spec.md (issue 32); the block factorisation is :mod:`.banded`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "StageBlocks",
    "StageIndex",
    "gather_rows",
    "gather_vars",
    "hess_matvec",
    "jac_matvec",
    "jac_rmatvec",
    "restricted",
    "scatter_rows",
    "scatter_vars",
    "stage_derivatives",
    "to_dense",
]

COLOURS_PER_CHAIN = 3  # stages k and k + 3 never meet in a row or a Hessian entry: they can share seeds


def _pack(stage: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(index (K, width) of each stage's ids in increasing order, -1 padded; border ids; position of each id in
    the flattened (K * width + border) layout)``, sorted in O(n log n) rather than one scan per stage."""
    core = np.flatnonzero(stage >= 0)
    stages = stage[core]
    counts = np.bincount(stages, minlength=K)
    width = int(counts.max(initial=0))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    order = np.argsort(stages, kind="stable")  # stable: ids stay increasing within a stage
    ids, owner = core[order], stages[order]
    slot = np.arange(ids.size) - starts[owner]
    index = np.full((K, width), -1, dtype=np.int64)
    index[owner, slot] = ids
    border = np.flatnonzero(stage < 0).astype(np.int64)
    position = np.empty(stage.size, dtype=np.int64)
    position[ids] = owner * width + slot
    position[border] = K * width + np.arange(border.size)
    return index, border, position


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for a in arrays:
        a.setflags(write=False)
    return arrays


@dataclasses.dataclass(frozen=True, eq=False)
class StageIndex:
    """Where the blocks of a :class:`StageBlocks` sit in ``z`` and ``c`` (static host arrays, never traced).

    Attributes:
        K: stages; sv, sr: the most core variables and rows in one stage; nb, mb: border variables and rows.
        var_index: (K, sv) int64, the variable ids of stage k in increasing order, -1 padding; row_index (K, sr).
        border_vars: (nb,), border_rows: (mb,) int64.
        n, m: variables and rows of the NLP.
        var_position, row_position: (n,), (m,) each id's place in the flattened ``(K * sv + nb)`` or
            ``(K * sr + mb)`` layout of :func:`scatter_vars` / :func:`scatter_rows`.
    """

    K: int
    sv: int
    sr: int
    nb: int
    mb: int
    var_index: np.ndarray
    row_index: np.ndarray
    border_vars: np.ndarray
    border_rows: np.ndarray
    n: int
    m: int
    var_position: np.ndarray
    row_position: np.ndarray

    @classmethod
    def from_structure(cls, structure: Any) -> "StageIndex":
        """The index of a :class:`~myriad.runtime.transcriptions.stage_structure.StageStructure`."""
        return cls.from_stages(structure.var_stage, structure.row_stage, structure.n_stages)

    @classmethod
    def from_stages(cls, var_stage: np.ndarray, row_stage: np.ndarray, n_stages: int) -> "StageIndex":
        """The index of the stages of each variable and row (as a StageStructure holds them, already checked): for a
        solver that extends the NLP's structure (slacks) without importing the transcriptions package, which imports
        the solvers."""
        K = int(n_stages)
        var_index, border_vars, var_position = _frozen(*_pack(np.asarray(var_stage, dtype=np.int64), K))
        row_index, border_rows, row_position = _frozen(*_pack(np.asarray(row_stage, dtype=np.int64), K))
        return cls(K=K, sv=var_index.shape[1], sr=row_index.shape[1], nb=border_vars.size, mb=border_rows.size,
                   var_index=var_index, row_index=row_index, border_vars=border_vars, border_rows=border_rows,
                   n=var_position.size, m=row_position.size, var_position=var_position, row_position=row_position)

    @property
    def n_colours(self) -> int:
        """Seeds of :func:`stage_derivatives`: ``3 sv`` for the core variables, one per border variable."""
        return COLOURS_PER_CHAIN * self.sv + self.nb

    @functools.cached_property
    def colour(self) -> np.ndarray:
        """(n,) the seed of each variable: ``(k mod 3) sv + i`` for core variable ``(k, i)``, ``3 sv + j`` for
        border variable ``j``."""
        k, i = np.divmod(self.var_position, max(self.sv, 1))
        core = self.var_position < self.K * self.sv
        border = COLOURS_PER_CHAIN * self.sv + self.var_position - self.K * self.sv
        return np.where(core, (k % COLOURS_PER_CHAIN) * self.sv + i, border)

    @functools.cached_property
    def vars_padded(self) -> np.ndarray:
        """(K + 2, sv) ``var_index`` with a padding stage before and after, pads at ``n`` (one past the last id):
        row ``k + 1`` is stage ``k``, so stages ``k - 1`` and ``k + 1`` are rows ``k`` and ``k + 2``."""
        pads = np.full((1, self.sv), self.n, dtype=np.int64)
        return np.concatenate([pads, np.where(self.var_index < 0, self.n, self.var_index), pads])

    @functools.cached_property
    def rows_padded(self) -> np.ndarray:
        """(K, sr) ``row_index`` with pads at ``m``."""
        return np.where(self.row_index < 0, self.m, self.row_index)


class StageBlocks(NamedTuple):
    """The Hessian ``H`` and Jacobian ``J`` by stage (zeros at padding); ``vars_k``, ``rows_k`` as in
    :class:`StageIndex`."""

    h_diag: Any  # (K, sv, sv) H[vars_k, vars_k]
    h_next: Any  # (K-1, sv, sv) H[vars_k, vars_{k+1}]
    h_border: Any  # (K, sv, nb) H[vars_k, border vars]
    h_bb: Any  # (nb, nb)
    j_prev: Any  # (K, sr, sv) J[rows_k, vars_{k-1}] (zeros for k = 0)
    j_diag: Any  # (K, sr, sv) J[rows_k, vars_k]
    j_next: Any  # (K, sr, sv) J[rows_k, vars_{k+1}] (zeros for k = K-1)
    j_border: Any  # (K, sr, nb) J[rows_k, border vars]
    b_core: Any  # (mb, K, sv) J[border rows, vars_k]
    b_bb: Any  # (mb, nb) J[border rows, border vars]


# ---- vectors by stage -----------------------------------------------------------------------------------------------


def gather_vars(index: StageIndex, v: Any) -> Any:
    """``v`` (n,) as (K, sv) by stage, zeros at padding (the border part is ``v[index.border_vars]``)."""
    return jnp.concatenate([v, jnp.zeros(1, v.dtype)])[index.vars_padded[1:-1]]


def gather_rows(index: StageIndex, y: Any) -> Any:
    """``y`` (m,) as (K, sr) by stage, zeros at padding (the border part is ``y[index.border_rows]``)."""
    return jnp.concatenate([y, jnp.zeros(1, y.dtype)])[index.rows_padded]


def scatter_vars(index: StageIndex, vk: Any, nb_part: Any) -> Any:
    """The (n,) vector whose stage parts are ``vk`` (K, sv) and border part ``nb_part`` (nb,): the inverse of
    :func:`gather_vars` (a gather, since every variable has exactly one place)."""
    return jnp.concatenate([jnp.reshape(vk, (-1,)), nb_part])[index.var_position]


def scatter_rows(index: StageIndex, yk: Any, mb_part: Any) -> Any:
    """The (m,) vector whose stage parts are ``yk`` (K, sr) and border part ``mb_part`` (mb,)."""
    return jnp.concatenate([jnp.reshape(yk, (-1,)), mb_part])[index.row_position]


def _from_prev(x: Any) -> Any:
    """``out[k] = x[k - 1]`` (zeros at k = 0): what stage k receives from stage k - 1."""
    return jnp.concatenate([jnp.zeros_like(x[:1]), x[:-1]])


def _from_next(x: Any) -> Any:
    """``out[k] = x[k + 1]`` (zeros at k = K - 1)."""
    return jnp.concatenate([x[1:], jnp.zeros_like(x[:1])])


# ---- products -------------------------------------------------------------------------------------------------------


def jac_matvec(blocks: StageBlocks, index: StageIndex, v: Any) -> Any:
    """``J v`` (m,) for ``v`` (n,)."""
    vk, vb = gather_vars(index, v), v[index.border_vars]
    core = (jnp.einsum("kab,kb->ka", blocks.j_diag, vk) + jnp.einsum("kab,kb->ka", blocks.j_prev, _from_prev(vk))
            + jnp.einsum("kab,kb->ka", blocks.j_next, _from_next(vk)) + blocks.j_border @ vb)
    border = jnp.einsum("ikb,kb->i", blocks.b_core, vk) + blocks.b_bb @ vb
    return scatter_rows(index, core, border)


def jac_rmatvec(blocks: StageBlocks, index: StageIndex, y: Any) -> Any:
    """``J^T y`` (n,) for ``y`` (m,): row stage k's ``j_prev`` lands on variable stage k - 1, its ``j_next`` on
    k + 1."""
    yk, yb = gather_rows(index, y), y[index.border_rows]
    core = (jnp.einsum("kab,ka->kb", blocks.j_diag, yk) + _from_next(jnp.einsum("kab,ka->kb", blocks.j_prev, yk))
            + _from_prev(jnp.einsum("kab,ka->kb", blocks.j_next, yk)) + jnp.einsum("ikb,i->kb", blocks.b_core, yb))
    border = jnp.einsum("kaj,ka->j", blocks.j_border, yk) + blocks.b_bb.T @ yb
    return scatter_vars(index, core, border)


def hess_matvec(blocks: StageBlocks, index: StageIndex, v: Any) -> Any:
    """``H v`` (n,) for ``v`` (n,), ``H`` symmetric: the block below the diagonal is ``h_next`` transposed."""
    vk, vb = gather_vars(index, v), v[index.border_vars]
    zero = jnp.zeros_like(vk[:1])
    upper = jnp.concatenate([jnp.einsum("kab,kb->ka", blocks.h_next, vk[1:]), zero])
    lower = jnp.concatenate([zero, jnp.einsum("kab,ka->kb", blocks.h_next, vk[:-1])])
    core = jnp.einsum("kab,kb->ka", blocks.h_diag, vk) + upper + lower + blocks.h_border @ vb
    border = jnp.einsum("kaj,ka->j", blocks.h_border, vk) + blocks.h_bb @ vb
    return scatter_vars(index, core, border)


def restricted(blocks: StageBlocks, index: StageIndex, keep_vars: Any, keep_rows: Any) -> StageBlocks:
    """``blocks`` with the Hessian's rows and columns of the variables not in ``keep_vars`` (n,) and the Jacobian's
    rows not in ``keep_rows`` (m,) and columns not in ``keep_vars`` set to zero (bool masks): the KKT matrix of a
    subset of the variables and rows, with static shapes (the implicit rule's, where the free variables and the
    active rows are known only at run time)."""
    vk = gather_vars(index, keep_vars.astype(blocks.h_diag.dtype))
    vb = keep_vars[index.border_vars].astype(vk.dtype)
    rk = gather_rows(index, keep_rows.astype(vk.dtype))
    rb = keep_rows[index.border_rows].astype(vk.dtype)
    pair = lambda a, b: a[..., :, None] * b[..., None, :]  # noqa: E731
    return StageBlocks(
        h_diag=blocks.h_diag * pair(vk, vk), h_next=blocks.h_next * pair(vk[:-1], vk[1:]),
        h_border=blocks.h_border * pair(vk, vb), h_bb=blocks.h_bb * pair(vb, vb),
        j_prev=blocks.j_prev * pair(rk, _from_prev(vk)), j_diag=blocks.j_diag * pair(rk, vk),
        j_next=blocks.j_next * pair(rk, _from_next(vk)), j_border=blocks.j_border * pair(rk, vb),
        b_core=blocks.b_core * rb[:, None, None] * vk[None], b_bb=blocks.b_bb * pair(rb, vb))


def to_dense(blocks: StageBlocks, index: StageIndex) -> tuple[Any, Any]:
    """``(H (n, n), J (m, n))`` from the blocks: a reference for tests and small problems, never the solver's path."""
    n, m, vp, bv, br = index.n, index.m, index.vars_padded, index.border_vars, index.border_rows
    here, after, before, rows = vp[1:-1], vp[2:], vp[:-2], index.rows_padded
    H = jnp.zeros((n, n), blocks.h_diag.dtype)

    def put(A, r, c, values):  # pads point one past the end: dropped
        return A.at[r, c].set(values, mode="drop")

    H = put(H, here[:, :, None], here[:, None, :], blocks.h_diag)
    H = put(H, here[:-1, :, None], after[:-1, None, :], blocks.h_next)
    H = put(H, after[:-1, None, :], here[:-1, :, None], blocks.h_next)
    H = put(H, here[:, :, None], bv[None, None, :], blocks.h_border)
    H = put(H, bv[None, None, :], here[:, :, None], blocks.h_border)
    H = put(H, bv[:, None], bv[None, :], blocks.h_bb)
    J = jnp.zeros((m, n), blocks.j_diag.dtype)
    for cols, block in ((before, blocks.j_prev), (here, blocks.j_diag), (after, blocks.j_next)):
        J = put(J, rows[:, :, None], cols[:, None, :], block)
    J = put(J, rows[:, :, None], bv[None, None, :], blocks.j_border)
    J = put(J, br[:, None, None], here[None, :, :], blocks.b_core)
    return H, put(J, br[:, None], bv[None, :], blocks.b_bb)


# ---- derivatives by stage -------------------------------------------------------------------------------------------


def _seeds(index: StageIndex, stages: np.ndarray) -> np.ndarray:
    """(len(stages), 1, sv): the seeds of the core colours of ``stages`` (any integers: taken mod 3)."""
    return ((stages % COLOURS_PER_CHAIN) * index.sv)[:, None, None] + np.arange(index.sv)[None, None, :]


def _read(products: Any, seeds: np.ndarray, at: np.ndarray, cols: np.ndarray, pad: int) -> Any:
    """Block entries ``products[seed, at]`` (products: (colours, size + 1), zero in the last column, where the pads
    ``at == size`` read), zero where the block's column variable ``cols`` is a pad (``== pad``): a pad colour's seed
    holds other stages' variables, which the band makes zero here, but padding is promised exactly zero."""
    return jnp.where(cols < pad, products[seeds, at], 0.0)


def _symmetric(a: Any) -> Any:
    return 0.5 * (a + jnp.swapaxes(a, -1, -2))


def _hessian_blocks(index: StageIndex, hv: Any) -> tuple[Any, Any, Any, Any]:
    """``(h_diag, h_next, h_border, h_bb)`` from ``hv`` (colours, n + 1), the Hessian's products with the seeds.
    Forward over reverse is symmetric only to rounding: both triangles are read and averaged, as the dense path does."""
    K, n, vp, nb = index.K, index.n, index.vars_padded, index.nb
    here, after, border_seeds = vp[1:-1], vp[2:], COLOURS_PER_CHAIN * index.sv + np.arange(nb)
    stages = np.arange(K)
    h_diag = _symmetric(_read(hv, _seeds(index, stages), here[:, :, None], here[:, None, :], n))
    upper = _read(hv, _seeds(index, stages[1:]), here[:-1, :, None], after[:-1, None, :], n)
    lower = _read(hv, _seeds(index, stages[:-1]), after[:-1, :, None], here[:-1, None, :], n)
    h_next = 0.5 * (upper + jnp.swapaxes(lower, -1, -2))
    h_border = hv[border_seeds[None, None, :], here[:, :, None]]
    h_bb = _symmetric(hv[border_seeds[None, :], index.border_vars[:, None]])
    return h_diag, h_next, h_border, h_bb


def _jacobian_blocks(index: StageIndex, jv: Any, border_rows: Any) -> tuple[Any, ...]:
    """``(j_prev, j_diag, j_next, j_border, b_core, b_bb)`` from ``jv`` (colours, m + 1), the Jacobian's products with
    the seeds, and ``border_rows`` (mb, n + 1), the border rows of the Jacobian (reverse mode)."""
    n, vp, rows, stages = index.n, index.vars_padded, index.rows_padded[:, :, None], np.arange(index.K)
    blocks = tuple(_read(jv, _seeds(index, stages + shift), rows, cols[:, None, :], n)
                   for shift, cols in ((-1, vp[:-2]), (0, vp[1:-1]), (1, vp[2:])))
    j_border = jv[COLOURS_PER_CHAIN * index.sv + np.arange(index.nb)[None, None, :], rows]
    return (*blocks, j_border, border_rows[:, vp[1:-1]], border_rows[:, index.border_vars])


def _with_zero_column(a: Any) -> Any:
    return jnp.concatenate([a, jnp.zeros((a.shape[0], 1), a.dtype)], axis=1)


def stage_derivatives(evaluate: Callable[[Any, Any], tuple[Any, Any]], index: StageIndex) -> Callable:
    """``fn(w, y, data, objective_weight=1) -> (F, c (m,), grad F (n,), StageBlocks)`` of ``evaluate(w, data) ->
    (F, c)``, the Hessian that of ``objective_weight F + y^T c``.

    One forward-over-reverse pass along the ``3 sv + nb`` colour seeds (:attr:`StageIndex.colour`) gives ``c``'s
    and the Lagrangian gradient's directional derivatives, from which static gathers read every block; one reverse
    pass per border row (their Jacobian rows are dense across stages, so no colouring separates them) and one for
    ``grad F`` (the Lagrangian's gradient mixes in ``J^T y`` and ``objective_weight`` may be 0). Cost linear in the
    number of stages; jit- and vmap-able."""
    colour, n_colours, mb = index.colour, index.n_colours, index.mb
    cotangent_rows = np.zeros((mb + 1, index.m))
    cotangent_rows[1 + np.arange(mb), index.border_rows] = 1.0

    def fn(w, y, data, objective_weight=1.0):
        def values(w_):
            f_, c_ = evaluate(w_, data)
            return f_, jnp.reshape(c_, (-1,))

        def lagrangian(w_):
            f_, c_ = values(w_)
            return objective_weight * f_ + (jnp.dot(y, c_) if index.m else 0.0), (f_, c_)

        def outputs(w_):
            grad_l, (f_, c_) = jax.grad(lagrangian, has_aux=True)(w_)
            return f_, c_, grad_l

        seeds = jnp.asarray(colour[None, :] == np.arange(n_colours)[:, None], w.dtype)
        (f, c, _), (_, jv, hv) = jax.vmap(lambda s: jax.jvp(outputs, (w,), (s,)), out_axes=(None, 0))(seeds)
        _, pullback = jax.vjp(values, w)
        cot_f = jnp.zeros(mb + 1, w.dtype).at[0].set(1.0)
        (reverse,) = jax.vmap(pullback)((cot_f, jnp.asarray(cotangent_rows, w.dtype)))
        h = _hessian_blocks(index, _with_zero_column(hv))
        j = _jacobian_blocks(index, _with_zero_column(jv), _with_zero_column(reverse[1:]))
        return f, c, reverse[0], StageBlocks(*h, *j)

    return fn
