r"""The Newton system of a single-shooting NLP, stage by stage: a Riccati recursion instead of dense Cholesky.

Where the decisions reach the functions only through one rollout (``transcriptions/staged.py``), the Hessian of the
Lagrangian in the decisions ``w`` is that of a linear-quadratic problem in the rollout's stages (Dunn & Bertsekas
1989), and the barrier problem's variables are ``x = (w, s)`` (slacks ``s`` for the inequality rows, which read only
the final state: ``A = [G S_N, J_s]`` with ``G`` the scaled rows' ``dc/dy_N`` and ``S_N = dy_N/dw``). The dense
method of :mod:`.kkt` certifies the inertia of

.. math::
    K = \begin{pmatrix} H_s & A^\top \\ A & -\delta_c I \end{pmatrix}

by Cholesky factors of ``H_rho = H_s + rho A^T A`` and of the Schur complement ``S``. Here the same certificate and
the same step (so the same iterates, up to rounding) come from an ``O(N)`` recursion: ``x^T H_rho x`` is the LQ cost

.. math::
    \tfrac12 \sum_k \begin{pmatrix} \delta y_k \\ \delta v_k \end{pmatrix}^\top W_k
    \begin{pmatrix} \delta y_k \\ \delta v_k \end{pmatrix} + \tfrac12 \delta w^\top D \delta w
    + \tfrac12 \delta y_N^\top G_{yy} \delta y_N + \tfrac12 \delta s^\top D_s \delta s
    + \tfrac12 \|\rho^{1/2} (G \delta y_N + J_s \delta s)\|^2,\qquad \delta y_{k+1} = A_k \delta y_k + B_k \delta v_k,

with ``D = Sigma + delta_w I`` and ``rho`` a vector of row weights (the certificate's scalar, or the restoration
phase's ``(Sigma_p^-1 + Sigma_n^-1)^-1``). The slacks enter only at the end: eliminating them through the
(positive) ``T = D_s + J_s^T rho J_s`` leaves the terminal cost ``P_N = G_yy + G^T rho G - C T^-1 C^T``,
``C = G^T rho J_s``. Steps that share decisions (Heun reads ``u_k`` and ``u_{k+1}``) carry the shared ones in the
state, ``X_k = (y_k, w_k)`` with ``w_k`` the entries of ``v_k`` that step ``k - 1`` also read, and the new ones
``U_k`` are the stage's decision; the first step's carried entries are a free initial block. The backward recursion

.. math::
    R_k = Q^{uu}_k + \tilde B_k^\top P_{k+1} \tilde B_k,\quad K_k = -R_k^{-1}(Q^{ux}_k + \tilde B_k^\top P_{k+1}
    \tilde A_k),\quad P_k = Q^{xx}_k + \tilde A_k^\top P_{k+1} \tilde A_k + (Q^{ux}_k + \tilde B_k^\top P_{k+1}
    \tilde A_k)^\top K_k

eliminates the stages one at a time, so ``H_rho`` is positive definite exactly when every ``R_k``, the initial
block ``P_0^{ww} + D_0`` and ``T`` are (the Schur complements of a block elimination): the certificate. A solve is
one backward pass for the linear terms and one forward pass. ``m`` is small (terminal rows), so ``S = (1 - rho
delta_c) A H_rho^{-1} A^T + delta_c I`` comes from ``m`` more solves, all at once. One step of iterative refinement
on ``K`` uses the stage-wise product ``H_s v`` (a forward and an adjoint pass) for the residual, and is taken
where IPOPT's residual ratio exceeds 1e-10 (:meth:`Riccati.solve`). The residual is measured only where the
factorisation gives a reason to doubt the solve (``Factors.check``: the certificate raised ``rho`` or regularised
``A``, or the Schur complement's factor looks ill-conditioned): measured at every step, it took a third of a vmapped
batch's time. Why stage by stage, and unrolled small Cholesky factors (:mod:`.blocks`): this package's README.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ...smallops import add_at, matmul, matvec, take
from . import blocks as bl
from .blocks import cho_solve_array as _cho_solve
from .blocks import cholesky_array as _cholesky
from .rules import CHECK_COND, RESIDUAL_RATIO_MAX, certified, condition_bound, regularized, residual_ratio

__all__ = ["StageHessian", "Riccati", "chain"]


class StageHessian(NamedTuple):
    """The scaled barrier problem's Hessian ``H`` (of ``sigma F + lambda^T g`` in ``x = (w, s)``), as stages."""

    a: jax.Array  # (N, n_y, n_y)
    b: jax.Array  # (N, n_y, q), in w
    w: jax.Array  # (N, n_y + q, n_y + q), in (y, w), times sigma
    g_yy: jax.Array  # (n_y, n_y), times sigma
    g_rows: jax.Array  # (m, n_y): the solver's scaled rows' derivative in y_N (A's w-columns are g_rows S_N)


def chain(index: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(carry, new, sel)`` positions in each row of ``index`` when the steps read ``w`` as a chain, else None.

    Step ``k >= 1`` reads at positions ``carry`` the entries step ``k - 1`` read at positions ``sel`` (the same for
    every ``k``), and at ``new`` decisions no step read before; step 0's ``carry`` entries and every step's ``new``
    ones are each decision exactly once. Disjoint steps have an empty ``carry``."""
    index = np.asarray(index)
    n_steps, q = index.shape
    if any(len(set(row)) != q for row in index.tolist()):
        return None
    shared = np.isin(index[1], index[0]) if n_steps > 1 else np.zeros(q, bool)
    carry, new = np.flatnonzero(shared), np.flatnonzero(~shared)
    sel = np.array([int(np.flatnonzero(index[0] == e)[0]) for e in index[1, carry]] if n_steps > 1 else [], int)
    for k in range(1, n_steps):
        if not (np.array_equal(np.isin(index[k], index[k - 1]), shared)
                and np.array_equal(index[k, carry], index[k - 1, sel])):
            return None
    order = np.concatenate([index[0, carry], index[:, new].ravel()])
    if order.size != n or not np.array_equal(np.sort(order), np.arange(n)):
        return None
    return carry, new, sel


class Factors(NamedTuple):
    """``H_rho`` factorised stage-wise, and what :meth:`Riccati.solve` needs besides."""

    hess: StageHessian
    d: jax.Array  # (n_x,) Sigma + delta_w
    at: list  # the augmented stage Jacobians' rows for y (blocks.py: entries (N,)), (n_y, nX); the rows for the
    bt: list  # carried decisions are static selections. (n_y, nu)
    gain: list  # (nu, nX) K_k
    chol_r: list  # (nu, nu) lower triangles of R_k's factors
    chol_0: jax.Array  # (c, c) the initial block's factor
    p0_w: jax.Array  # (c, nX) rows of P_0 for the initial block
    chol_t: jax.Array  # (n_s, n_s) T's factor
    cross: jax.Array  # (n_y, n_s) C = G^T rho J_s
    # The certificate's Schur complement (empty for the restoration phase's weighted factorisation):
    hinv_at: jax.Array  # (n_x, m) H_rho^{-1} A^T
    hinv_r1: jax.Array  # (n_x, 1) H_rho^{-1} r1 for the r1 given to factorize_with_inertia, else (n_x, 0)
    chol_s: jax.Array  # (m, m)
    rho: jax.Array
    delta_c: jax.Array
    check: jax.Array  # whether a solve measures its residual (and refines where IPOPT's residual ratio asks)


class Riccati:
    """The stage-wise Newton step for one barrier problem: ``n`` decisions read by the steps as ``index`` says
    (a :func:`chain`), ``n_s`` slacks after them."""

    def __init__(self, index: np.ndarray, n: int, n_s: int):
        links = chain(index, n)
        if links is None:
            raise ValueError("Riccati: the steps do not read the decisions as a chain (see chain())")
        self.index, self.n, self.n_s = np.asarray(index), n, n_s
        self.carry, self.new, self.sel = links
        self.c, self.nu = self.carry.size, self.new.size
        self.first, self.later = self.index[0, self.carry], self.index[:, self.new]  # where w_0 and U_k live in w
        q = self.index.shape[1]
        select = np.zeros((self.c, q))
        select[np.arange(self.c), self.sel] = 1.0  # w_{k+1} = select v_k
        self.select_c, self.select_n = select[:, self.carry], select[:, self.new]

    # ---- the stages --------------------------------------------------------------------------------------------

    def _stages(self, h: StageHessian):
        """``(A~, B~)``'s rows for ``y`` and ``(Q^xx, Q^ux, Q^uu)`` of the augmented stages ``X_k = (y_k, w_k)``,
        ``U_k``, as blocks (entries of shape (N,))."""
        n_y = h.a.shape[1]
        order = np.concatenate([np.arange(n_y), n_y + self.carry, n_y + self.new])
        w = take(take(h.w, order, axis=1), order, axis=2)
        nx = n_y + self.c
        return (bl.blocks(jnp.concatenate([h.a, take(h.b, self.carry, axis=2)], axis=2)),
                bl.blocks(take(h.b, self.new, axis=2)),
                bl.blocks(w[:, :nx, :nx]), bl.blocks(w[:, nx:, :nx]), bl.blocks(w[:, nx:, nx:]))

    def _full(self, a_top, b_top):
        """A stage's ``A~`` and ``B~``: the rows for y, then the carried decisions' static selections."""
        n_y = len(a_top[0]) - self.c
        a_rows = [[0.0] * n_y + [float(e) for e in row] for row in self.select_c]
        b_rows = [[float(e) for e in row] for row in self.select_n]
        return a_top + a_rows, b_top + b_rows

    def _terminal(self, h: StageHessian, d, jac, weights):
        """``(P_N^yy, chol T, C, ok)`` after the slacks' elimination."""
        j_s = jac[:, self.n:]
        g_w = h.g_rows * weights[:, None]
        p_yy = h.g_yy + matmul(h.g_rows.T, g_w)
        if not self.n_s:
            return p_yy, jnp.zeros((0, 0), d.dtype), jnp.zeros((p_yy.shape[0], 0), d.dtype), jnp.array(True)
        t = jnp.diag(d[self.n:]) + matmul(j_s.T, weights[:, None] * j_s)
        chol_t, ok = _cholesky(t)
        cross = matmul(g_w.T, j_s)
        return p_yy - matmul(cross, _cho_solve(chol_t, cross.T)), chol_t, cross, ok

    def factor(self, h: StageHessian, d, jac, weights, r=None) -> tuple[Factors, jax.Array, Any]:
        """``H + diag(d) + A^T diag(weights) A`` factorised, whether it is positive definite, and its solve of the
        columns ``r`` (n_x, k) when given (else None): their linear terms ride the factorisation's backward pass, so
        the solve costs one forward pass more, where :meth:`solve_h` after it would cost two."""
        at, bt, qxx, qux, quu = self._stages(h)
        n_y, c, nu, dtype = h.a.shape[1], self.c, self.nu, h.a.dtype
        p_yy, chol_t, cross, ok_t = self._terminal(h, d, jac, weights)
        p_n = jnp.zeros((n_y + c, n_y + c), dtype).at[:n_y, :n_y].set(p_yy)
        d_u = take(d, self.later)  # (N, nu)
        rhs = None if r is None else self._rhs(chol_t, cross, r, n_y)

        def backward(carry, inp):
            p, lin = carry
            a_top, b_top, qxx_k, qux_k, quu_k, du_k = inp[:6]
            a_k, b_k = self._full(a_top, b_top)
            pa, pb = bl.keep(bl.mm(p, a_k), bl.mm(p, b_k))
            r_k = bl.add(quu_k, bl.mm(bl.tr(b_k), pb))
            r_k = [[x + du_k[i] if i == j else x for j, x in enumerate(row)] for i, row in enumerate(r_k)]
            s_k = bl.keep(bl.add(qux_k, bl.mm(bl.tr(b_k), pa)))
            low, ok = bl.cholesky(r_k, du_k[0])
            gain = bl.keep(bl.scale(-1.0, bl.cho_solve(low, s_k)))
            p_new = bl.add(qxx_k, bl.mm(bl.tr(a_k), pa), bl.mm(bl.tr(s_k), gain))
            p_new = [[0.5 * (p_new[i][j] + p_new[j][i]) for j in range(len(p_new))] for i in range(len(p_new))]
            lin, ff = (lin, None) if rhs is None else self._linear_step(lin, a_k, b_k, gain, low, inp[6])
            return (p_new, lin), (gain, [row[:i + 1] for i, row in enumerate(low)], ok, ff)

        inputs = (at, bt, qxx, qux, quu, [d_u[:, i] for i in range(nu)]) + (() if rhs is None else (rhs[3],))
        lin_n = None if rhs is None else bl.blocks(rhs[2])
        (p0, lin0), (gain, chol_r, ok_r, ff) = jax.lax.scan(backward, (bl.blocks(p_n), lin_n), inputs, reverse=True)
        p0_w = bl.array(p0, d_u[:, 0][0])[n_y:]
        chol_0, ok_0 = _cholesky(p0_w[:, n_y:] + jnp.diag(take(d, self.first)))
        zeros = jnp.zeros((), dtype)
        none = jnp.zeros((jac.shape[1], 0), dtype)
        f = Factors(h, d, at, bt, gain, chol_r, chol_0, p0_w, chol_t, cross, none, none, jnp.zeros((0, 0), dtype),
                    zeros, zeros, jnp.array(True))
        solved = None if rhs is None else self._forward(f, lin0, ff, rhs, r)
        return f, jnp.all(ok_r) & ok_0 & ok_t, solved

    def _rhs(self, chol_t, cross, r, n_y):
        """What the backward pass for the columns ``r`` (n_x, k) starts from: ``(r_w, r_s, p_N, r_u)``, ``p_N`` the
        terminal linear term (the slacks eliminated) and ``r_u`` the new decisions' rows as (nu, k) blocks of
        (N,)."""
        r_w, r_s = r[:self.n], r[self.n:]
        p_s = _cho_solve(chol_t, r_s) if self.n_s else r_s  # T^{-1} r_s
        p_n = jnp.zeros((n_y + self.c, r.shape[1]), r.dtype).at[:n_y].set(matmul(cross, p_s))
        return r_w, r_s, p_n, bl.blocks(take(r_w, self.later))

    def _linear_step(self, p, a_k, b_k, gain, low, ru):
        """One stage of the backward pass for the linear terms: ``(p_k, feedforward_k)`` from ``p_{k+1}``."""
        hh = bl.keep(bl.add(bl.mm(bl.tr(b_k), p), bl.scale(-1.0, ru)))
        ff = bl.scale(-1.0, bl.cho_solve(low, hh))
        return bl.add(bl.mm(bl.tr(a_k), p), bl.mm(bl.tr(gain), hh)), ff

    def _forward(self, f: Factors, p0, ff, rhs, r):
        """The solve from the backward pass's ``p_0`` and feedforwards: the initial block, then one forward pass."""
        n, n_y = self.n, f.hess.a.shape[1]
        r_w, r_s = rhs[0], rhs[1]
        p0 = bl.array(p0, r[0, 0])
        w0 = -_cho_solve(f.chol_0, p0[n_y:] - take(r_w, self.first))
        x0 = jnp.concatenate([jnp.zeros((n_y, r.shape[1]), r.dtype), w0])

        def forward(x, inp):
            a_top, b_top, gain, ff_k = inp
            a_k, b_k = self._full(a_top, b_top)
            u = bl.keep(bl.add(bl.mm(gain, x), ff_k))
            return bl.add(bl.mm(a_k, x), bl.mm(b_k, u)), u

        x_n, u = jax.lax.scan(forward, bl.blocks(x0), (f.at, f.bt, f.gain, ff))
        u = bl.array(u, r[0, 0])  # (N, nu, k)
        dw = add_at(n, self.first, w0) + add_at(n, self.later, u)  # w_0 and U_k are disjoint entries of w
        if not self.n_s:
            return dw
        y_n = bl.array(x_n, r[0, 0])[:n_y]
        return jnp.concatenate([dw, _cho_solve(f.chol_t, r_s - matmul(f.cross.T, y_n))])

    def solve_h(self, f: Factors, r):
        """``H_rho^{-1} r`` for ``r`` (n_x,) or (n_x, k): one backward pass for the linear terms, one forward."""
        vector = r.ndim == 1
        r = r[:, None] if vector else r
        rhs = self._rhs(f.chol_t, f.cross, r, f.hess.a.shape[1])
        full_low = lambda low: [row + [0.0] * (len(low) - len(row)) for row in low]  # noqa: E731

        def backward(p, inp):
            a_top, b_top, gain, low, ru = inp
            a_k, b_k = self._full(a_top, b_top)
            return self._linear_step(p, a_k, b_k, gain, full_low(low), ru)

        p0, ff = jax.lax.scan(backward, bl.blocks(rhs[2]), (f.at, f.bt, f.gain, f.chol_r, rhs[3]), reverse=True)
        out = self._forward(f, p0, ff, rhs, r)
        return out[:, 0] if vector else out

    def hvp(self, h: StageHessian, v):
        """``H v`` (n_x,) without ``H``: the forward sensitivity of ``v``, then the adjoint (slacks: no curvature)."""
        n, n_y = self.n, h.a.shape[1]
        dv = take(v[:n], self.index)  # (N, q)

        def forward(dy, inp):
            a_k, b_k, dv_k = inp
            return matvec(a_k, dy) + matvec(b_k, dv_k), dy

        dy_n, dy = jax.lax.scan(forward, jnp.zeros(n_y, v.dtype), (h.a, h.b, dv))
        g = matvec(h.w, jnp.concatenate([dy, dv], axis=1))  # W_k (dy_k, dv_k)

        def backward(lam, inp):
            a_k, b_k, g_k = inp
            return matvec(a_k.T, lam) + g_k[:n_y], g_k[n_y:] + matvec(b_k.T, lam)

        _, per_step = jax.lax.scan(backward, matvec(h.g_yy, dy_n), (h.a, h.b, g), reverse=True)
        out = add_at(n, self.index, per_step)
        return jnp.concatenate([out, jnp.zeros(self.n_s, v.dtype)])

    # ---- the certificate (the dense method's, kkt.py) ----------------------------------------------------------

    def factorize_with_inertia(self, h: StageHessian, sigma, jac, mu, delta_w_last,
                               r1=None) -> tuple[Factors, Any, Any]:
        """IPOPT's inertia correction with :mod:`.kkt`'s certificate and schedule (:func:`~.rules.certified`):
        ``(factors, delta_w, ok)``, ``factors.check`` set where the solves should measure their residual (``rho``
        or ``delta_w`` raised, ``delta_c > 0``, or a Schur complement whose condition bound exceeds ``CHECK_COND``).

        ``r1`` (optional): the Newton system's first block of right-hand side, solved in the same sweeps as the Schur
        complement's ``m`` columns (``H_rho^{-1} (r1 + rho A^T r2) = H_rho^{-1} r1 + rho H_rho^{-1} A^T r2``), so
        that :meth:`solve` with ``presolved=True`` saves a backward and a forward pass: a tenth of a vmapped
        iteration's sweeps."""
        m, dtype = jac.shape[0], jac.dtype
        row_sq = jnp.max(jnp.sum(jac * jac, axis=1), initial=0.0) if m else jnp.zeros((), dtype)
        # The dense method's rho0 scales with max |H|; the stages' curvature is the stage-wise proxy for it.
        size = jnp.maximum(jnp.max(jnp.abs(h.w), initial=0.0), jnp.max(jnp.abs(h.g_yy), initial=0.0))
        rho0 = (1.0 + size) / jnp.maximum(row_sq, 1e-12) if m else jnp.zeros((), dtype)

        def factorize(k, delta_w, rho, delta_c):
            columns = ([jac.T] if m else []) + ([r1[:, None]] if r1 is not None else [])
            f, ok_h, solved = self.factor(h, sigma + delta_w, jac, jnp.full(m, rho, dtype),
                                          jnp.concatenate(columns, axis=1) if columns else None)
            solved = f.hinv_at if solved is None else solved
            hinv_at, hinv_r1 = solved[:, :m], solved[:, m:]
            if m:
                schur = (1.0 - rho * delta_c) * matmul(jac, hinv_at) + delta_c * jnp.eye(m, dtype=dtype)
                chol_s, ok_s = _cholesky(schur)
                ok_s = ok_s & ok_h
            else:
                chol_s, ok_s = f.chol_s, ok_h
            f = f._replace(hinv_at=hinv_at, hinv_r1=hinv_r1, chol_s=chol_s, rho=rho, delta_c=delta_c,
                           check=(k > 0) | (delta_c > 0) | (condition_bound(chol_s) > CHECK_COND))
            return f, ok_h, ok_s

        return certified(factorize, rho0, m, mu, delta_w_last, dtype)

    def _once(self, f: Factors, jac, r1, r2, presolved=False):
        if not jac.shape[0]:
            return (f.hinv_r1[:, 0] if presolved else self.solve_h(f, r1)), r2
        beta = 1.0 - f.rho * f.delta_c
        t = (f.hinv_r1[:, 0] + f.rho * matvec(f.hinv_at, r2) if presolved
             else self.solve_h(f, r1 + f.rho * matvec(jac.T, r2)))
        dl = _cho_solve(f.chol_s, (matvec(jac, t) - r2)[:, None])[:, 0]
        return t - beta * matvec(f.hinv_at, dl), dl

    def solve(self, f: Factors, jac, r1, r2, presolved=False):
        """``(d_x, d_lambda)`` solving ``K (d_x, d_lambda) = (r1, r2)``; ``presolved``: ``r1`` is the one given to
        :meth:`factorize_with_inertia`. Where ``f.check``, one step of iterative refinement where IPOPT's residual
        ratio asks: a loop of at most one pass, so that under ``vmap`` its four sweeps run only when needed."""
        dx, dl = self._once(f, jac, r1, r2, presolved)

        def refine(c):
            _, dx_, dl_ = c
            res1 = self.hvp(f.hess, dx_) + f.d * dx_ + matvec(jac.T, dl_) - r1
            res2 = matvec(jac, dx_) - f.delta_c * dl_ - r2
            needed = residual_ratio((r1, r2), (dx_, dl_), (res1, res2)) > RESIDUAL_RATIO_MAX
            cx, cl = self._once(f, jac, res1, res2)
            return jnp.array(False), jnp.where(needed, dx_ - cx, dx_), jnp.where(needed, dl_ - cl, dl_)

        _, dx, dl = jax.lax.while_loop(lambda c: c[0], refine, (f.check, dx, dl))
        return dx, dl

    # ---- the restoration phase's system ------------------------------------------------------------------------

    def factorize_weighted(self, h: StageHessian, d, jac, weights, delta_w_last):
        """``H + diag(d) + delta_w I + A^T diag(weights) A`` positive definite for the least ``delta_w`` of IPOPT's
        schedule (the restoration phase's exact inertia test): ``(factors, delta_w, ok)``."""
        return regularized(lambda delta_w: self.factor(h, d + delta_w, jac, weights)[:2], delta_w_last, d.dtype)

    def solve_weighted(self, f: Factors, jac, weights, r1, r2):
        """``(d_x, d_lambda)`` of ``[H_s A^T; A -diag(1/weights)] (d_x, d_lambda) = (r1, r2)``, one refinement."""
        def once(s1, s2):
            dx = self.solve_h(f, s1 + matvec(jac.T, weights * s2))
            return dx, weights * (matvec(jac, dx) - s2)

        dx, dl = once(r1, r2)
        cx, cl = once(self.hvp(f.hess, dx) + f.d * dx + matvec(jac.T, dl) - r1,
                      matvec(jac, dx) - dl / weights - r2)
        return dx - cx, dl - cl
