r"""The barrier problem's derivatives stage by stage, for the block-tridiagonal Newton step (:mod:`.banded`).

The barrier problem's variables are ``x = (w, s)`` (a slack for each non-equality row) and its rows the NLP's in the
solver's order (:class:`~.problem.Layout`). A slack joins its row's stage (a border row's slack is a border
variable), so the NLP's stage structure carries over. The derivatives come from the colour seeds of
:func:`~.stage_blocks.stage_derivatives` applied to the unscaled residuals ``c(w)[rows] - b + slack_sign s``: the
slacks' Jacobian columns (``slack_sign``) and their zero Hessian come out of the same pass, and IPOPT's scaling
(``sigma`` on the objective, ``D`` on the rows) multiplies the blocks afterwards, as the dense path scales its
matrices.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from . import stage_blocks as sb
from .banded import Banded, StageJacobian

__all__ = ["StageProblem"]


class StageProblem:
    """Stage-wise derivatives and Newton step of one :class:`~.problem.Layout` (host index arrays, built once)."""

    def __init__(self, layout: Any):
        structure = layout.problem.stage_structure
        self.layout = layout
        var_stage = np.concatenate([structure.var_stage, structure.row_stage[layout.ineq]])
        row_stage = structure.row_stage[layout.rows]
        self.index = sb.StageIndex.from_stages(var_stage, row_stage, structure.n_stages)
        self.banded = Banded(self.index, layout.n_x, layout.m)
        self._derivatives = sb.stage_derivatives(self._residuals, self.index)
        ix = self.index
        # Which stage slots hold an NLP variable (not a slack, not padding): the rows' scaling reads only those.
        self.core_w = (ix.var_index >= 0) & (ix.var_index < layout.n)
        self.border_w = ix.border_vars < layout.n

    @staticmethod
    def applies(problem: Any) -> bool:
        """Whether the NLP has a stage structure (collocation, multiple shooting)."""
        return problem.stage_structure is not None

    def _residuals(self, x, data):
        """``(F(w), c(w)[rows] - b + slack_sign s)``: the barrier problem's functions before scaling."""
        lay = self.layout
        f, c = lay.problem.evaluate(x[: lay.n], data)
        s = jnp.concatenate([jnp.zeros(lay.eq.size, x.dtype), x[lay.n:]])
        return f, jnp.reshape(c, (-1,))[lay.rows] - lay.b + lay.slack_sign * s

    def derivatives(self, w, y, data, objective_weight):
        """The :meth:`~.problem.Layout.derivatives` tuple, the Jacobian and Hessian as one :class:`StageBlocks`
        (unscaled, in ``x``; the slacks at 0, where ``c(w)`` is read off the residuals)."""
        lay = self.layout
        x = jnp.concatenate([w, jnp.zeros(lay.n_s, w.dtype)])
        y_rows = y[lay.rows] if lay.m else y
        f, g0, grad_x, blocks = self._derivatives(x, y_rows, data, objective_weight)
        c = jnp.zeros(lay.m, w.dtype).at[lay.rows].set(g0 + lay.b) if lay.m else g0
        return f, c, grad_x[: lay.n], blocks, blocks

    def row_max(self, blocks: sb.StageBlocks):
        """``max_j |dc_i/dw_j|`` for each row in the solver's order (the slacks' columns left out): IPOPT's scaling."""
        ix = self.index
        w_prev = jnp.concatenate([jnp.zeros_like(self.core_w[:1]), self.core_w[:-1]])
        w_next = jnp.concatenate([self.core_w[1:], jnp.zeros_like(self.core_w[:1])])

        def masked(block, mask):
            return jnp.max(jnp.where(mask[:, None, :], jnp.abs(block), 0.0), axis=2, initial=0.0)

        core = jnp.maximum(jnp.maximum(masked(blocks.j_prev, w_prev), masked(blocks.j_diag, self.core_w)),
                           masked(blocks.j_next, w_next))
        core = jnp.maximum(core, jnp.max(jnp.where(self.border_w, jnp.abs(blocks.j_border), 0.0), axis=2,
                                          initial=0.0))
        border = jnp.maximum(
            jnp.max(jnp.where(self.core_w[None], jnp.abs(blocks.b_core), 0.0), axis=(1, 2), initial=0.0),
            jnp.max(jnp.where(self.border_w, jnp.abs(blocks.b_bb), 0.0), axis=1, initial=0.0))
        return sb.scatter_rows(ix, core, border)

    def scaled(self, blocks: sb.StageBlocks, sigma, row_scale) -> tuple[sb.StageBlocks, StageJacobian]:
        """The scaled barrier problem's Hessian (``sigma`` times) and Jacobian (rows times ``D``), as blocks."""
        ix = self.index
        d_core = sb.gather_rows(ix, row_scale)[:, :, None]
        d_border = row_scale[ix.border_rows]
        scaled = blocks._replace(
            h_diag=sigma * blocks.h_diag, h_next=sigma * blocks.h_next, h_border=sigma * blocks.h_border,
            h_bb=sigma * blocks.h_bb, j_prev=d_core * blocks.j_prev, j_diag=d_core * blocks.j_diag,
            j_next=d_core * blocks.j_next, j_border=d_core * blocks.j_border,
            b_core=d_border[:, None, None] * blocks.b_core, b_bb=d_border[:, None] * blocks.b_bb)
        return scaled, StageJacobian(scaled, ix)
