r"""The augmented Lagrangian's derivatives and the KKT test at one primal-dual point.

With equalities ``h(w) = c_E(w) - c^l_E = 0`` and one-sided inequalities ``g(w) <= 0`` (``c_U - c^u_U`` for each finite
upper bound and ``c^l_L - c_L`` for each finite lower bound of the remaining rows), all on the scaled rows ``r * c``
(:mod:`.scaling`), ``L_rho`` is ``Extragradient``'s augmented Lagrangian of ``sigma F``. The multiplier estimates

.. math::
    y = \big(\lambda + \rho h,\ \max(0, \mu + \rho g)\big), \qquad \nabla_w L_\rho = \sigma \nabla F + J^\top y

(exactly), and the inequalities' ascent direction is ``dL/dmu = max(g, -mu / rho)`` (``g`` when ``rho = 0``), which
cannot drive ``mu`` negative by more than the step. The KKT residual, judged on the rows *as given* and in ``w``
(whatever the scalings, so the test means the same with or without them), is the largest of

* stationarity ``|| w - clip(w - grad_w L_rho, lo, hi) ||_inf`` (the projected gradient: active bounds count);
* feasibility: the largest constraint violation (``|h|``, ``g``; bounds hold by construction);
* complementarity ``max_i |min(y_i, -g_i)|`` over the inequalities;

and ``+inf`` at a non-finite point, so NaNs never pass ``tol``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .box import Box
from .penalty import PenaltySchedule
from .scaling import Scales

__all__ = ["Lagrangian", "Point"]


class Point(NamedTuple):
    """The (augmented) Lagrangian's derivatives at one primal-dual point."""

    grad_p: jax.Array  # descent direction's gradient for the primal parameters p
    grad_duals: tuple  # -dL/d(lambda, mu_upper, mu_lower): "gradients" whose descent is ascent
    kkt: jax.Array  # max(stationarity, violation, complementarity)
    violation: jax.Array
    multipliers: jax.Array  # the estimates y, one per NLP constraint, IPOPT's sign convention


class Lagrangian(NamedTuple):
    """The static pieces of one scaled problem that :meth:`evaluate` needs (host arrays; the row indices of
    :func:`~myriad.runtime.solvers.base.split_constraints`)."""

    f: Callable
    c_fn: Callable | None
    m: int
    eq_idx: np.ndarray
    up_idx: np.ndarray
    lo_idx: np.ndarray
    c_lo: np.ndarray
    c_up: np.ndarray
    box: Box
    penalty: PenaltySchedule

    def evaluate(self, p, duals, rho, data, scales: Scales) -> Point:
        """The derivatives, the KKT residual and the multiplier estimates at ``(to_w(p), duals)`` for penalty ``rho``.

        Returns ``grad_p`` (the chain rule through the box), the dual "gradients" ``-(h, ascent_u, ascent_l) * rho /
        rho_0`` in the scaled rows (their descent is ascent, in units of the penalty), and ``y`` in the rows as given
        but for the scaled objective ``sigma F`` (the solve divides by ``sigma`` to report them).
        """
        f, c_fn, m, box = self.f, self.c_fn, self.m, self.box
        eq_idx, up_idx, lo_idx, c_lo, c_up = self.eq_idx, self.up_idx, self.lo_idx, self.c_lo, self.c_up
        lam, mu_u, mu_l = duals
        sigma, r = scales.sigma, scales.row
        w = box.to_w(p)
        if m:
            (_, c), vjp = jax.vjp(lambda w_: (f(w_, data), c_fn(w_, data)), w)
            h, g_u, g_l = c[eq_idx] - c_lo[eq_idx], c[up_idx] - c_up[up_idx], c_lo[lo_idx] - c[lo_idx]
            # The Lagrangian is built on the scaled rows r * c; feasibility and complementarity below are judged on
            # the rows as given.
            hs, g_us, g_ls = r[eq_idx] * h, r[up_idx] * g_u, r[lo_idx] * g_l
            # First-order multiplier estimates: grad_w L_rho = sigma grad F + J^T y exactly (y in the given rows).
            y_eq, y_u, y_l = lam + rho * hs, jnp.maximum(mu_u + rho * g_us, 0.0), jnp.maximum(mu_l + rho * g_ls, 0.0)
            y_eq, y_u, y_l = r[eq_idx] * y_eq, r[up_idx] * y_u, r[lo_idx] * y_l
            y = jnp.zeros(m, dtype=w.dtype).at[eq_idx].add(y_eq).at[up_idx].add(y_u).at[lo_idx].add(-y_l)
            (grad_w,) = vjp((sigma, y))
            # dL_rho/dmu = (max(0, mu + rho g) - mu) / rho = max(g, -mu / rho); g itself when rho = 0.
            safe = jnp.maximum(rho, 1e-300)
            ascent_u = jnp.where(rho > 0, jnp.maximum(g_us, -mu_u / safe), g_us)
            ascent_l = jnp.where(rho > 0, jnp.maximum(g_ls, -mu_l / safe), g_ls)
            # Dual steps in units of the penalty: they grow with it, as in the method of multipliers.
            ratio = self.penalty.dual_ratio(rho, w.dtype)
            grad_duals = (-hs * ratio, -ascent_u * ratio, -ascent_l * ratio)
            g_all, y_ineq = jnp.concatenate([g_u, g_l]), jnp.concatenate([y_u, y_l])
            violation = jnp.max(jnp.concatenate([jnp.zeros(1), jnp.abs(h), g_all]))
            complementarity = jnp.max(jnp.concatenate([jnp.zeros(1), jnp.abs(jnp.minimum(y_ineq, -g_all))]))
        else:
            grad_w = sigma * jax.grad(f)(w, data)
            y = jnp.zeros(0, dtype=w.dtype)
            grad_duals = (jnp.zeros(0, dtype=w.dtype),) * 3
            violation = complementarity = jnp.zeros((), dtype=w.dtype)
        # Stationarity in w (not in the column-scaled v = w / d, where it would be looser by d): the same test
        # whatever the scaling.
        stationarity = jnp.max(jnp.abs(w - jnp.clip(w - grad_w, box.lo, box.hi)), initial=0.0)
        kkt = jnp.maximum(jnp.maximum(stationarity, violation), complementarity)
        kkt = jnp.where(jnp.isfinite(kkt) & jnp.all(jnp.isfinite(w)), kkt, jnp.inf)
        return Point(grad_w * box.dw_dp(p), grad_duals, kkt, violation, y)
