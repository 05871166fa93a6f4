r"""The Newton system of a collocation or multiple-shooting NLP, stage by stage: a block-tridiagonal factorisation.

Ordered by stage (:mod:`.stage_blocks`: stage ``k`` holds its variables, then its rows), the primal-dual matrix

.. math::
    K = \begin{pmatrix} H + D_x & A^\top \\ A & -D_c \end{pmatrix},\qquad
    D_x = \Sigma + \delta_w I,\quad D_c = \delta_c I \ \text{(main phase) or}\ \mathrm{diag}(1/d)\
    \text{(restoration)},

is block tridiagonal with stage blocks ``D_k`` (size ``s = sv + sr``) and couplings ``E_k`` between stages ``k`` and
``k + 1`` (the Hessian's ``H[vars_k, vars_{k+1}]`` and the rows that read the next or previous stage), bordered by
the few variables and rows that reach every stage (a free final time; terminal fixed-value rows). The core is
factorised by block Gaussian elimination (:mod:`.tridiagonal`: sequential for few stages, partitioned into chunks
eliminated side by side for many), the border by the Schur complement ``C - B^T K_core^{-1} B``. Elimination is a
congruence, so by Sylvester's law the pivot blocks' inertias summed are ``K``'s, exactly: no certificate, no
``rho``. That is the test IPOPT's inertia correction asks for (``(n_x, m, 0)``; a zero eigenvalue is a singular
``K``, for which ``delta_c`` is tried first), and the schedule is the dense method's (:func:`~.rules.certified`
without its ``rho`` retries). Cost: ``O(K s^3)`` per factorisation and ``O(K s^2)`` per solve, linear in the number
of stages; memory ``O(K s^2)``.

Padding: stages have ``sv`` variable and ``sr`` row slots; an unused variable slot carries ``+1`` on the diagonal and
an unused row slot ``-1``, uncoupled, so each adds one known eigenvalue that the inertia test expects.

Why no pivoting across stages: a stage's rows (its defects, which hold the stage's own state with a near-identity
coefficient) have full row rank in its own variables, so each pivot block is invertible wherever ``K`` is well
posed, and a pivot block's own inverse (its equilibrated eigendecomposition) is a stage-sized Bunch-Kaufman in
effect. What could still be inaccurate is caught by one step of iterative refinement on
``K`` in every solve, as the dense method does.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import stage_blocks as sb
from . import tridiagonal as tri
from .rules import certified, regularized

__all__ = ["Banded", "BandedFactors", "StageJacobian"]


@jax.tree_util.register_pytree_node_class
class StageJacobian:
    """``A`` (the scaled rows' Jacobian in ``x``) held as stage blocks; ``A @ v`` and ``A.T @ y`` in ``O(N)``, so the
    loop's residuals read it as they read a dense matrix."""

    def __init__(self, blocks: sb.StageBlocks, index: sb.StageIndex, transposed: bool = False):
        self.blocks, self.index, self.transposed = blocks, index, transposed

    def tree_flatten(self):
        return (self.blocks,), (self.index, self.transposed)

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(children[0], *aux)

    @property
    def T(self) -> "StageJacobian":  # noqa: N802 (numpy's name)
        return StageJacobian(self.blocks, self.index, not self.transposed)

    def __matmul__(self, v):
        if self.transposed:
            return sb.jac_rmatvec(self.blocks, self.index, v)
        return sb.jac_matvec(self.blocks, self.index, v)


class BandedFactors(NamedTuple):
    """The factorised system for any right-hand side, and what the refinement's residual needs."""

    blocks: sb.StageBlocks
    d_var: jax.Array  # (K, sv) D_x on the core variables (1 at padding)
    d_row: jax.Array  # (K, sr) -D_c on the core rows (-1 at padding)
    d_bvar: jax.Array  # (nb,)
    d_brow: jax.Array  # (mb,)
    core: tri.Factors  # the core's block-tridiagonal factors
    bmat: jax.Array  # (K, s, q) B, the core's coupling to the border (q = nb + mb)
    tinv_b: jax.Array  # (K, s, q) K_core^{-1} B
    schur_inv: jax.Array  # (q, q)


class _Inertia(NamedTuple):
    positive: jax.Array
    negative: jax.Array
    zero: jax.Array


class Banded:
    """The block-tridiagonal Newton step of one barrier problem's stage index (host arrays, built once)."""

    def __init__(self, index: sb.StageIndex, n_x: int, m: int):
        self.index, self.n_x, self.m = index, n_x, m
        self.K, self.sv, self.sr = index.K, index.sv, index.sr
        self.var_pad = np.asarray(index.var_index) < 0
        self.row_pad = np.asarray(index.row_index) < 0
        # Eigenvalues the inertia test expects: n_x positive (with the padded variable slots), m negative.
        self.expect_pos = n_x + int(self.var_pad.sum())
        self.expect_neg = m + int(self.row_pad.sum())

    # ---- assembly ----------------------------------------------------------------------------------------------

    def _stage_matrices(self, b: sb.StageBlocks, d_var, d_row):
        """``(D_k (K, s, s), E_k (K - 1, s, s))``: the stage blocks and the couplings to the next stage."""
        diag_h = b.h_diag + jax.vmap(jnp.diag)(d_var)
        top = jnp.concatenate([diag_h, jnp.swapaxes(b.j_diag, 1, 2)], axis=2)
        bottom = jnp.concatenate([b.j_diag, jax.vmap(jnp.diag)(d_row)], axis=2)
        d = jnp.concatenate([top, bottom], axis=1)
        e_top = jnp.concatenate([b.h_next, jnp.swapaxes(b.j_prev[1:], 1, 2)], axis=2)
        zeros = jnp.zeros((self.K - 1, self.sr, self.sr), d.dtype)
        e_bottom = jnp.concatenate([b.j_next[:-1], zeros], axis=2)
        return d, jnp.concatenate([e_top, e_bottom], axis=1)

    def _border(self, b: sb.StageBlocks, d_bvar, d_brow):
        """``(B (K, s, q), C (q, q))``: the core's coupling to the border variables and rows, and the border block."""
        mb = b.b_bb.shape[0]
        top = jnp.concatenate([b.h_border, jnp.transpose(b.b_core, (1, 2, 0))], axis=2)
        bottom = jnp.concatenate([b.j_border, jnp.zeros((self.K, self.sr, mb), b.j_border.dtype)], axis=2)
        c_top = jnp.concatenate([b.h_bb + jnp.diag(d_bvar), b.b_bb.T], axis=1)
        c_bottom = jnp.concatenate([b.b_bb, jnp.diag(d_brow)], axis=1)
        return jnp.concatenate([top, bottom], axis=1), jnp.concatenate([c_top, c_bottom], axis=0)

    # ---- factorisation -----------------------------------------------------------------------------------------

    def factor(self, b: sb.StageBlocks, d_var, d_row, d_bvar, d_brow) -> tuple[BandedFactors, _Inertia]:
        """The factors of ``K`` (diagonals given in stage form) and its inertia."""
        d, e = self._stage_matrices(b, d_var, d_row)
        core, counts = tri.factor(d, e, self.sv)
        bmat, cmat = self._border(b, d_bvar, d_brow)
        f = BandedFactors(b, d_var, d_row, d_bvar, d_brow, core, bmat, bmat, jnp.zeros_like(cmat))
        if cmat.shape[0]:
            tinv_b = tri.solve(core, bmat)
            schur_inv, border = tri.pivot(cmat - jnp.einsum("ksp,ksq->pq", bmat, tinv_b))
            f, counts = f._replace(tinv_b=tinv_b, schur_inv=schur_inv), counts + border
        return f, _Inertia(*(counts[i] for i in range(3)))

    def _right(self, inertia: _Inertia) -> jax.Array:
        return (inertia.positive == self.expect_pos) & (inertia.negative == self.expect_neg) & (inertia.zero == 0)

    def _diagonals(self, sigma, delta_w, row_diag):
        """``D_x`` and ``-D_c`` in stage form (padding +1 / -1) from the vectors over ``x`` and the rows."""
        ix = self.index
        d_x = sigma + delta_w
        d_var = jnp.where(self.var_pad, 1.0, sb.gather_vars(ix, d_x))
        d_row = jnp.where(self.row_pad, -1.0, -sb.gather_rows(ix, row_diag))
        return d_var, d_row, d_x[ix.border_vars], -row_diag[ix.border_rows]

    def factorize_with_inertia(self, h: sb.StageBlocks, sigma, jac: StageJacobian, mu, delta_w_last, r1=None):
        """IPOPT's inertia correction on the exact inertia (the module docstring): ``(factors, delta_w, ok)``."""
        del r1, jac
        dtype = sigma.dtype

        def factorize(k, delta_w, rho, delta_c):
            del k, rho
            f, inertia = self.factor(h, *self._diagonals(sigma, delta_w, jnp.full(self.m, delta_c, dtype)))
            singular = inertia.zero > 0
            # A singular K asks for delta_c first ((H ok, S failed) in the certificate's terms), else delta_w grows.
            return f, singular | self._right(inertia), ~singular

        return certified(factorize, jnp.zeros((), dtype), self.m, mu, delta_w_last, dtype, retries=0)

    def factorize_weighted(self, h: sb.StageBlocks, d, jac: StageJacobian, weights, delta_w_last):
        """The restoration phase's system, ``D_c = diag(1 / weights)``: right inertia exactly when ``H + D +
        delta_w I + A^T diag(weights) A`` is positive definite; ``(factors, delta_w, ok)``."""
        del jac
        row_diag = 1.0 / weights

        def factorize(delta_w):
            f, inertia = self.factor(h, *self._diagonals(d, delta_w, row_diag))
            return f, self._right(inertia)

        return regularized(factorize, delta_w_last, d.dtype)

    # ---- solves ------------------------------------------------------------------------------------------------

    def _solve_stages(self, f: BandedFactors, rc, rb):
        u = tri.solve(f.core, rc)
        if not rb.shape[0]:
            return u, rb
        xb = f.schur_inv @ (rb - jnp.einsum("ksq,ks->q", f.bmat, u))
        return u - f.tinv_b @ xb, xb

    def _split(self, v, y):
        """``(v, y)`` over ``x`` and the rows as ``(r_core (K, s), r_border (q,))``."""
        ix = self.index
        rc = jnp.concatenate([sb.gather_vars(ix, v), sb.gather_rows(ix, y)], axis=1)
        return rc, jnp.concatenate([v[ix.border_vars], y[ix.border_rows]])

    def _join(self, xc, xb):
        ix, sv, nb = self.index, self.sv, self.index.border_vars.shape[0]
        return (sb.scatter_vars(ix, xc[:, :sv], xb[:nb]), sb.scatter_rows(ix, xc[:, sv:], xb[nb:]))

    def _kkt_product(self, f: BandedFactors, dx, dl):
        """``K (dx, dl)`` with the factorisation's diagonals: the refinement's residual."""
        ix, b = self.index, f.blocks
        d_x = sb.scatter_vars(ix, f.d_var, f.d_bvar)
        d_c = sb.scatter_rows(ix, f.d_row, f.d_brow)
        top = sb.hess_matvec(b, ix, dx) + d_x * dx + sb.jac_rmatvec(b, ix, dl)
        return top, sb.jac_matvec(b, ix, dx) + d_c * dl

    def solve(self, f: BandedFactors, jac, r1, r2, presolved: bool = False):
        """``(d_x, d_lambda)`` solving ``K (d_x, d_lambda) = (r1, r2)``, with one step of iterative refinement."""
        del jac, presolved
        dx, dl = self._join(*self._solve_stages(f, *self._split(r1, r2)))
        res1, res2 = self._kkt_product(f, dx, dl)
        cx, cl = self._join(*self._solve_stages(f, *self._split(res1 - r1, res2 - r2)))
        return dx - cx, dl - cl

    def solve_restricted(self, b: sb.StageBlocks, keep_vars, keep_rows, r1, r2):
        """``(d_x, d_lambda, ||residual||)`` for the KKT matrix ``[[H, A^T], [A, 0]]`` of ``b`` restricted to the
        variables ``keep_vars`` and rows ``keep_rows`` (bool masks; the identity elsewhere: ``+1`` on a variable,
        ``-1`` on a row, so a right-hand side zero there gives zero there): the implicit rule's system at a solution
        (:mod:`~myriad.runtime.solvers.implicit`). One refinement step, as :meth:`solve`; the residual is the
        caller's to judge (a singular restriction leaves it large: the pivots drop zero eigenvalues)."""
        ix = self.index
        d_x, d_c = jnp.where(keep_vars, 0.0, 1.0), jnp.where(keep_rows, 0.0, -1.0)
        d_var = jnp.where(self.var_pad, 1.0, sb.gather_vars(ix, d_x))
        d_row = jnp.where(self.row_pad, -1.0, sb.gather_rows(ix, d_c))
        f, _ = self.factor(sb.restricted(b, ix, keep_vars, keep_rows), d_var, d_row, d_x[ix.border_vars],
                           d_c[ix.border_rows])
        dx, dl = self.solve(f, None, r1, r2)
        t1, t2 = self._kkt_product(f, dx, dl)
        return dx, dl, jnp.sqrt(jnp.sum((t1 - r1) ** 2) + jnp.sum((t2 - r2) ** 2))

    def solve_weighted(self, f: BandedFactors, jac, weights, r1, r2):
        """The restoration phase's step (:meth:`factorize_weighted`): the same solve, its ``D_c`` in the factors."""
        del weights
        return self.solve(f, jac, r1, r2)
