r"""The variable box ``lo <= w <= hi``: projection, or a sigmoid reparametrisation of the doubly bounded variables
(``Extragradient``'s "Bounds"). The solver's primal iterate is ``p`` with ``w = to_w(p)``; with the projection
``p = w``. Measurements: docs/notes/extragradient-tuning.md ("Bounds").
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Box", "make_box"]

# Where the sigmoid starts a variable that sits on its bound: logit(1e-2) = -4.6 keeps sigma' ~ 1e-2, not 0.
_SIGMOID_MARGIN = 1e-2


class Box(NamedTuple):
    """The box in scaled variables (``lo``, ``hi``, possibly infinite) and the map ``p -> w``: ``boxed`` variables go
    through the sigmoid (none with ``bounds="projection"``), ``width`` and ``base`` are ``u - l`` and ``l`` there."""

    lo: jax.Array
    hi: jax.Array
    boxed: jax.Array
    width: jax.Array
    base: jax.Array
    sigmoid: bool

    def to_w(self, p: jax.Array) -> jax.Array:
        r"""``w = l + (u - l) sigmoid(p)`` where boxed, ``p`` elsewhere; clipped to the box.

        The clip only removes rounding: ``l + (u - l) * sigmoid(p)`` can exceed ``u`` by an ulp."""
        return jnp.clip(jnp.where(self.boxed, self.base + self.width * jax.nn.sigmoid(p), p), self.lo, self.hi)

    def dw_dp(self, p: jax.Array) -> jax.Array:
        r"""The diagonal Jacobian of :meth:`to_w`: ``(u - l) s (1 - s)`` with ``s = sigmoid(p)`` where boxed, else 1
        (so ``grad_p = grad_w * dw_dp(p)``)."""
        s = jax.nn.sigmoid(p)
        return jnp.where(self.boxed, self.width * s * (1.0 - s), 1.0)

    def from_w(self, w: jax.Array) -> jax.Array:
        r"""The inverse of :meth:`to_w`: ``p = logit((w - l) / (u - l))`` where boxed, the clip of ``w`` elsewhere.

        The fraction is kept ``_SIGMOID_MARGIN`` (1e-2) inside the box, like IPOPT's ``bound_push``: a start on the
        bound would have ``sigmoid' = 0`` and never move."""
        frac = jnp.clip((w - self.base) / self.width, _SIGMOID_MARGIN, 1.0 - _SIGMOID_MARGIN)
        return jnp.where(self.boxed, jnp.log(frac) - jnp.log1p(-frac), jnp.clip(w, self.lo, self.hi))

    def project(self, p: jax.Array) -> jax.Array:
        """The projection onto the feasible ``p``: the clip to the box of every variable not boxed (the sigmoid's
        ``p`` is unconstrained)."""
        return jnp.where(self.boxed, p, jnp.clip(p, self.lo, self.hi))

    def start(self, w0: jax.Array) -> jax.Array:
        """The starting parameters for a start ``w0``: :meth:`from_w` with the sigmoid, the clip of ``w0`` without."""
        return self.from_w(w0) if self.sigmoid else jnp.clip(w0, self.lo, self.hi)


def make_box(w_lower: np.ndarray, w_upper: np.ndarray, bounds: str) -> Box:
    """The :class:`Box` for the scaled bounds ``w_lower, w_upper`` (host arrays) and ``bounds`` (``"projection"`` or
    ``"sigmoid"``). With the sigmoid, exactly the variables with both bounds finite are boxed."""
    n = np.shape(w_lower)[0]
    lo, hi = jnp.asarray(w_lower), jnp.asarray(w_upper)
    sigmoid = bounds == "sigmoid"
    boxed = jnp.asarray(np.isfinite(w_lower) & np.isfinite(w_upper)) if sigmoid else jnp.zeros(n, bool)
    width = jnp.where(boxed, hi - lo, 1.0)
    base = jnp.where(boxed, lo, 0.0)
    return Box(lo, hi, boxed, width, base, sigmoid)
