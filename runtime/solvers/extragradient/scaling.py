r"""Per-solve scale factors measured at the start (``Extragradient``'s "Scaling"): the objective factor ``sigma``,
column ``d`` and row ``r`` scales, computed inside the jitted solve from the start ``w0`` (so they may depend on
``data``). All three are changes of variables or units: the KKT test, the violation and the reported multipliers are
the same with or without them.

.. math::
    \sigma = \min\big(1,\ 100 / \lVert d \odot \nabla F(w_0) \rVert_\infty\big),\qquad
    d_j = \max(|w_{0,j}|, 10^{-4}),\qquad
    r_i = \operatorname{clip}\Big(1 \big/ \max_j |\partial c_i / \partial w_j(w_0)|\, d_j,\ 10^{-4}, 10^{4}\Big)

with ``sigma = 1`` where that gradient is not finite, ``d_j = 1`` where ``w_{0,j}`` is 0 or not finite or ``j`` is
boxed (the sigmoid's parameter is not ``w``), ``r_i = 1`` where the maximum is 0 or not finite, and ``d = r = 1`` with
``scaling="bounds"``. Measurements: docs/notes/extragradient-tuning.md ("Column and row scaling", "Objective
scaling").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["Scales", "make_scales"]

# IPOPT's nlp_scaling_max_gradient: the objective is scaled so its gradient at the start is at most this.
_MAX_START_GRADIENT = 100.0
# scaling="guess": start magnitudes below this (in the NLP's scaled units) are raised to it, so that a start of 1e-12
# does not freeze a variable; an exact zero carries no magnitude at all and keeps the nominal scale 1.
_MIN_COLUMN_SCALE = 1e-4
# scaling="guess": limits of the row factors (IPOPT's gradient-based rule only ever scales down, to 1e-8; rows here are
# scaled up as well, which is what a defect row of a tiny state needs, so both directions are bounded).
_ROW_SCALE_LIMITS = (1e-4, 1e4)
# Columns of the start Jacobian computed per JVP batch when measuring the rows (memory: this many constraint vectors).
_JACOBIAN_CHUNK = 32


class Scales(NamedTuple):
    """Per-solve scale factors, computed from the start point inside the jitted solve (so they may depend on data)."""

    sigma: jax.Array  # objective factor: the solver minimises sigma F
    column: jax.Array  # d (n,): the step rules act on v = w / d
    row: jax.Array  # r (m,): the Lagrangian and the dual steps use r * c


def _row_max_abs(c_fn: Callable, w: jax.Array, d: jax.Array, data: Any, m: int) -> jax.Array:
    """``max_j |dc_i/dw_j| d_j`` for every row ``i``, from one JVP per column in chunks of ``_JACOBIAN_CHUNK``.

    A scan over chunks keeps the memory at ``_JACOBIAN_CHUNK`` constraint vectors instead of the dense Jacobian (which,
    under ``vmap`` over a large batch, would be the largest array of the whole solve). It runs once per solve.
    """
    n = w.shape[0]
    chunks = -(-n // _JACOBIAN_CHUNK)

    def columns(carry, k):
        idx = k * _JACOBIAN_CHUNK + jnp.arange(_JACOBIAN_CHUNK)
        basis = (idx[:, None] == jnp.arange(n)[None, :]).astype(w.dtype) * d  # rows past n are zero
        jd = jax.vmap(lambda v: jax.jvp(lambda w_: c_fn(w_, data), (w,), (v,))[1])(basis)
        return jnp.maximum(carry, jnp.max(jnp.abs(jd), axis=0)), None

    out, _ = jax.lax.scan(columns, jnp.zeros(m, dtype=w.dtype), jnp.arange(chunks))
    return out


def make_scales(f: Callable, c_fn: Callable | None, w0: jax.Array, data: Any, dtype: Any, *, boxed: jax.Array,
                m: int, from_guess: bool, scale_objective: bool) -> Scales:
    """The :class:`Scales` at the start ``w0`` (in ``w``, after the box) of the scaled objective ``f`` and constraints
    ``c_fn`` (unused when ``m == 0``), as in the module docstring; ``boxed``: the variables behind the sigmoid."""
    n = w0.shape[0]
    ones_n, ones_m = jnp.ones(n, dtype), jnp.ones(m, dtype)
    if from_guess:
        a = jnp.abs(w0)
        column = jnp.where(jnp.isfinite(a) & (a > 0), jnp.maximum(a, _MIN_COLUMN_SCALE), 1.0)
        # The sigmoid's parameter p is not w: its scale is the logit's, leave it alone.
        column = jnp.where(boxed, 1.0, column).astype(dtype)
    else:
        column = ones_n
    if from_guess and m:
        norms = _row_max_abs(c_fn, w0, column, data, m)
        row = jnp.where(jnp.isfinite(norms) & (norms > 0), jnp.clip(1.0 / norms, *_ROW_SCALE_LIMITS), 1.0)
        row = row.astype(dtype)
    else:
        row = ones_m
    g0 = jnp.max(jnp.abs(column * jax.grad(f)(w0, data)), initial=0.0)
    sigma = jnp.where(jnp.isfinite(g0), jnp.minimum(1.0, _MAX_START_GRADIENT / jnp.maximum(g0, 1e-300)), 1.0)
    sigma = sigma if scale_objective else jnp.ones_like(sigma)
    return Scales(sigma.astype(dtype), column, row)
