"""IPOPT (interior-point filter line search) through cyipopt, with exact JAX derivatives."""

from __future__ import annotations

import dataclasses
import functools
import importlib
import time
from typing import Any, Callable, ClassVar, Literal, Mapping, final

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation import CompiledFunction, compile_many, program_key
from ..data import require_float64
from ..nlp import NLP, NLPResult
from ..status import from_ipopt
from .base import (
    AbstractNLPSolver,
    ScaledProblem,
    cached,
    canonical_data,
    constraint_violation,
    initial_point,
)
from .sparse import HessianColouring, compressed_jacobian_fn, dense_from_hvps, hessian_structure, hvp_batch_fn

__all__ = ["Ipopt"]

# IPOPT reads bounds at or beyond +-1e19 (nlp_{lower,upper}_bound_inf) as absent.
_IPOPT_INF = 1e20
_HESSIAN_MODES = ("exact", "limited-memory")
# Hessian-vector products per call of the one compiled second-order program: detection takes n / 16 calls once,
# every Hessian ceil(colours / 16) calls. Larger wastes padded products on banded Hessians (often < 16 colours);
# smaller means more calls for dense ones.
_HVP_BATCH = 16
# A transcription without a Jacobian pattern (single shooting) has a dense Hessian: one call of n products is then
# 2-4x cheaper per Hessian than ceil(n / 16) calls, for the same compile time (measured on Timber Harvest and
# Cart-Pole, n = 101). Capped so the program stays small.
_DENSE_HVP_MAX = 512
# Statuses that mean "converged"; every other status (including 6, Feasible_Point_Found) is a failure.
_CONVERGED = {0: "Solve_Succeeded", 1: "Solved_To_Acceptable_Level"}


@final
@dataclasses.dataclass(frozen=True)
class Ipopt(AbstractNLPSolver):
    """IPOPT, the primal-dual interior-point method, through cyipopt's low-level ``Problem`` interface.

    IPOPT solves the barrier problems

    .. math::
        \\min_{w}\\ F(w) - \\mu \\sum_j \\big(\\ln(w_j - w^l_j) + \\ln(w^u_j - w_j)\\big)
        \\quad\\text{s.t.}\\quad c(w) - s = 0,\\ c^l \\le s \\le c^u

    for a decreasing barrier parameter ``mu`` by Newton steps on the primal-dual KKT system, globalised by a filter
    line search. It needs the gradient ``dF/dw``, the constraint Jacobian ``dc/dw`` as sparse triplets and (unless
    ``hessian="limited-memory"``) the lower triangle of the Hessian of the Lagrangian
    ``sigma * d2F/dw2 + sum_i lambda_i d2c_i/dw2``; all are exact JAX derivatives, jit-compiled once per NLP.

    * Variables: IPOPT works in ``w = z / nlp.z_scale`` (:class:`ScaledProblem`); its own gradient-based scaling stays.
    * Derivatives: one compiled program per point for all four first-order callbacks, the Jacobian as the triplets
      of ``nlp.jacobian_sparsity`` by coloured JVPs (dense without one).
    * Hessian: the pattern is detected numerically once per NLP, as the union of the non-zeros of the dense Lagrangian
      Hessian at two random points near the first starting point with random multipliers (plus the diagonal);
      values then come from coloured Hessian-vector products. An entry is missed only if it vanishes at both random
      points for the first solve's ``data`` (e.g. a term multiplied by a parameter that is exactly zero there); pass
      ``hessian="limited-memory"`` for such problems.
    * Bounds are kept exact (``bound_relax_factor = 0``, ``honor_original_bounds = yes``): a solver that steps a hair
      outside a control box stalls on dynamics that are undefined there.

    Attributes:
        tol: IPOPT's ``tol``, the (scaled) KKT error at which it stops.
        max_iter: IPOPT's ``max_iter``.
        hessian: ``"exact"`` or ``"limited-memory"`` (L-BFGS; no second derivatives are compiled).
        print_level: IPOPT's ``print_level`` (0 silent, 5 the usual log).
        constr_viol_tol: the largest constraint or bound violation a successful solve may have; also passed to
            IPOPT as ``constr_viol_tol``.
        options: further IPOPT options, ``{name: value}``; they override the above. Stored as a sorted tuple of
            pairs so that the solver stays hashable.
    """

    label: ClassVar[str] = "ipopt"

    tol: float = 1e-8
    max_iter: int = 3000
    hessian: Literal["exact", "limited-memory"] = "exact"
    print_level: int = 0
    constr_viol_tol: float = 1e-6
    options: Mapping[str, Any] | tuple[tuple[str, Any], ...] = ()

    def __post_init__(self):
        if self.hessian not in _HESSIAN_MODES:
            raise ValueError(f"Ipopt(hessian={self.hessian!r}): expected one of {_HESSIAN_MODES}")
        if not self.tol > 0 or not self.constr_viol_tol > 0:
            raise ValueError("Ipopt: tol and constr_viol_tol must be positive")
        if self.max_iter < 0:
            raise ValueError("Ipopt: max_iter must be non-negative")
        options = self.options.items() if isinstance(self.options, Mapping) else self.options
        object.__setattr__(self, "options", tuple(sorted((str(k), v) for k, v in options)))

    def ipopt_options(self) -> dict[str, Any]:
        """The options handed to IPOPT, in order of precedence (later wins)."""
        return {
            "tol": float(self.tol),
            "max_iter": int(self.max_iter),
            "print_level": int(self.print_level),
            "sb": "yes",  # no banner
            "constr_viol_tol": float(self.constr_viol_tol),
            "bound_relax_factor": 0.0,
            "honor_original_bounds": "yes",
            "hessian_approximation": self.hessian,
            **dict(self.options),
        }

    def solve(self, nlp: NLP, data: Any, z0: Any = None) -> NLPResult:
        require_float64("Ipopt.solve")
        exact = self.hessian == "exact"
        fns = cached(nlp, ("ipopt", exact),
                     lambda: _Derivatives(ScaledProblem.from_nlp(nlp), nlp.jacobian_sparsity, exact))
        problem = fns.problem
        data = canonical_data(data)
        w0 = problem.to_w(initial_point(nlp, data, z0))
        # cyipopt imported here, not at the top (0.35 s that every other solver's solve would pay), and while XLA
        # compiles this solve's programs
        compile_seconds = fns.prepare(w0, data, exact, meanwhile=lambda: importlib.import_module("cyipopt"))
        import cyipopt

        callbacks = _Callbacks(fns, w0, data, exact)
        ipopt = cyipopt.Problem(
            n=problem.n_variables,
            m=problem.n_constraints,
            problem_obj=callbacks,
            lb=_finite(problem.w_lower),
            ub=_finite(problem.w_upper),
            cl=_finite(problem.c_lower),
            cu=_finite(problem.c_upper),
        )
        for name, value in self.ipopt_options().items():
            try:
                ipopt.add_option(name, value)
            except TypeError as error:  # cyipopt's only word for an unknown name or a value of the wrong type
                raise ValueError(
                    f"Ipopt: IPOPT {'.'.join(map(str, cyipopt.IPOPT_VERSION))} rejected the option {name}={value!r} "
                    f"(unknown name, or a value of the wrong type: int, float or str)"
                ) from error
        start = time.perf_counter()
        w, info = ipopt.solve(w0)
        solve_seconds = time.perf_counter() - start

        z = problem.to_z(w)
        c = np.asarray(info["g"]) if problem.n_constraints else None
        violation = constraint_violation(nlp, z, c)
        objective = float(info["obj_val"])
        code = int(info["status"])
        success, message = judge(code, info["status_msg"], violation, objective, self.constr_viol_tol)
        return NLPResult(
            z=z,
            objective=objective,
            status=from_ipopt(code, success),
            solver_code=code,
            message=message,
            iterations=callbacks.iterations,
            constraint_violation=violation,
            multipliers=np.asarray(info["mult_g"]) if problem.n_constraints else None,
            compile_seconds=compile_seconds,
            solve_seconds=solve_seconds,
        )


def judge(
    status: int, message: bytes | str, violation: float, objective: float, constr_viol_tol: float
) -> tuple[bool, str]:
    """IPOPT's exit status as (success, message): success needs a converged status (``Solve_Succeeded`` or
    ``Solved_To_Acceptable_Level``, whose looser ``acceptable_*`` tolerances allow e.g. a violation up to 1e-2), our
    own violation within ``constr_viol_tol`` and a finite objective; every other status keeps IPOPT's message."""
    message = message.decode() if isinstance(message, bytes) else str(message)
    if status not in _CONVERGED:
        return False, message
    if violation <= constr_viol_tol and np.isfinite(objective):
        return True, message
    return False, (
        f"IPOPT reported {_CONVERGED[status]}, but the constraint violation {violation:.3g} exceeds "
        f"constr_viol_tol={constr_viol_tol:.3g} or the objective {objective:.6g} is not finite: {message}"
    )


def _finite(bounds: np.ndarray) -> np.ndarray:
    return np.clip(np.asarray(bounds, dtype=np.float64), -_IPOPT_INF, _IPOPT_INF)


class _Derivatives:
    """The compiled functions IPOPT calls, for one NLP (in scaled variables ``w``).

    Two programs: ``point`` (objective, gradient, constraints and Jacobian values at ``w``, packed into one vector,
    on ``nlp.objective_and_constraints``: one rollout for shooting) and ``hvps`` (Hessian-vector products of the
    Lagrangian, 16 per call, serving the pattern's detection too). IPOPT asks for the four first-order quantities in
    four callbacks, nearly always at the same point: one program per point means one dispatch and one rollout
    instead of four, and the derivatives of a rejected trial point are the only waste.

    One program (``shared``) where the transcription gives its Lagrangian's derivatives whole and the Jacobian is
    dense (single shooting's stages): ``staged`` returns the packed point and the dense Hessian, and serves both
    (less to compile); a point call skips the second-order part (``hessian=False``, a ``lax.cond``).
    """

    def __init__(self, problem: ScaledProblem, jacobian_sparsity: tuple[np.ndarray, np.ndarray] | None,
                 exact: bool = True):
        self.problem = problem
        n, m = problem.n_variables, problem.n_constraints
        evaluate = problem.evaluate
        # Dense unless a sparse pattern is given; offsets of f, grad, c and the Jacobian values in the packed vector.
        self.jacobian_structure = tuple(idx.ravel() for idx in np.indices((m, n)))
        self.layout = np.cumsum([0, 1, n, m, m * n])
        self.hessian_structure: tuple[np.ndarray, np.ndarray] | None = None
        self.hessian_colouring: HessianColouring | None = None
        self.shared = exact and problem.derivatives is not None and jacobian_sparsity is None
        if self.shared:
            derivatives = problem.derivatives

            def staged(w, sigma, lam, data, hessian):  # hessian False: the first-order part alone (lax.cond)
                f, c, grad, jac, hess = derivatives(w, lam, data, sigma, hessian)
                return jnp.concatenate([jnp.reshape(f, (1,)), grad, jnp.reshape(c, (-1,)), jnp.ravel(jac)]), hess

            self.staged = CompiledFunction(staged, program_key(problem.key, "ipopt.staged"))
            return

        if m and jacobian_sparsity is not None:
            rows, cols = _validated_sparsity(jacobian_sparsity, (m, n))
            jacobian_values = compressed_jacobian_fn(problem.constraints, rows, cols, (m, n))
            self.jacobian_structure, self.layout = (rows, cols), np.cumsum([0, 1, n, m, rows.size])

            def point(w, data):
                (f, c), grad = jax.value_and_grad(lambda w_: evaluate(w_, data), has_aux=True)(w)
                return jnp.concatenate([f[None], grad, c, jacobian_values(w, data)])
        else:
            # Dense (or no) Jacobian: the gradient and the m Jacobian rows are the m + 1 rows of the Jacobian of
            # (F, c), one forward pass shared by m + 1 reverse passes (forward mode when that is cheaper).

            def point(w, data):
                def stacked(w_):
                    f, c = evaluate(w_, data)
                    return jnp.concatenate([f[None], c])

                if m + 1 <= n:
                    values, pullback = jax.vjp(stacked, w)
                    jac = jax.vmap(pullback)(jnp.eye(m + 1, dtype=w.dtype))[0]
                else:
                    values, jac = stacked(w), jax.jacfwd(stacked)(w)
                return jnp.concatenate([values[:1], jac[0], values[1:], jac[1:].reshape(-1)])

        self.point = CompiledFunction(point, program_key(
            problem.key, "ipopt.point", "dense" if jacobian_sparsity is None else "sparse"))  # the NLP's own pattern)

        def lagrangian_gradient(w, sigma, lam, data):
            def lagrangian(w_):
                f, c = evaluate(w_, data)
                return sigma * f + jnp.dot(lam, c)

            return jax.grad(lagrangian)(w)

        # (w, seeds (B, n), sigma, lam, data) -> seeds @ H; see sparse.hvp_batch_fn.
        self.hvps = CompiledFunction(hvp_batch_fn(lagrangian_gradient), program_key(problem.key, "ipopt.hvps"))
        self.hvp_batch = n if jacobian_sparsity is None and n <= _DENSE_HVP_MAX else min(n, _HVP_BATCH)

    def hvp_args(self, w0: np.ndarray, data: Any) -> tuple:
        """Example arguments of ``self.hvps`` (its signature)."""
        seeds = np.zeros((self.hvp_batch, self.problem.n_variables))
        return w0, seeds, np.float64(1.0), np.zeros(self.problem.n_constraints), data

    def staged_args(self, w0: np.ndarray, data: Any) -> tuple:
        """Example arguments of ``self.staged`` (its signature; a point call's own objective factor and multipliers)."""
        return w0, np.float64(1.0), np.zeros(self.problem.n_constraints), data, np.bool_(False)

    def prepare(self, w0: np.ndarray, data: Any, exact: bool, meanwhile: Callable[[], Any] | None = None) -> float:
        """Compile everything for the signature of ``(w0, data)``; returns the seconds spent (0 when cached).
        ``meanwhile``: the caller's work done while XLA compiles (:func:`~myriad.runtime.compilation.compile_many`)."""
        if self.shared:
            jobs = [(self.staged, self.staged_args(w0, data))]
        else:
            jobs = ([(self.hvps, self.hvp_args(w0, data))] if exact else []) + [(self.point, (w0, data))]
        seconds = compile_many(jobs, meanwhile)
        if exact and self.hessian_structure is None:
            start = time.perf_counter()
            self._detect_hessian(w0, data)
            seconds += time.perf_counter() - start
        return seconds

    def _detect_hessian(self, w0: np.ndarray, data: Any) -> None:
        """The Hessian pattern from dense Hessians at random points near ``w0`` (see :class:`Ipopt`)."""
        p, n, m = self.problem, self.problem.n_variables, self.problem.n_constraints
        if self.shared:
            staged = self.staged.executable(*self.staged_args(w0, data))

            def dense(w, lam):
                return np.asarray(staged(w, np.float64(1.0), lam, data, np.bool_(True))[1])
        else:
            hvps = self.hvps.executable(*self.hvp_args(w0, data))

            def dense(w, lam):
                return dense_from_hvps(lambda seeds: hvps(w, seeds, np.float64(1.0), lam, data), n, self.hvp_batch)
        rng = np.random.default_rng(0)  # deterministic: the same NLP always gets the same pattern
        samples = []
        for _ in range(2):
            w = np.clip(w0 + 0.1 * (1.0 + np.abs(w0)) * rng.standard_normal(n), p.w_lower, p.w_upper)
            lam = rng.uniform(1.0, 2.0, m) * rng.choice([-1.0, 1.0], m)
            samples.append(dense(w, lam))
        rows, cols = hessian_structure(samples, n)
        self.hessian_structure = (rows, cols)
        if not self.shared:
            self.hessian_colouring = HessianColouring(rows, cols, n, self.hvp_batch)


def _validated_sparsity(
    sparsity: tuple[np.ndarray, np.ndarray], shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = (np.asarray(a, dtype=np.int64).ravel() for a in sparsity)
    if rows.shape != cols.shape:
        raise ValueError(f"jacobian_sparsity: rows and cols differ in length ({rows.size} vs {cols.size})")
    if rows.size and (rows.min() < 0 or rows.max() >= shape[0] or cols.min() < 0 or cols.max() >= shape[1]):
        raise ValueError(f"jacobian_sparsity: an entry lies outside the {shape[0]} x {shape[1]} Jacobian")
    # IPOPT sums duplicate triplets; every duplicate would be counted twice. Keep each entry once, row-major.
    flat = np.unique(rows * shape[1] + cols)
    return flat // shape[1], flat % shape[1]


class _Callbacks:
    """The object cyipopt calls back into: NumPy in, NumPy out, ``data`` fixed for the solve.

    The first-order callbacks share one evaluation of ``point`` per distinct ``w`` (compared by value: cyipopt
    hands over a fresh array every call), cached for the last two points.
    """

    def __init__(self, fns: _Derivatives, w0: np.ndarray, data: Any, exact: bool):
        # Bind the executables once: IPOPT makes several calls per iteration, and looking the signature up in
        # CompiledFunction.__call__ would flatten `data` every time.
        self._data = data
        self._layout = fns.layout
        self._recent: dict[bytes, np.ndarray] = {}
        # cyipopt finds the callbacks by attribute; the first-order ones share one evaluation per point (_at).
        self.gradient, self.constraints, self.jacobian = (functools.partial(self._at, part=p) for p in (1, 2, 3))
        self.jacobianstructure = lambda: fns.jacobian_structure
        self.iterations = 0
        self._staged = None
        if fns.shared:
            args = fns.staged_args(w0, data)
            self._staged = staged = fns.staged.executable(*args)
            _, one, zeros, _, first_order = args
            self._point = lambda w, data_: staged(w, one, zeros, data_, first_order)[0]
        else:
            self._point = fns.point.executable(w0, data)
        if exact:
            if not fns.shared:
                self._hvps = fns.hvps.executable(*fns.hvp_args(w0, data))
                self._colouring = fns.hessian_colouring
            self._hess_structure = fns.hessian_structure
            # cyipopt finds the callbacks by attribute; without `hessian`, IPOPT must approximate it.
            self.hessian = self._hessian
            self.hessianstructure = lambda: self._hess_structure

    def _at(self, w: np.ndarray, part: int) -> np.ndarray:
        key = w.tobytes()
        values = self._recent.get(key)
        if values is None:
            values = np.asarray(self._point(w, self._data))
            # Two points: IPOPT sometimes evaluates a second trial point (backtracking, second-order correction)
            # before it asks for the derivatives at the first.
            if len(self._recent) >= 2:
                del self._recent[next(iter(self._recent))]
            self._recent[key] = values
        return values[self._layout[part] : self._layout[part + 1]]

    def objective(self, w):
        return float(self._at(w, 0)[0])

    def _hessian(self, w, lagrange, obj_factor):
        sigma, lam = np.float64(obj_factor), np.asarray(lagrange, dtype=np.float64)
        if self._staged is not None:
            return np.asarray(self._staged(w, sigma, lam, self._data, np.bool_(True))[1])[self._hess_structure]
        return self._colouring.values(lambda seeds: self._hvps(w, seeds, sigma, lam, self._data))

    def intermediate(self, alg_mod, iter_count, *args):
        self.iterations = int(iter_count)
        return True
