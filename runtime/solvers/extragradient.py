"""A first-order Lagrangian (saddle-point) method with extragradient steps, entirely in JAX."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, ClassVar, Literal, NamedTuple, final

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..nlp import NLP, NLPResult
from ..status import Status
from .base import (
    AbstractNLPSolver,
    CompiledFunction,
    ScaledProblem,
    cached,
    canonical_data,
    constraint_violation,
    initial_point,
    split_constraints,
)
from .pure import AbstractPureSolver

__all__ = ["Extragradient", "ExtragradientSolution"]

_BOUNDS_MODES = ("projection", "sigmoid")
_MESSAGES = {
    Status.CONVERGED: "converged: KKT residual and constraint violation below tol",
    Status.ITERATION_LIMIT: "maximum number of iterations reached before the KKT residual fell below tol",
    Status.NOT_FINITE: "stopped at a non-finite iterate (NaN or inf); try smaller steps",
}
# Iterations between checks of the constraint violation's progress (see Extragradient, "Penalty"). Checking
# every 500 with a demand to halve the violation grew the penalty on HS71 during its slow start and stalled it.
_PENALTY_CHECK = 2000
# Where the sigmoid starts a variable that sits on its bound: logit(1e-2) = -4.6 keeps sigma' ~ 1e-2, not 0.
_SIGMOID_MARGIN = 1e-2
# IPOPT's nlp_scaling_max_gradient: the objective is scaled so its gradient at the start is at most this.
_MAX_START_GRADIENT = 100.0
_SCALING_MODES = ("guess", "bounds")
# scaling="guess": start magnitudes below this (in the NLP's scaled units) are raised to it, so that a start of 1e-12
# does not freeze a variable; an exact zero carries no magnitude at all and keeps the nominal scale 1.
_MIN_COLUMN_SCALE = 1e-4
# scaling="guess": limits of the row factors (IPOPT's gradient-based rule only ever scales down, to 1e-8; rows here are
# scaled up as well, which is what a defect row of a tiny state needs, so both directions are bounded).
_ROW_SCALE_LIMITS = (1e-4, 1e4)
# Columns of the start Jacobian computed per JVP batch when measuring the rows (memory: this many constraint vectors).
_JACOBIAN_CHUNK = 32


class ExtragradientSolution(NamedTuple):
    """What the jit-compiled ``solve_fn(data, z0)`` returns (every field gains a batch axis under ``vmap``).

    Attributes:
        z: the final iterate (n_variables,), in the original variables.
        multipliers: constraint multipliers (n_constraints,) in IPOPT's convention, ``dF/dz + (dc/dz)^T y`` = bound
            terms: the augmented-Lagrangian estimates ``lambda + rho h`` and ``max(0, mu + rho g)`` (signed).
        iterations: extragradient iterations taken (each costs two gradient evaluations).
        converged: KKT residual and constraint violation both at most ``tol`` (and everything finite).
        violation: the largest constraint or bound violation at ``z``.
    """

    z: jax.Array
    multipliers: jax.Array
    iterations: jax.Array
    converged: jax.Array
    violation: jax.Array


@final
@dataclasses.dataclass(frozen=True)
class Extragradient(AbstractPureSolver, AbstractNLPSolver):
    """Gradient descent-ascent on the (augmented) Lagrangian with an extragradient look-ahead, in pure JAX.

    With equalities ``h(w) = c_E(w) - c^l_E = 0`` and one-sided inequalities ``g(w) <= 0`` (``c_U - c^u_U`` for each
    finite upper bound and ``c^l_L - c_L`` for each finite lower bound of the remaining constraints), the method
    seeks a saddle point of the augmented Lagrangian

    .. math::
        L_\\rho(w, \\lambda, \\mu) = F(w) + \\lambda^\\top h + \\frac{\\rho}{2}\\lVert h\\rVert^2
            + \\frac{1}{2\\rho}\\sum_i \\big(\\max(0, \\mu_i + \\rho g_i)^2 - \\mu_i^2\\big),
        \\qquad \\min_{w \\in B}\\ \\max_{\\lambda,\\ \\mu \\ge 0}\\ L_\\rho

    (``rho = penalty``; ``rho = 0`` is the plain Lagrangian ``F + lambda^T h + mu^T g``). Writing
    ``v = (w, lambda, mu)`` and ``G(v) = (grad_w L, -grad_lambda L, -grad_mu L)``, one iteration is Korpelevich's
    extragradient step, with optax step rules ``T`` in place of a fixed step:

    .. math::
        v_{k+1/2} = \\Pi\\big(v_k + T(G(v_k))\\big), \\qquad v_{k+1} = \\Pi\\big(v_k + T(G(v_{k+1/2}))\\big)

    i.e. the gradient is evaluated at the extrapolated point but the step is taken from the original point, which
    damps the rotation that makes plain descent-ascent cycle around saddle points. The optimiser states are
    threaded through both half-steps (restarting the look-ahead from the previous state instead stalled 27 times
    further from HS71's solution in our measurements with adam). ``Pi`` projects ``mu`` onto ``mu >= 0`` and the
    variables onto their box (see ``bounds``). The inequality multipliers are thus projected non-negative
    multipliers (no slack variables); with ``rho > 0`` their ascent direction is
    ``dL/dmu = max(g, -mu / rho)``, which cannot drive ``mu`` negative by more than the step.

    Convergence is the KKT test, at the current point, on the multiplier estimates ``y = (lambda + rho h,
    max(0, mu + rho g))`` (for which ``grad_w L_rho = grad F + J^T y`` exactly):

    * stationarity ``|| w - Pi_B(w - grad_w L_rho) ||_inf`` (the projected gradient, so active bounds count);
    * feasibility: the largest constraint or bound violation;
    * complementarity ``max_i |min(y_i, -g_i)|`` over the inequalities;

    all at most ``tol``. Only then is the solve a success. Everything runs in scaled variables ``w = z / z_scale``
    (see :class:`ScaledProblem`), so the stationarity test is on the scaled gradient.

    Scaling:
        ``"guess"`` (default) adds two diagonal scalings measured at the start ``w0``, a column scale ``d`` for the
        step rules and a row scale ``r`` for the Lagrangian:

        .. math::
            d_j = \\max(|w_{0,j}|, 10^{-4})\\ (1 \\text{ where } w_{0,j} = 0), \\qquad
            r_i = \\operatorname{clip}\\Big(1 \\big/ \\max_j |\\partial c_i / \\partial w_j(w_0)|\\, d_j,\\
                10^{-4}, 10^{4}\\Big)

        The primal rule acts on ``v = w / d`` (it is given ``d * grad_w L`` and its step is multiplied by ``d``), and
        ``L_rho`` is built on the rows ``r * c`` (so ``lambda, mu`` and ``rho`` are in those units). AMSGrad's steps
        are about ``lr`` in ``v`` whatever the gradient's size, so ``d`` makes each variable's steps proportional to
        its magnitude instead of to the nominal ``z_scale``; ``r`` equilibrates the Jacobian in ``v`` to a largest
        entry of 1 per row, which turns the huge multipliers of rows whose variables are small into ``O(1)`` ones
        that the dual ascent can reach. Both are changes of variables: the KKT test above (in ``w``, on the rows as
        given), the violation and the reported multipliers are the same quantities with or without them. An exact
        zero in ``w0`` carries no magnitude and keeps ``d = 1``; rows are measured by one JVP per column, once.
        Measured on HIV Treatment (``Trapezoidal(50)``: ``z_scale`` from the bounds ``[1600, 100, 100]`` against
        trajectories of about ``[800, 0.04, 1.5]``, multipliers up to 9e4): stalls at violation 9e-4 with
        ``"bounds"``, converges in 34k iterations with ``"guess"``; each scaling alone fails. The scale is only as
        good as the start's magnitudes: Epidemic's default start holds E and I at their initial 100 and 50 while the
        solution falls to 1e-4, and takes 277k iterations (411k with ``"bounds"``); from a start simulated with the
        same controls, 11k.
        ``"bounds"``: ``d = 1`` and ``r = 1``, only ``z_scale`` (the behaviour before ``"guess"``).

    Bounds:
        ``"projection"``: clip ``w`` to the box after every half-step.
        ``"sigmoid"``: for variables with both bounds finite, optimise ``p`` with
        ``w = l + (u - l) * sigmoid(p)`` (``grad_p = grad_w * (u - l) s (1 - s)``), starting from
        ``p0 = logit((w0 - l) / (u - l))`` with the fraction kept ``1e-2`` inside the box (like IPOPT's
        ``bound_push``: a start on the bound would have ``sigmoid' = 0``); variables with one or no finite bound
        are still clipped. The sigmoid never reaches the bound, so a solution on a bound is
        approached only asymptotically and the (projected) stationarity decreases accordingly: on HS71, whose
        solution has x1 on its bound, the default step rule is still 3e-3 away after 1e5 iterations.

    Penalty:
        Every 2000 iterations, if the constraint violation has fallen by less than 10% since the last check (and is
        above ``tol``), ``rho`` grows by ``penalty_growth`` up to ``penalty_max``; the dual steps are taken in units
        of ``rho / penalty`` (the dual "gradient" is scaled by it), so they grow with the penalty as in the method
        of multipliers, ``lambda += rho h``. Without this, transcribed OCPs (dozens of defect equalities against an
        objective of order 1 to 1e3) stalled at violations of 1e-2 with ``rho = 1``, while ``rho = 100`` from the
        start stalled HS71; growing it only on stalls solves both. Measured on 8 systems x 4 transcriptions (with
        ``scaling="bounds"``): 23 of 32 converge within 1e5 iterations (to IPOPT's objective or another local
        optimum); with a fixed ``rho = 1``, 3 of the first 17 had within 5e4. The slow solves we measured end the
        same way: ``rho`` at its cap of 1e4 and the stationarity decaying by about half per 2e4 iterations
        (AMSGrad's normaliser keeps the gradients of the penalty's jumps). Capping at 1e3 or 1e5, growing by 3 or
        100, checking every 1000 to 10000 iterations, growing only while the violation exceeds the stationarity,
        and letting AMSGrad's maximum decay (0.9999 to 0.99999 per step) were each no better on Epidemic and
        worse on others of the smooth Lenhart systems.

    Step rules:
        The default primal rule is AMSGrad, Adam whose normaliser ``sqrt(v_max)`` never decreases. Plain Adam with a
        constant learning rate is a poor partner for extragradient: its step length stays about ``lr`` however
        small the gradient, so the look-ahead never shrinks, and with its moments threaded through both half-steps
        it can settle where the gradients at the point and at the look-ahead cancel in the first moment, a point
        with KKT residual ``O(lr * ||Hessian||)``. We measured exactly that (HS71 stalling at violation 1.4e-3 with
        ``adam(1e-3)`` and 3e-2 with ``adam(1e-2)``; a 150-variable Euler-transcribed OCP at 2.6e-4), while
        AMSGrad's bounded, non-increasing preconditioner converges on all of them (with ``bounds="projection"``).
        Its weakness is the converse: a huge gradient at the start shrinks that variable's steps for good.
        The dual step (plain ascent, 0.1 with ``penalty=1``) sets the pace on equality-constrained problems:
        iterations scale about as ``1 / dual_step``, and 0.3 already diverges on HS71.

    The whole solve is one ``lax.while_loop``: :meth:`solve_fn` returns the jit-compiled ``(data, z0) ->``
    :class:`ExtragradientSolution`, and :meth:`solve_batch` runs ``jax.vmap`` of it over a batch of ``data`` as one
    program (the loop then runs until every member has stopped; stopped members are frozen by ``vmap``'s select,
    so each result equals its single solve).

    Attributes:
        step: the primal step rule, an ``optax.GradientTransformation`` applied to ``grad_w L`` (descent), or a
            learning rate for ``optax.amsgrad`` (see "Step rules").
        dual_step: the dual step rule, applied to ``-grad_(lambda, mu) L`` (so that descent is ascent), or a learning
            rate for plain gradient ascent ``optax.sgd``.
        penalty: the initial augmented-Lagrangian weight ``rho >= 0``; 0 is the plain Lagrangian.
        penalty_growth: the factor by which ``rho`` grows when the violation stalls (1 keeps it fixed).
        penalty_max: the largest ``rho``.
        max_iter: the iteration limit.
        tol: the KKT tolerance (absolute, infinity norms).
        bounds: ``"projection"`` or ``"sigmoid"`` (see above).
        scale_objective: scale F so that its gradient at the start (with respect to ``v``) is at most 100 in the
            infinity norm (IPOPT's gradient-based rule); the KKT test then holds in the scaled units, and multipliers
            are reported unscaled.
        scaling: ``"guess"`` or ``"bounds"`` (see "Scaling").

    References:
        Korpelevich (1976), The extragradient method for finding saddle points and other problems.
        Gidel, Berard, Vignoud, Vincent & Lacoste-Julien (2019), A variational inequality perspective on generative
        adversarial networks. Reddi, Kale & Kumar (2018), On the convergence of Adam and beyond (AMSGrad).
        Howe, Dufort-Labbe, Rajkumar & Bacon (2022), Myriad: a real-world testbed to bridge trajectory optimization
        and deep learning.
    """

    label: ClassVar[str] = "extragradient"

    step: optax.GradientTransformation | float = 0.1
    dual_step: optax.GradientTransformation | float = 0.1
    penalty: float = 1.0
    penalty_growth: float = 10.0
    penalty_max: float = 1e4
    max_iter: int = 100_000
    tol: float = 1e-6
    bounds: Literal["projection", "sigmoid"] = "projection"
    scale_objective: bool = True
    scaling: Literal["guess", "bounds"] = "guess"

    def __post_init__(self):
        if self.bounds not in _BOUNDS_MODES:
            raise ValueError(f"Extragradient(bounds={self.bounds!r}): expected one of {_BOUNDS_MODES}")
        if self.scaling not in _SCALING_MODES:
            raise ValueError(f"Extragradient(scaling={self.scaling!r}): expected one of {_SCALING_MODES}")
        if not self.tol > 0 or self.max_iter < 1 or not self.penalty >= 0:
            raise ValueError("Extragradient: tol must be positive, max_iter at least 1 and penalty non-negative")
        if not self.penalty_growth >= 1 or not self.penalty_max >= self.penalty:
            raise ValueError("Extragradient: penalty_growth must be >= 1 (1 keeps the penalty fixed) and "
                             "penalty_max >= penalty")
        for name in ("step", "dual_step"):
            value = getattr(self, name)
            if not isinstance(value, (optax.GradientTransformation, float, int)):
                raise TypeError(f"Extragradient({name}=...): expected an optax.GradientTransformation or a learning "
                                f"rate, got {type(value).__name__}")

    # ---- public API --------------------------------------------------------------------------------------------

    def solve(self, nlp: NLP, data: Any, z0: Any = None) -> NLPResult:
        return self._solve_single(nlp, data, z0)

    # ---- the pure tier (see AbstractPureSolver) ----------------------------------------------------------------

    def pure_solve(self, nlp: NLP) -> Callable[[Any, Any], ExtragradientSolution]:
        return self._compiled(nlp).raw

    def start(self, nlp: NLP, data: Any, z0: Any = None) -> np.ndarray:
        return initial_point(nlp, data, z0)

    def prepare_report(self, nlp: NLP, z0: np.ndarray, data: Any) -> float:
        return self._compiled(nlp).prepare_evaluation(z0, data)

    def report(self, nlp: NLP, out: ExtragradientSolution, data: Any, compile_seconds: float,
               solve_seconds: float) -> NLPResult:
        fns = self._compiled(nlp)
        z = np.asarray(out.z)
        objective = float(fns.objective(z, data))
        c = np.asarray(fns.constraints(z, data)) if fns.problem.n_constraints else None
        violation = constraint_violation(nlp, z, c)
        converged = bool(out.converged) and np.isfinite(objective)
        if converged:
            status = Status.CONVERGED
        elif int(out.iterations) >= self.max_iter and np.all(np.isfinite(z)) and np.isfinite(objective):
            status = Status.ITERATION_LIMIT
        else:  # the loop stops early only at a non-finite point
            status = Status.NOT_FINITE
        return NLPResult(
            z=z,
            objective=objective,
            status=status,
            solver_code=int(status),
            message=_MESSAGES[status],
            iterations=int(out.iterations),
            constraint_violation=violation,
            multipliers=np.asarray(out.multipliers) if fns.problem.n_constraints else None,
            compile_seconds=compile_seconds,
            solve_seconds=solve_seconds,
        )

    # ---- implementation ----------------------------------------------------------------------------------------

    def _compiled(self, nlp: NLP) -> "_Compiled":
        return cached(nlp, ("extragradient", self), lambda: _Compiled(ScaledProblem.from_nlp(nlp), self))


class _Compiled:
    """The jitted solve (single and batched) and objective for one NLP and one solver configuration."""

    def __init__(self, problem: ScaledProblem, solver: Extragradient):
        self.problem = problem
        self.raw = _make_solve_fn(problem, solver)
        f, scale = problem.objective, jnp.asarray(problem.scale)
        self.objective = CompiledFunction(lambda z, data: f(z / scale, data))
        if problem.n_constraints:
            c = problem.constraints
            self.constraints = CompiledFunction(lambda z, data: c(z / scale, data))

    def prepare_evaluation(self, z: np.ndarray, data: Any) -> float:
        """Compile the objective and constraints used to report the result; returns the seconds spent."""
        seconds = self.objective.compile(z, data)
        if self.problem.n_constraints:
            seconds += self.constraints.compile(z, data)
        return seconds


class _Point(NamedTuple):
    """The (augmented) Lagrangian's derivatives at one primal-dual point."""

    grad_p: jax.Array  # descent direction's gradient for the primal parameters p
    grad_duals: tuple  # -dL/d(lambda, mu_upper, mu_lower): "gradients" whose descent is ascent
    kkt: jax.Array  # max(stationarity, violation, complementarity)
    violation: jax.Array
    multipliers: jax.Array  # the estimates y, one per NLP constraint, IPOPT's sign convention


def _optax_promotion():
    """Standard dtype promotion for optax's own arithmetic only.

    NOTE: optax mixes Python floats with its int32 step counter (``b1 ** count`` in adam's bias correction), which
    ``jax_numpy_dtype_promotion="strict"`` (our test setting) rejects. The context applies while tracing the step
    rules only; the NLP's functions stay under whatever promotion the caller set.
    """
    return jax.numpy_dtype_promotion("standard")


class _Scales(NamedTuple):
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


def _make_solve_fn(problem: ScaledProblem, solver: Extragradient) -> Callable[[Any, Any], ExtragradientSolution]:
    """Build the pure ``(data, z0) -> ExtragradientSolution`` for one scaled problem. All indices are static."""
    f, c_fn = problem.objective, problem.constraints
    n, m = problem.n_variables, problem.n_constraints
    scale = jnp.asarray(problem.scale)
    lo, hi = jnp.asarray(problem.w_lower), jnp.asarray(problem.w_upper)
    c_lo, c_up = problem.c_lower, problem.c_upper
    eq_idx, up_idx, lo_idx = split_constraints(c_lo, c_up)
    rho0 = float(solver.penalty)
    growth, rho_max, every = float(solver.penalty_growth), float(solver.penalty_max), _PENALTY_CHECK
    tol, max_iter = float(solver.tol), int(solver.max_iter)
    scale_objective = bool(solver.scale_objective)
    from_guess = solver.scaling == "guess"
    primal, dual = solver.step, solver.dual_step
    if not isinstance(primal, optax.GradientTransformation):
        primal = optax.amsgrad(float(primal))
    if not isinstance(dual, optax.GradientTransformation):
        dual = optax.sgd(float(dual))

    # Reparametrisation w = to_w(p). Variables with both bounds finite go through the sigmoid in "sigmoid" mode;
    # all others are the identity and are clipped.
    sigmoid = solver.bounds == "sigmoid"
    boxed = jnp.asarray(np.isfinite(problem.w_lower) & np.isfinite(problem.w_upper)) if sigmoid else jnp.zeros(n, bool)
    width = jnp.where(boxed, hi - lo, 1.0)
    base = jnp.where(boxed, lo, 0.0)

    def to_w(p):
        # The clip only removes rounding: lo + (hi - lo) * sigmoid(p) can exceed hi by an ulp.
        return jnp.clip(jnp.where(boxed, base + width * jax.nn.sigmoid(p), p), lo, hi)

    def dw_dp(p):
        s = jax.nn.sigmoid(p)
        return jnp.where(boxed, width * s * (1.0 - s), 1.0)

    def from_w(w):
        frac = jnp.clip((w - base) / width, _SIGMOID_MARGIN, 1.0 - _SIGMOID_MARGIN)
        return jnp.where(boxed, jnp.log(frac) - jnp.log1p(-frac), jnp.clip(w, lo, hi))

    def project_p(p):
        return jnp.where(boxed, p, jnp.clip(p, lo, hi))

    def project_duals(duals):
        lam, mu_u, mu_l = duals
        return lam, jnp.maximum(mu_u, 0.0), jnp.maximum(mu_l, 0.0)

    def make_scales(w0, data, dtype) -> _Scales:
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
        # Objective scaling as IPOPT's gradient-based rule: a start gradient above 100 (in the variables the steps
        # act on) is scaled down to 100, so an objective like Glucose's (a 1e5 factor) does not ask the duals for
        # multipliers of 1e4 (measured with scaling="bounds": Glucose then converges in 65k iterations instead of
        # stalling at 100k).
        g0 = jnp.max(jnp.abs(column * jax.grad(f)(w0, data)), initial=0.0)
        sigma = jnp.where(jnp.isfinite(g0), jnp.minimum(1.0, _MAX_START_GRADIENT / jnp.maximum(g0, 1e-300)), 1.0)
        sigma = sigma if scale_objective else jnp.ones_like(sigma)
        return _Scales(sigma.astype(dtype), column, row)

    def evaluate(p, duals, rho, data, scales: _Scales) -> _Point:
        lam, mu_u, mu_l = duals
        sigma, r = scales.sigma, scales.row
        w = to_w(p)
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
            ratio = rho / rho0 if rho0 > 0 else jnp.ones((), dtype=w.dtype)
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
        stationarity = jnp.max(jnp.abs(w - jnp.clip(w - grad_w, lo, hi)), initial=0.0)
        kkt = jnp.maximum(jnp.maximum(stationarity, violation), complementarity)
        kkt = jnp.where(jnp.isfinite(kkt) & jnp.all(jnp.isfinite(w)), kkt, jnp.inf)
        return _Point(grad_w * dw_dp(p), grad_duals, kkt, violation, y)

    def step(origin_p, origin_duals, state_p, state_d, at: _Point, d):
        """One projected optax step from ``origin`` along the gradients ``at`` a (possibly other) point.

        The primal rule acts on ``v = p / d``: it sees the gradient ``d * grad_p`` and its step ``dv`` is ``d * dv`` in
        ``p``. For AMSGrad, whose steps are about ``lr`` whatever the gradient's size, that makes a variable's steps
        proportional to its magnitude ``d``.
        """
        with _optax_promotion():
            update_v, state_p = primal.update(at.grad_p * d, state_p, origin_p / d)
            update_d, state_d = dual.update(at.grad_duals, state_d, origin_duals)
        p = project_p(origin_p + d * update_v)
        duals = project_duals(jax.tree.map(jnp.add, origin_duals, update_d))
        return p, duals, state_p, state_d

    def solve(data, z0) -> ExtragradientSolution:
        z0 = jnp.asarray(z0)
        p0 = from_w(z0 / scale) if sigmoid else jnp.clip(z0 / scale, lo, hi)
        duals0 = (jnp.zeros(eq_idx.size, z0.dtype), jnp.zeros(up_idx.size, z0.dtype), jnp.zeros(lo_idx.size, z0.dtype))
        with _optax_promotion():
            states0 = primal.init(p0), dual.init(duals0)
        rho_init = jnp.asarray(rho0, dtype=z0.dtype)
        scales = make_scales(to_w(p0), data, z0.dtype)
        d = scales.column
        point0 = evaluate(p0, duals0, rho_init, data, scales)
        init = (jnp.zeros((), jnp.int32), p0, duals0, *states0, point0, rho_init, point0.violation)

        def cond(carry):
            k, *_, point, _, _ = carry
            # A non-finite point has kkt = +inf: stop there rather than iterate on NaNs.
            return (k < max_iter) & (point.kkt > tol) & jnp.isfinite(point.kkt)

        def body(carry):
            k, p, duals, state_p, state_d, point, rho, v_ref = carry
            # NOTE: the optimiser states are threaded through both half-steps; restarting the second from the old
            # state measured worse (see the class docstring).
            # Look ahead from (p, duals) with the gradient there ...
            p_half, duals_half, state_p, state_d = step(p, duals, state_p, state_d, point, d)
            # ... and step from (p, duals) again with the gradient at the look-ahead point.
            point_half = evaluate(p_half, duals_half, rho, data, scales)
            p, duals, state_p, state_d = step(p, duals, state_p, state_d, point_half, d)
            point = evaluate(p, duals, rho, data, scales)
            checkpoint = (k + 1) % every == 0
            stalled = checkpoint & (point.violation > 0.9 * v_ref) & (point.violation > tol)
            rho = jnp.where(stalled, jnp.minimum(rho * growth, rho_max), rho)
            v_ref = jnp.where(checkpoint, point.violation, v_ref)
            return k + 1, p, duals, state_p, state_d, point, rho, v_ref

        k, p, duals, _, _, point, _, _ = jax.lax.while_loop(cond, body, init)
        return ExtragradientSolution(
            z=to_w(p) * scale,
            multipliers=point.multipliers / scales.sigma,  # back to the unscaled objective's multipliers
            iterations=k,
            converged=point.kkt <= tol,
            violation=point.violation,
        )

    return solve
