"""The abstract NLP solver and what every solver shares: the one feasibility measure every solver reports and judges
success by (:func:`constraint_violation`), the change of variables ``w = z / z_scale`` every solver works in
(:class:`ScaledProblem`), and a per-NLP cache of what a solver compiled (:func:`cached`), so that a second solve of the
same NLP with new ``data`` of the same shapes never traces or compiles again.
"""

from __future__ import annotations

import abc
import dataclasses
import weakref
from typing import Any, Callable, ClassVar, Hashable, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.caches import on_clear
from ..nlp import NLP, NLPResult, evaluation

__all__ = [
    "AbstractNLPSolver",
    "ScaledProblem",
    "cached",
    "canonical_data",
    "constraint_violation",
    "constraint_violations",
    "split_constraints",
]

T = TypeVar("T")


class AbstractNLPSolver(abc.ABC):
    """A configured NLP solver: a frozen (hence hashable) dataclass of options only, with its registry name ``label``
    (``"ipopt"``). Everything compiled for an NLP lives in the cache of :func:`cached`, keyed weakly by the NLP."""

    label: ClassVar[str]

    @abc.abstractmethod
    def solve(self, nlp: NLP, data: Any, z0: Any = None) -> NLPResult:
        """Solve ``nlp`` for the problem data ``data`` (only its shapes are static) from ``z0`` (the NLP's initial
        guess when None): an :class:`NLPResult` in the original variables ``z``, ``success`` only for a solve that
        converged to the solver's tolerance at a point within its constraint tolerance."""


def constraint_violation(nlp: NLP, z: Any, c: Any | None) -> float:
    """The largest violation of any constraint or variable bound (the infinity norm of the infeasibility).

    .. math::
        v(z) = \\max\\Big(0,\\ \\max_i (c^l_i - c_i(z)),\\ \\max_i (c_i(z) - c^u_i),
                          \\ \\max_j (z^l_j - z_j),\\ \\max_j (z_j - z^u_j)\\Big)

    at ``z`` with ``c = c(z)`` (None when the NLP has no constraints). Infinite bounds never contribute. A non-finite
    ``z`` or ``c`` gives ``inf``, so NaNs can never pass a tolerance test.
    """
    z = np.asarray(z, dtype=np.float64)
    return float(constraint_violations(nlp, z[None], None if c is None else np.asarray(c)[None])[0])


def constraint_violations(nlp: NLP, z: Any, c: Any | None) -> np.ndarray:
    """:func:`constraint_violation` of each row of ``z`` (B, n_variables) and ``c`` (B, n_constraints), at once."""
    z = np.asarray(z, dtype=np.float64)
    pairs = [(nlp.z_lower, z, nlp.z_upper)]
    if c is not None and nlp.n_constraints:
        pairs.append((nlp.c_lower, np.asarray(c, dtype=np.float64), nlp.c_upper))
    worst = np.zeros(z.shape[0])
    finite = np.ones(z.shape[0], bool)
    with np.errstate(invalid="ignore"):  # a non-finite member's NaNs are replaced by inf below
        for lower, value, upper in pairs:
            finite &= np.isfinite(value).all(axis=1)
            worst = np.maximum(worst, np.maximum(lower - value, value - upper).max(axis=1, initial=0.0))
    return np.where(finite, worst, np.inf)


def split_constraints(c_lower: np.ndarray, c_upper: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the equalities and of the finite upper and lower bounds of the inequalities.

    ``(eq, upper, lower)``: row ``i`` is an equality where ``c_lower[i] == c_upper[i]`` (finite); otherwise each
    finite side is a one-sided inequality, so a two-sided row is in both ``upper`` and ``lower``.
    """
    c_lower, c_upper = np.asarray(c_lower), np.asarray(c_upper)
    eq = (c_lower == c_upper) & np.isfinite(c_lower)
    return np.flatnonzero(eq), np.flatnonzero(~eq & np.isfinite(c_upper)), np.flatnonzero(~eq & np.isfinite(c_lower))


@dataclasses.dataclass(frozen=True, eq=False)
class ScaledProblem:
    """The NLP in scaled variables ``w = z / s`` with ``s = nlp.z_scale`` (all ones when absent).

    .. math::
        \\min_w F(s \\odot w)\\quad \\text{s.t.}\\quad c^l \\le c(s \\odot w) \\le c^u,\\quad
        z^l / s \\le w \\le z^u / s

    The constraint values, and hence the constraint multipliers, are the same in both variables; only the
    gradient (``s * dF/dz``) and the bounds change. Solvers use the change of variables rather than a solver's
    own user-scaling option so that all three solvers see the same well-scaled problem.

    NOTE: this object holds the NLP's *functions and arrays*, never the NLP itself: it is stored as a value in
    the weak-keyed cache, and a strong reference back to the key would keep every NLP alive forever.
    """

    objective: Callable[[Any, Any], Any]
    constraints: Callable[[Any, Any], Any] | None
    scale: np.ndarray
    w_lower: np.ndarray
    w_upper: np.ndarray
    c_lower: np.ndarray
    c_upper: np.ndarray
    # (w, data) -> (F, c): fused when the NLP provides objective_and_constraints (see NLP), else both calls.
    evaluate: Callable[[Any, Any], tuple[Any, Any]]
    key: str | None = None  # the NLP's key (myriad.runtime.compilation.programs): what its functions depend on, or None
    # (w, lam, data, objective_weight=1) -> (F, c, dF/dw, dc/dw, Hessian of the Lagrangian in w):
    # NLP.lagrangian_derivatives, or None.
    derivatives: Callable[[Any, Any, Any], tuple] | None = None
    # The same with the Hessian as the rollout's stages (NLP.stage_derivatives, in w), step k reading
    # w[stage_index[k]]; or None.
    stages: Callable[[Any, Any, Any], tuple] | None = None
    stage_index: np.ndarray | None = None
    # The stage of each variable and row (NLP.stage_structure: collocation, multiple shooting), or None.
    stage_structure: Any = None

    @classmethod
    def from_nlp(cls, nlp: NLP) -> "ScaledProblem":
        n = nlp.n_variables
        if nlp.z_scale is None:
            scale = np.ones(n)
        else:
            scale = np.asarray(nlp.z_scale, dtype=np.float64)
            if scale.shape != (n,) or not np.all(np.isfinite(scale)) or np.any(scale <= 0):
                raise ValueError(f"{nlp.name}: z_scale must be finite and positive with shape ({n},)")
        f, c = nlp.objective, nlp.constraints
        if c is None and nlp.n_constraints:
            raise ValueError(f"{nlp.name}: constraints is None but c_lower has {nlp.n_constraints} entries")
        s = jnp.asarray(scale)
        evaluate_z = evaluation(f, c, nlp.objective_and_constraints)
        return cls(
            objective=lambda w, data: f(w * s, data),
            constraints=None if nlp.n_constraints == 0 else (lambda w, data: c(w * s, data)),
            scale=scale,
            w_lower=np.asarray(nlp.z_lower, dtype=np.float64) / scale,
            w_upper=np.asarray(nlp.z_upper, dtype=np.float64) / scale,
            c_lower=np.asarray(nlp.c_lower, dtype=np.float64),
            c_upper=np.asarray(nlp.c_upper, dtype=np.float64),
            evaluate=lambda w, data: evaluate_z(w * s, data),
            key=nlp.key,
            derivatives=None if nlp.lagrangian_derivatives is None else _scaled_derivatives(
                nlp.lagrangian_derivatives, s),
            stages=None if nlp.stage_derivatives is None else _scaled_stages(nlp.stage_derivatives, s,
                                                                             nlp.stage_index),
            stage_index=None if nlp.stage_derivatives is None else np.asarray(nlp.stage_index),
            stage_structure=nlp.stage_structure,
        )

    @property
    def n_variables(self) -> int:
        return int(self.scale.shape[0])

    @property
    def n_constraints(self) -> int:
        return 0 if self.constraints is None else int(self.c_lower.shape[0])

    def to_w(self, z: Any) -> np.ndarray:
        return np.asarray(z, dtype=np.float64) / self.scale

    def to_z(self, w: Any) -> np.ndarray:
        return np.asarray(w, dtype=np.float64) * self.scale


def _scaled_derivatives(derivatives: Callable, s: Any) -> Callable:
    """An NLP's ``lagrangian_derivatives`` in ``w = z / s`` (the chain rule of a diagonal change of variables)."""
    def scaled(w, lam, data, objective_weight=1.0, hessian=True):
        f, c, grad, jac, hess = derivatives(w * s, lam, data, objective_weight, hessian)
        return f, c, grad * s, jac * s, hess * s[:, None] * s[None, :]

    return scaled


def _scaled_stages(derivatives: Callable, s: Any, index: np.ndarray) -> Callable:
    """An NLP's ``stage_derivatives`` in ``w = z / s``: step k's ``dv`` is ``s[index_k] dw``, so ``B_k`` and the
    ``v`` rows and columns of ``W_k`` take the factors (the state's rows are not decisions)."""
    index = np.asarray(index)

    def scaled(w, lam, data, objective_weight=1.0):
        f, c, grad, jac, st = derivatives(w * s, lam, data, objective_weight)
        sv = s[index]  # (N, q)
        n_y = st.a.shape[-1]
        full = jnp.concatenate([jnp.ones((sv.shape[0], n_y), sv.dtype), sv], axis=1)
        return f, c, grad * s, jac * s, st._replace(b=st.b * sv[:, None, :],
                                                     w=st.w * full[:, :, None] * full[:, None, :])

    return scaled


def unstack(tree: Any, size: int) -> list:
    """``[tree[i] for i < size]`` for a pytree of host arrays with a leading axis ``size``, flattened once (not a
    ``jax.tree.map`` per member: measured in the solver-code note)."""
    leaves, treedef = jax.tree.flatten(tree)
    leaves = [np.asarray(leaf) for leaf in leaves]
    return [treedef.unflatten([leaf[i] for leaf in leaves]) for i in range(size)]


def canonical_data(data: Any) -> Any:
    """``data`` as arrays (device or NumPy) with concrete (never weak) dtypes, so that a solve with ``{"k": 1.0}``
    and one with ``{"k": jnp.float64(2.0)}`` share one compiled program (weak and strong types trace apart)."""
    # A device array with a concrete dtype is already canonical, and so is a NumPy array of a canonical dtype (what
    # default_data builds): a compiled program takes it as it is (copies cost more: the solver-code note).
    return jax.tree.map(_canonical_leaf, data)


def _canonical_leaf(x: Any) -> Any:
    if isinstance(x, jax.Array) and not x.weak_type and not isinstance(x, jax.core.Tracer):
        return x
    host = np.asarray(x)
    return host if host.dtype == jax.dtypes.canonicalize_dtype(host.dtype) else jax.device_put(host)


_CACHE: "weakref.WeakKeyDictionary[NLP, dict[Hashable, Any]]" = weakref.WeakKeyDictionary()
on_clear(_CACHE.clear)


def cached(nlp: NLP, key: Hashable, build: Callable[[], T]) -> T:
    """The object ``build()`` made for ``(nlp, key)``, built on first use and kept while ``nlp`` is alive. ``build``
    must not capture ``nlp`` itself (see :class:`ScaledProblem`), or the entry would never be freed."""
    per_nlp = _CACHE.setdefault(nlp, {})
    if key not in per_nlp:
        per_nlp[key] = build()
    return per_nlp[key]


def initial_point(nlp: NLP, data: Any, z0: Any | None) -> np.ndarray:
    """``z0``, or the NLP's initial guess, as a float64 NumPy vector of the right length."""
    z = nlp.initial_guess(data) if z0 is None else z0
    z = np.asarray(z, dtype=np.float64)
    if z.shape != (nlp.n_variables,):
        raise ValueError(f"{nlp.name}: z0 has shape {z.shape}, expected ({nlp.n_variables},)")
    return z
