"""The stage structure of a transcribed NLP: which stage of the time chain each variable and each row belongs to.

Every direct transcription but single shooting is a chain of stages: the variables and rows of stage k couple only
to those of stages k - 1 and k + 1 (collocation defects, shooting continuity), apart from a few BORDER variables
(a free final time reads every stage) and BORDER rows (the terminal fixed-value rows). A solver that knows this can
factorise its Newton system block by block, in time linear in the number of stages (issue 32; the interface is
/work/coord/stages_spec.md, its blocks :mod:`~myriad.runtime.solvers.interior_point.stage_blocks`).

Convention, so that each stage's rows have full row rank in the stage's own variables (a block factorisation pivots
on them): a defect or continuity row between nodes k and k + 1 is in stage k + 1, where it holds x_{k+1} with a
near-identity coefficient; stage k holds node k's state (x_0 is data, not a variable) and the controls first used
there; path rows at node k are in stage k (a Hermite-Simpson midpoint row and the midpoint control u_{k+1/2} in
stage k + 1); terminal fixed-value rows are border rows; a free final time is a border variable.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["BORDER", "StageStructure", "collocation_structure", "multiple_shooting_structure"]

BORDER = -1  # the stage of a border variable or row


def _stages(name: str, values, n_stages: int) -> np.ndarray:
    """``values`` as a read-only (k,) int64 array of stages in [-1, n_stages - 1] (ValueError naming ``name``)."""
    array = np.asarray(values)
    if array.ndim != 1 or not (array.size == 0 or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"StageStructure: {name} must be a flat array of integer stages, got shape {array.shape} "
                         f"and dtype {array.dtype}")
    array = array.astype(np.int64)
    bad = np.flatnonzero((array < BORDER) | (array >= n_stages))
    if bad.size:
        raise ValueError(f"StageStructure: {name}[{bad[0]}] = {array[bad[0]]} is not a stage: stages are "
                         f"0..{n_stages - 1}, or {BORDER} for the border")
    array.setflags(write=False)
    return array


@dataclasses.dataclass(frozen=True, eq=False)
class StageStructure:
    """The stage of each NLP variable and constraint row (host NumPy; nothing here is traced).

    The promise, for core variables and rows (stage >= 0): a Jacobian entry (row r, variable j) is zero unless
    ``|row_stage[r] - var_stage[j]| <= 1``, and a Hessian entry of F + y^T c between variables i and j is zero unless
    ``|var_stage[i] - var_stage[j]| <= 1``. Border variables and rows (stage -1) may couple to anything.

    Attributes:
        var_stage: (n,) int64, each variable's stage 0..K-1, or -1 for a border variable.
        row_stage: (m,) int64, each row's stage, or -1 for a border row.
        n_stages: K.
    """

    var_stage: np.ndarray
    row_stage: np.ndarray
    n_stages: int

    def __post_init__(self):
        if isinstance(self.n_stages, bool) or not isinstance(self.n_stages, (int, np.integer)) or self.n_stages < 1:
            raise ValueError(f"StageStructure: n_stages must be a positive integer, got {self.n_stages!r}")
        object.__setattr__(self, "n_stages", int(self.n_stages))
        object.__setattr__(self, "var_stage", _stages("var_stage", self.var_stage, self.n_stages))
        object.__setattr__(self, "row_stage", _stages("row_stage", self.row_stage, self.n_stages))

    @property
    def n_variables(self) -> int:
        return int(self.var_stage.size)

    @property
    def n_constraints(self) -> int:
        return int(self.row_stage.size)

    def check_jacobian(self, rows, cols) -> None:
        """Check that the Jacobian pattern ``(rows, cols)`` (e.g. ``NLP.jacobian_sparsity``) keeps the promise.

        Raises:
            ValueError: an entry outside the sizes, or one coupling a core row and a core variable more than one
                stage apart (the first such is named, with the stages and the count).
        """
        rows, cols = self._entries("Jacobian", rows, self.n_constraints, "row", cols)
        self._check_band("Jacobian", "row", self.row_stage[rows], rows, cols)

    def check_hessian(self, rows, cols) -> None:
        """Check that the Hessian pattern ``(rows, cols)`` (the non-zeros of the Hessian of F + y^T c, variables
        both) keeps the promise.

        Raises:
            ValueError: as :meth:`check_jacobian`.
        """
        rows, cols = self._entries("Hessian", rows, self.n_variables, "variable", cols)
        self._check_band("Hessian", "variable", self.var_stage[rows], rows, cols)

    def _entries(self, what: str, rows, size: int, kind: str, cols) -> tuple[np.ndarray, np.ndarray]:
        rows, cols = np.asarray(rows, dtype=np.int64).ravel(), np.asarray(cols, dtype=np.int64).ravel()
        if rows.shape != cols.shape:
            raise ValueError(f"StageStructure: the {what} pattern has {rows.size} rows but {cols.size} columns")
        for name, index, bound in ((kind, rows, size), ("variable", cols, self.n_variables)):
            bad = np.flatnonzero((index < 0) | (index >= bound))
            if bad.size:
                raise ValueError(f"StageStructure: the {what} pattern names {name} {index[bad[0]]}, but there are "
                                 f"{bound} {name}s (a structure built for another NLP?)")
        return rows, cols

    def _check_band(self, what: str, kind: str, row_stages: np.ndarray, rows: np.ndarray, cols: np.ndarray):
        col_stages = self.var_stage[cols]
        bad = np.flatnonzero((row_stages >= 0) & (col_stages >= 0) & (np.abs(row_stages - col_stages) > 1))
        if bad.size:
            i = bad[0]
            raise ValueError(
                f"StageStructure: the {what} entry of {kind} {rows[i]} (stage {row_stages[i]}) and variable "
                f"{cols[i]} (stage {col_stages[i]}) couples stages more than one apart ({bad.size} such entries); "
                f"the stage structure does not describe this NLP: mark the row or variable as border (-1) or fix "
                f"its stage"
            )


def collocation_structure(N: int, n: int, m: int, n_fixed: int, n_path: int, n_T: int,
                          midpoints: bool = False) -> StageStructure:
    """A collocation's stages (K = N + 1), for the layout of :func:`~.nlp_parts.collocation_blocks`: variables
    ``[x_1..x_N, u_0..u_N, (u_{1/2}..u_{N-1/2} with midpoints), T (n_T = 1 when free)]``, rows ``[defects (N n),
    required final values (n_fixed), path rows (n_path at each node, or each point of the half-step grid)]``.

    Stage k holds x_k (k >= 1), u_k and, with midpoints, u_{k-1/2}; its rows are the defect of interval k - 1 and
    the path rows at node k (and at the midpoint k - 1/2)."""
    nodes = np.arange(1, N + 1)
    var_stage = [np.repeat(nodes, n), np.repeat(np.arange(N + 1), m)]
    if midpoints:
        var_stage.append(np.repeat(nodes, m))  # u_{k+1/2} is first used by interval k's defect, in stage k + 1
    # Half-step point p is node p / 2 (stage p / 2) or the midpoint of interval p // 2 (stage p // 2 + 1).
    points = (np.arange(2 * N + 1) + 1) // 2 if midpoints else np.arange(N + 1)
    row_stage = [np.repeat(nodes, n), np.full(n_fixed, BORDER), np.repeat(points, n_path)]
    return StageStructure(np.concatenate(var_stage + [np.full(n_T, BORDER)]), np.concatenate(row_stage), N + 1)


def multiple_shooting_structure(M: int, S: int, n: int, m: int, n_fixed: int, n_path: int,
                                n_T: int) -> StageStructure:
    """Multiple shooting's stages (K = M + 1) for M shooting intervals of S steps: variables ``[X_1..X_M,
    u_0..u_N (N = M S), T (n_T = 1 when free)]``, rows ``[continuity defects (M n), required final values
    (n_fixed), path rows (n_path at each control node)]``.

    Stage j holds X_j (j >= 1) and the controls u_{jS}..u_{jS+S-1} that interval j reads first (u_{jS+S}, shared
    with interval j + 1, is stage j + 1's; u_N is stage M's); its rows are the continuity defect of interval j - 1
    and the path rows at the control nodes of interval j (the last node's, on X_M and u_N, in stage M)."""
    steps = np.arange(M * S + 1) // S  # the stage of control node k, and of its path rows
    var_stage = [np.repeat(np.arange(1, M + 1), n), np.repeat(steps, m), np.full(n_T, BORDER)]
    row_stage = [np.repeat(np.arange(1, M + 1), n), np.full(n_fixed, BORDER), np.repeat(steps, n_path)]
    return StageStructure(np.concatenate(var_stage), np.concatenate(row_stage), M + 1)
