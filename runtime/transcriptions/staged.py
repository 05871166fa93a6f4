r"""Exact first and second derivatives of a rollout's Lagrangian, stage by stage (the second-order adjoint).

A shooting NLP's functions reach the decisions ``z`` through one rollout

.. math::
    y_{k+1} = \Phi_k(y_k, v_k),\quad v_k = z[\text{index}_k],\quad k = 0..N-1;\qquad (F, c) = G(y_N),

so the Lagrangian ``l^T G(y_N)`` with ``l = (1, lambda)`` has the Hessian

.. math::
    H = \sum_k P_k^T D_k P_k + P_k^T M_k S_k + S_k^T M_k^T P_k,\qquad
    D_k = W^{vv}_k + B_k^T Q_{k+1} B_k,\quad M_k = W^{vy}_k + B_k^T Q_{k+1} A_k,

where ``A_k, B_k`` are the step's Jacobians, ``S_k = dy_k/dz`` the forward sensitivities
(``S_{k+1} = A_k S_k + B_k P_k``), ``mu`` the adjoint (``mu_N = G_y^T l``, ``mu_k = A_k^T mu_{k+1}``),
``W_k = \nabla^2 (mu_{k+1}^T \Phi_k)`` the step's curvature and ``Q`` the backward recursion
``Q_N = \nabla^2 (l^T G)``, ``Q_k = W^{yy}_k + A_k^T Q_{k+1} A_k`` (substitute ``S_{k+1}`` and telescope).

Why: forward over reverse through the rollout puts the step's whole second-order program inside two sequential
loops, and on the CPU a loop's cost is its kernels per iteration. Here the step's derivatives are taken for all ``k``
at once (``vmap``), and the loops left (adjoint, ``Q``, ``S``) hold one or two small matrix products each.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..smallops import add_at, matmul, matvec, take

__all__ = ["Stages", "stage_derivatives", "staged_derivatives"]


class Stages(NamedTuple):
    """The rollout's linearisation and the Lagrangian's curvature, stage by stage (see :func:`stage_derivatives`)."""

    a: Any  # (N, n_y, n_y) A_k = d Phi_k / d y_k
    b: Any  # (N, n_y, q) B_k = d Phi_k / d v_k
    w: Any  # (N, n_y + q, n_y + q) W_k, the Hessian of mu_{k+1}^T Phi_k in (y_k, v_k)
    g_yy: Any  # (n_y, n_y) the Hessian of l^T G at y_N
    g_c: Any  # (m, n_y) dc/dy_N: the rows' Jacobian is g_c S_N


def staged_derivatives(
    step: Callable[[Any, Any, Any], Any],
    terminal: Callable[[Any], tuple[Any, Any]],
    y0: Any,
    z: Any,
    index: Any,
    lam: Any,
    objective_weight: Any = 1.0,
    hessian: Any = True,
) -> tuple[Any, Any, Any, Any, Any]:
    """``(F, c, dF/dz, dc/dz, Hessian of sigma F + lam^T c)`` where ``(F, c) = terminal(y_N)``, ``sigma`` the
    ``objective_weight`` (IPOPT's ``obj_factor``: 0 in its restoration phase).

    Args:
        step: ``(k, y_k, v_k) -> y_{k+1}``, traceable in ``k`` (an int32 scalar); y0 the initial state.
        terminal: ``y_N -> (F, c)``, F a scalar and c a vector (possibly empty), lam its multipliers.
        z: the decisions (n_z,); every one must be read by some step (nothing else reaches ``terminal``).
        index: (N, q) integer NumPy array (static): step k reads ``v_k = z[index[k]]``; steps may share entries.
        hessian: True, or a traced boolean: where false the Hessian is zeros and its second-order part is skipped
            (a ``lax.cond``), so that one compiled program serves first-order calls at first-order cost (IPOPT's).
    """
    index = np.asarray(index)  # static: its gathers and scatters are strided slices (smallops)
    n_z, n_y = z.shape[0], y0.shape[0]
    r = _rollout(step, terminal, y0, z, index)
    grad, jac = _first_order(r, z, index)

    def second_order():
        g_yy, w = _curvature(step, r, lam, objective_weight)
        a, b = r.a, r.b
        w_yy, w_vy, w_vv = w[:, :n_y, :n_y], w[:, n_y:, :n_y], w[:, n_y:, n_y:]
        _, q_next = jax.lax.scan(lambda q_, inp: (inp[1] + inp[0].T @ q_ @ inp[0], q_), g_yy, (a, w_yy),
                                 reverse=True)  # q_next[k] = Q_{k+1}
        c_in = jax.vmap(lambda b_k, idx: jnp.zeros((n_y, n_z), z.dtype).at[:, idx].add(b_k))(b, index)  # B_k P_k
        _, s = jax.lax.scan(lambda s_, inp: (inp[0] @ s_ + inp[1], s_), jnp.zeros((n_y, n_z), z.dtype),
                            (a, c_in))  # s[k] = S_k
        bq = jnp.einsum("kai,kab->kib", b, q_next)
        d = w_vv + jnp.einsum("kib,kbj->kij", bq, b)
        m_s = jnp.einsum("kij,kjn->kin", w_vy + jnp.einsum("kib,kbj->kij", bq, a), s)  # M_k S_k: (N, q, n_z)
        rows = jnp.zeros((n_z, n_z), z.dtype).at[index].add(m_s)
        diag = jnp.zeros((n_z, n_z), z.dtype).at[index[:, :, None], index[:, None, :]].add(d)
        full = diag + 2.0 * rows  # H without the transposed cross terms; symmetrised in one sum (exactly symmetric)
        return 0.5 * (full + full.T)

    if hessian is True:
        hess = second_order()
    else:
        hess = jax.lax.cond(hessian, second_order, lambda: jnp.zeros((n_z, n_z), z.dtype))
    return r.values[0], r.values[1:], grad, jac, hess


class _Rollout(NamedTuple):
    ks: Any  # (N,) step numbers
    ys: Any  # (N, n_y) y_k, k < N
    v: Any  # (N, q) v_k
    y_n: Any
    a: Any  # (N, n_y, n_y)
    b: Any  # (N, n_y, q)
    values: Any  # (1 + m,) (F, c)
    g_jac: Any  # (1 + m, n_y) dG/dy_N
    adj: Any  # (N, 1 + m, n_y) adj[k] = Lambda_{k+1}
    stacked: Callable  # y_N -> (F, c) as one vector


def _rollout(step, terminal, y0, z, index) -> _Rollout:
    """The rollout, the steps' Jacobians and the adjoints of F and of each row (``Lambda_k = Lambda_{k+1} A_k``, in
    one pass): everything first order."""
    ks = jnp.arange(index.shape[0], dtype=jnp.int32)
    v = take(z, index)

    def forward(y, inputs):
        k, vk = inputs
        return step(k, y, vk), y

    y_n, ys = jax.lax.scan(forward, y0, (ks, v))
    a, b = jax.vmap(jax.jacfwd(step, argnums=(1, 2)))(ks, ys, v)

    def stacked(y):
        f_, c_ = terminal(y)
        return jnp.concatenate([jnp.reshape(f_, (1,)), c_])

    g_jac = jax.jacfwd(stacked)(y_n)
    _, adj = jax.lax.scan(lambda l_, a_k: (matmul(l_, a_k), l_), g_jac, a, reverse=True)
    return _Rollout(ks, ys, v, y_n, a, b, stacked(y_n), g_jac, adj, stacked)


def _first_order(r: _Rollout, z, index):
    """The gradient and the Jacobian: row ``i`` of ``dG/dv_k`` is ``Lambda^i_{k+1} B_k``, scattered to ``z`` by
    ``index`` (``O(N n_y (1 + m))``, without the ``n_y x n_z`` forward sensitivities)."""
    per_step = matmul(r.adj, r.b)  # (N, 1 + m, q)
    dz = add_at(z.shape[0], index, jnp.moveaxis(per_step, 1, 0), axis=1)
    return dz[0], dz[1:]


def _curvature(step, r: _Rollout, lam, objective_weight):
    """``(G_yy, W)``: the Hessian of ``l^T G`` at ``y_N`` and each step's curvature ``W_k``, the Hessian of
    ``mu_{k+1}^T Phi_k`` in ``(y_k, v_k)``, with the Lagrangian's adjoint ``mu`` the weighted sum of the adjoints."""
    weights = jnp.concatenate([jnp.reshape(jnp.asarray(objective_weight, r.y_n.dtype), (1,)), lam])
    n_y = r.y_n.shape[0]
    g_yy = jax.hessian(lambda y: weights @ r.stacked(y))(r.y_n)
    mu = matvec(jnp.swapaxes(r.adj, 1, 2), weights)  # mu[k] = mu_{k+1}

    def curvature(k, y, vk, mu_k):
        return jax.hessian(lambda yv: jnp.sum(mu_k * step(k, yv[:n_y], yv[n_y:])))(jnp.concatenate([y, vk]))

    return g_yy, jax.vmap(curvature)(r.ks, r.ys, r.v, mu)


def stage_derivatives(
    step: Callable[[Any, Any, Any], Any],
    terminal: Callable[[Any], tuple[Any, Any]],
    y0: Any,
    z: Any,
    index: Any,
    lam: Any,
    objective_weight: Any = 1.0,
) -> tuple[Any, Any, Any, Any, Stages]:
    r"""``(F, c, dF/dz, dc/dz, Stages)``: :func:`staged_derivatives` with the Hessian left as its stages.

    The Hessian of ``sigma F + lam^T c`` in ``z`` is that of the linear-quadratic problem (Dunn & Bertsekas 1989)

    .. math::
        \tfrac12 \sum_k \begin{pmatrix} \delta y_k \\ \delta v_k \end{pmatrix}^\top W_k
        \begin{pmatrix} \delta y_k \\ \delta v_k \end{pmatrix} + \tfrac12 \delta y_N^\top G_{yy} \delta y_N,
        \qquad \delta y_{k+1} = A_k \delta y_k + B_k \delta v_k,\quad \delta y_0 = 0,\quad \delta v_k =
        \delta z[\text{index}_k],

    which a Riccati recursion factorises in ``O(N)`` (``solvers/interior_point/riccati.py``), with no ``n_z x n_z``
    Hessian formed (the first derivatives: :func:`_first_order`). Arguments as :func:`staged_derivatives`.
    """
    index = np.asarray(index)  # static: its gathers and scatters are strided slices (smallops)
    r = _rollout(step, terminal, y0, z, index)
    grad, jac = _first_order(r, z, index)
    g_yy, w = _curvature(step, r, lam, objective_weight)
    return r.values[0], r.values[1:], grad, jac, Stages(r.a, r.b, w, g_yy, r.g_jac[1:])
