r"""The iteration: one ``lax.while_loop`` of primal-dual barrier Newton steps (Wächter & Biegler 2006, Algorithm A).

With ``x = (w, s)``, equality residuals ``g(x) = 0`` and bound multipliers ``z_l, z_u`` (see :mod:`.problem`), each
iteration

1. evaluates ``sigma F``, its gradient, ``g``, ``A = dg/dx`` and the exact Hessian ``W`` of ``sigma F + lambda^T g``;
2. stops when the scaled optimality error ``E_0`` (IPOPT's eq. 5: dual infeasibility over ``s_d``, ``||g||_inf``,
   complementarity over ``s_c``) is at most ``tol`` and the NLP's own violation at most ``constr_viol_tol``;
3. decreases the barrier parameter while ``E_mu <= 10 mu`` (monotone Fiacco-McCormick rule,
   ``mu <- max(tol / 10, min(0.2 mu, mu^1.5))``);
4. solves the Newton system with inertia correction (:mod:`.kkt`) and recovers the bound multipliers' steps;
5. limits the steps by the fraction-to-the-boundary rule (``tau = max(0.99, 1 - mu)``), primal and dual apart;
6. backtracks with IPOPT's filter line search (Wächter & Biegler 2006, sec. 2.3) on the pair (``theta = ||g||_1``,
   barrier objective ``phi_mu``): a trial is accepted when the filter does not dominate it and it decreases
   ``theta`` or ``phi_mu`` enough, or, near feasibility under the switching condition, by Armijo on ``phi_mu``
   (``eta = 1e-4``); one second-order correction after a rejected full step that did not reduce ``theta`` counters
   the Maratos effect; a non-finite trial is rejected;
7. keeps ``z`` within ``[mu / (1e10 gap), 1e10 mu / gap]`` of the primal-dual central path (IPOPT's eq. 16).

The filter is a fixed array of ``FILTER_SIZE`` pairs (empty entries are ``inf``), emptied whenever ``mu`` changes, as
IPOPT does; when full, the oldest pair is replaced. That bound is what lets the loop keep fixed shapes under ``jit``
and ``vmap``. The filter replaced an exact-penalty merit search (``phi_mu + nu ||g||_1``, Nocedal & Wright eq. 18.36)
that crawled on Rocket Landing (3000 iterations) and took 268 on Van der Pol (README.md has the measurements).

There is no restoration phase. Where IPOPT would enter it (the filter rejects every step down to ``alpha_min``, its
eq. 23), the search restarts from the full step on that merit function, and a step accepted there empties the filter;
if the merit cannot be decreased either, the solve ends, ``INFEASIBLE`` when the point is infeasible (the honest
failure the issue allows) and ``NOT_CONVERGED`` otherwise; so do three consecutive negligible steps (below
``1e-10 (1 + |x|)``) at an infeasible point, where bounds block every move towards feasibility and the
fraction-to-the-boundary rule shrinks the steps geometrically.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ...status import Status
from .kkt import factorize_with_inertia, solve
from .problem import Layout

__all__ = ["InteriorPointSolution", "WarmStart", "make_solve_fn"]

RUNNING = -1
MU_INIT, KAPPA_EPS, KAPPA_MU, THETA_MU, TAU_MIN, KAPPA_SIGMA, S_MAX = 0.1, 10.0, 0.2, 1.5, 0.99, 1e10, 100.0
ETA, MAX_TRIALS = 1e-4, 45
# The filter line search's constants, IPOPT's defaults (W&B 2006 sec. 2.3 and 3.1); FILTER_SIZE bounds the filter
# for a fixed-shape loop: when full, the oldest pair is replaced (the filter is reset at every change of mu, and
# between two changes the problems here add a few pairs).
GAMMA_THETA, GAMMA_PHI, GAMMA_ALPHA, DELTA, S_THETA, S_PHI = 1e-5, 1e-8, 0.05, 1.0, 1.1, 2.3
THETA_MIN_FACT, THETA_MAX_FACT, FILTER_SIZE = 1e-4, 1e4, 32
# A step below STALL_STEP (relative to |x|) at an infeasible point, STALL_COUNT times in a row, ends the solve as
# INFEASIBLE: the fraction-to-the-boundary rule shrinks every step towards bounds that block all progress.
STALL_STEP, STALL_COUNT = 1e-10, 3
EPS = float(np.finfo(np.float64).eps)
# A primal-dual warm start (IPOPT's warm_start_init_point): the barrier parameter it restarts from (the last solve's
# ~tol/10 would leave no room to re-centre when the active set moves) and the push off the bounds (relative).
WARM_MU, WARM_PUSH = 1e-6, 1e-9


class WarmStart(NamedTuple):
    """Where a solve starts, in the barrier problem's own terms: a cold start (:func:`make_solve_fn`'s ``cold``,
    IPOPT's defaults) or the end of an earlier solve (``InteriorPointSolution.warm``: its point, multipliers and
    scaling, restarted at ``mu = WARM_MU``). Every field is a float array, so a batch or a ``jnp.where`` between a
    cold and a warm start is one program; ``fresh`` (1.0 or 0.0) says to measure the scaling at the start."""

    x: jax.Array
    lam: jax.Array
    zl: jax.Array
    zu: jax.Array
    mu: jax.Array
    sigma: jax.Array
    row_scale: jax.Array
    fresh: jax.Array


class InteriorPointSolution(NamedTuple):
    """One solve's output (pure JAX; a batch has a leading axis on every field).

    ``z``, ``objective`` and ``multipliers`` are differentiable with respect to ``data`` in reverse mode (see
    :mod:`.implicit`); the rest is not.

    Attributes:
        z: the final iterate in the NLP's variables; objective: ``F(z)``.
        multipliers: constraint multipliers (IPOPT's sign: ``dF/dz + J^T y`` equals the bound multipliers' terms).
        bound_multipliers: ``z_l - z_u`` of the variable bounds, in units of ``dF/dz``.
        iterations: Newton steps taken; status: a :class:`~myriad.runtime.status.Status` as an integer.
        kkt_error: IPOPT's scaled optimality error ``E_0`` at ``z``; violation: the NLP's constraint violation.
        mu: the final barrier parameter.
        active_lower, active_upper: variables held at a bound (multiplier larger than the gap to it);
        active_rows: constraint rows held at a bound (equalities, and inequalities whose slack is held).
        warm: a :class:`WarmStart` from this solution, for the next solve of a nearby problem.
    """

    z: jax.Array
    objective: jax.Array
    multipliers: jax.Array
    bound_multipliers: jax.Array
    iterations: jax.Array
    status: jax.Array
    kkt_error: jax.Array
    violation: jax.Array
    mu: jax.Array
    active_lower: jax.Array
    active_upper: jax.Array
    active_rows: jax.Array
    warm: WarmStart


class _State(NamedTuple):
    x: jax.Array
    lam: jax.Array
    zl: jax.Array
    zu: jax.Array
    mu: jax.Array
    nu: jax.Array  # the merit's penalty (the fallback line search)
    theta_min: jax.Array  # the filter's thresholds on ||g||_1, fixed at the start (IPOPT's eq. 21 and 22)
    theta_max: jax.Array
    filter_theta: jax.Array  # the filter: FILTER_SIZE pairs (inf: empty), newest at filter_next - 1
    filter_phi: jax.Array
    filter_next: jax.Array
    delta_w: jax.Array
    k: jax.Array
    status: jax.Array
    kkt: jax.Array
    objective: jax.Array
    violation: jax.Array
    stalls: jax.Array  # consecutive iterations with a negligible step at an infeasible point
    sigma: jax.Array  # objective scale
    row_scale: jax.Array  # constraint row scales (solver's row order)


def _fraction_to_boundary(v, dv, tau):
    """The largest ``alpha`` in (0, 1] with ``v + alpha dv >= (1 - tau) v`` where ``v > 0`` (``v = 0``: no bound)."""
    limit = jnp.where((dv < 0) & (v > 0), -tau * v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.minimum(1.0, jnp.min(limit, initial=jnp.inf))


def make_solve_fn(layout: Layout, tol: float, constr_viol_tol: float, max_iter: int,
                  second_order_correction: bool = True) -> tuple[Callable[[Any, Any], InteriorPointSolution],
                                                                 Callable[[Any, Any], WarmStart]]:
    """``(solve, cold)``: the pure solve ``(data, start) -> InteriorPointSolution``, where ``start`` is the NLP's
    variables ``z0`` or a :class:`WarmStart`, and ``cold(data, z0) -> WarmStart``, IPOPT's default start from ``z0``
    (neither jitted; see the module docstring)."""
    n, m = layout.n, layout.m
    hl, hu = jnp.asarray(layout.has_lower), jnp.asarray(layout.has_upper)
    xl, xu = jnp.asarray(layout.x_lower), jnp.asarray(layout.x_upper)
    scale = jnp.asarray(layout.problem.scale)
    n_bounds = max(int(layout.has_lower.sum() + layout.has_upper.sum()), 1)
    mu_min = tol / 10.0

    def gaps(x):
        return jnp.where(hl, x - xl, 1.0), jnp.where(hu, xu - x, 1.0)

    def log_barrier(x):
        gl, gu = gaps(x)
        return jnp.sum(jnp.where(hl, jnp.log(gl), 0.0)) + jnp.sum(jnp.where(hu, jnp.log(gu), 0.0))

    def cold(data: Any, z0: Any) -> WarmStart:
        x0 = layout.start(jnp.asarray(z0) / scale, data)
        one = jnp.ones((), x0.dtype)
        return WarmStart(x0, jnp.zeros(m, x0.dtype), jnp.where(hl, 1.0, 0.0), jnp.where(hu, 1.0, 0.0), MU_INIT * one,
                         one, jnp.ones(m, x0.dtype), one)

    def solve_fn(data: Any, start: Any) -> InteriorPointSolution:
        ws = start if isinstance(start, WarmStart) else cold(data, start)
        # A warm point sits on its active bounds up to the barrier's ~mu: keep it (barely) inside.
        push = WARM_PUSH * (1.0 + jnp.maximum(jnp.abs(xl), jnp.abs(xu)))
        x0 = jnp.where(hl, jnp.maximum(ws.x, xl + push), ws.x)
        x0 = jnp.where(hu, jnp.minimum(x0, xu - push), x0)
        dtype = x0.dtype
        fresh = ws.fresh > 0.5

        def error(x, lam, zl, zu, grad, g, jac, mu):
            """IPOPT's E_mu (its eq. 5) with s_max = 100."""
            gl, gu = gaps(x)
            dual = grad + (jac.T @ lam if m else 0.0) - zl + zu
            compl = jnp.concatenate([jnp.where(hl, gl * zl - mu, 0.0), jnp.where(hu, gu * zu - mu, 0.0)])
            z_sum = jnp.sum(jnp.abs(zl)) + jnp.sum(jnp.abs(zu))
            s_d = jnp.maximum(S_MAX, (jnp.sum(jnp.abs(lam)) + z_sum) / (m + n_bounds)) / S_MAX
            s_c = jnp.maximum(S_MAX, z_sum / n_bounds) / S_MAX
            inf = lambda v: jnp.max(jnp.abs(v), initial=0.0)  # noqa: E731
            return jnp.maximum(jnp.maximum(inf(dual) / s_d, inf(g)), inf(compl) / s_c)

        def body(st: _State) -> _State:
            x, lam, zl, zu = st.x, st.lam, st.zl, st.zu
            y = layout.multipliers(lam, st.sigma, st.row_scale)
            f, c, grad_f, jac_c, hess = layout.derivatives(x[:n], y, data)
            # The scaling is IPOPT's, measured at the start (the first iteration's point; lam = 0 there).
            first_sigma, first_rows = layout.scaling(grad_f, jac_c)
            sigma = jnp.where((st.k == 0) & fresh, first_sigma, st.sigma)
            row_scale = jnp.where((st.k == 0) & fresh, first_rows, st.row_scale)
            pt = layout.point(x, f, c, grad_f, jac_c, hess, sigma, row_scale)
            finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(a)) for a in (pt.f, pt.grad, pt.g, pt.jac, pt.hess)]))
            kkt = error(x, lam, zl, zu, pt.grad, pt.g, pt.jac, 0.0)
            converged = finite & (kkt <= tol) & (pt.violation <= constr_viol_tol)
            stop = jnp.where(~finite, int(Status.NOT_FINITE), jnp.where(
                converged, int(Status.CONVERGED), jnp.where(st.k >= max_iter, int(Status.ITERATION_LIMIT), RUNNING)))

            def finish(_):
                # The iterate is final: no step, no line search (a cond, so a single solve skips their cost; under
                # vmap both branches run, as every member's step did before).
                return st._replace(status=stop.astype(st.status.dtype), kkt=kkt, objective=pt.objective,
                                   violation=pt.violation, sigma=sigma, row_scale=row_scale)

            def advance(_):
                # Barrier update (monotone): as many decreases as the current point allows.
                def decrease(mu):
                    return jnp.maximum(mu_min, jnp.minimum(KAPPA_MU * mu, mu**THETA_MU))

                mu = jax.lax.while_loop(
                    lambda mu_: (mu_ > mu_min) & (error(x, lam, zl, zu, pt.grad, pt.g, pt.jac, mu_) <= KAPPA_EPS * mu_),
                    decrease, st.mu)

                gl, gu = gaps(x)
                sig_l, sig_u = jnp.where(hl, zl / gl, 0.0), jnp.where(hu, zu / gu, 0.0)
                grad_phi = pt.grad - jnp.where(hl, mu / gl, 0.0) + jnp.where(hu, mu / gu, 0.0)
                factors, delta_w, inertia_ok = factorize_with_inertia(pt.hess, sig_l + sig_u, pt.jac, mu, st.delta_w)
                r1 = -(grad_phi + (pt.jac.T @ lam if m else 0.0))
                dx, dlam = solve(factors, pt.jac, r1, -pt.g)
                dzl = jnp.where(hl, mu / gl - zl - sig_l * dx, 0.0)
                dzu = jnp.where(hu, mu / gu - zu + sig_u * dx, 0.0)
                tau = jnp.maximum(TAU_MIN, 1.0 - mu)
                alpha_max = jnp.minimum(_fraction_to_boundary(jnp.where(hl, gl, 0.0), dx, tau),
                                        _fraction_to_boundary(jnp.where(hu, gu, 0.0), -dx, tau))
                alpha_z = jnp.minimum(_fraction_to_boundary(jnp.where(hl, zl, 0.0), dzl, tau),
                                      _fraction_to_boundary(jnp.where(hu, zu, 0.0), dzu, tau))

                # Filter line search (Wächter & Biegler 2006, sec. 2.3) on theta = ||g||_1 and the barrier objective.
                theta = jnp.sum(jnp.abs(pt.g))
                phi0 = pt.f - mu * log_barrier(x)
                slope = grad_phi @ dx
                theta_min = jnp.where(st.k == 0, THETA_MIN_FACT * jnp.maximum(1.0, theta), st.theta_min)
                theta_max = jnp.where(st.k == 0, THETA_MAX_FACT * jnp.maximum(1.0, theta), st.theta_max)
                # The filter holds only pairs made under the current mu: IPOPT resets it when mu changes.
                reset = mu != st.mu
                f_theta = jnp.where(reset, jnp.inf, st.filter_theta)
                f_phi = jnp.where(reset, jnp.inf, st.filter_phi)
                descent = slope < 0
                switching_ok = lambda a: descent & (a * (-slope) ** S_PHI > DELTA * theta**S_THETA)  # noqa: E731
                alpha_min = GAMMA_ALPHA * jnp.where(descent, jnp.minimum(
                    jnp.minimum(GAMMA_THETA, GAMMA_PHI * theta / jnp.where(descent, -slope, 1.0)),
                    jnp.where(theta <= theta_min,
                              DELTA * theta**S_THETA / jnp.where(descent, -slope, 1.0) ** S_PHI, jnp.inf)), GAMMA_THETA)
                tiny = jnp.max(jnp.abs(dx) / (1.0 + jnp.abs(x)), initial=0.0) < 10.0 * EPS
                slack = 10.0 * EPS * jnp.abs(phi0)
                # The fallback when the filter rejects every step down to alpha_min (where IPOPT would enter its
                # restoration phase): backtracking on the exact-penalty merit phi + nu ||g||_1, with nu large enough
                # for the step to be a descent direction (Nocedal & Wright, eq. 18.36); nu only grows.
                curvature = dx @ (factors.h_s @ dx)
                nu_req = (slope + 0.5 * jnp.maximum(curvature, 0.0)) / jnp.maximum(0.9 * theta, 1e-300)
                nu = jnp.where((theta > 0) & (st.nu < nu_req), nu_req + 1.0, st.nu)
                merit0 = phi0 + nu * theta

                def acceptable(alpha, theta_t, phi_t):
                    """(accepted, f-type: by Armijo under the switching condition, which leaves the filter as it is)."""
                    finite_t = jnp.isfinite(theta_t) & jnp.isfinite(phi_t)
                    f_type = (theta <= theta_min) & switching_ok(alpha)
                    armijo = phi_t <= phi0 + ETA * alpha * slope + slack
                    decrease = (theta_t <= (1.0 - GAMMA_THETA) * theta) | (phi_t <= phi0 - GAMMA_PHI * theta + slack)
                    outside = jnp.all((theta_t < f_theta) | (phi_t < f_phi))
                    ok = jnp.where(f_type, armijo, decrease) & outside & (theta_t <= theta_max) & finite_t
                    return ok, f_type

                def trial(ls):
                    j, _, _, _, _, g_first, theta_first, _, fallback = ls
                    alpha = alpha_max * 0.5 ** jnp.maximum(j - 1, 0).astype(dtype)
                    x_t, lam_t = x + alpha * dx, lam + alpha * dlam
                    if second_order_correction:
                        # Trial 1: the full step plus a correction for the constraints' curvature (IPOPT's eq. 27),
                        # taken only when the full step did not reduce the infeasibility. A cond, not a select: the
                        # correction's two solves would otherwise be paid on every trial of a long line search.
                        def corrected(_):
                            dx_c, dlam_c = solve(factors, pt.jac, r1, -(alpha_max * pt.g + g_first))
                            a_c = jnp.minimum(_fraction_to_boundary(jnp.where(hl, gl, 0.0), dx_c, tau),
                                              _fraction_to_boundary(jnp.where(hu, gu, 0.0), -dx_c, tau))
                            return x + a_c * dx_c, lam + a_c * dlam_c

                        use_soc = (j == 1) & ~fallback & jnp.all(jnp.isfinite(g_first)) & (theta_first >= theta)
                        x_t, lam_t = jax.lax.cond(use_soc, corrected, lambda _: (x_t, lam_t), None)
                    f_t, g_t = layout.values(x_t, data, sigma, row_scale)
                    theta_t = jnp.sum(jnp.abs(g_t))
                    phi_t = f_t - mu * log_barrier(x_t)
                    ok, f_type = acceptable(alpha, theta_t, phi_t)
                    by_merit = jnp.isfinite(phi_t + theta_t) & (
                        phi_t + nu * theta_t <= merit0 + ETA * alpha * (slope - nu * theta) + slack)
                    ok = jnp.where(fallback, by_merit, ok)
                    g_first = jnp.where(j == 0, g_t, g_first)
                    theta_first = jnp.where(j == 0, theta_t, theta_first)
                    # The filter gives up below alpha_min (after the full step and its correction): restart from the
                    # full step on the merit.
                    give_up = ~fallback & ~ok & (j >= 1) & (
                        (alpha_max * 0.5 ** j.astype(dtype) < alpha_min) | (j + 1 >= MAX_TRIALS))
                    j_next = jnp.where(give_up, 2, j + 1)
                    return j_next, ok, x_t, lam_t, alpha, g_first, theta_first, f_type, fallback | give_up

                first_trial = 0 if second_order_correction else 1
                ls0 = (jnp.array(first_trial), tiny, x + alpha_max * dx, lam + alpha_max * dlam, alpha_max,
                       jnp.zeros(m, dtype), jnp.inf * jnp.ones((), dtype), jnp.array(True), jnp.array(False))
                _, accepted, x_new, lam_new, alpha, _, _, f_type, fallback = jax.lax.while_loop(
                    lambda ls: ~ls[1] & (ls[0] < MAX_TRIALS), trial, ls0)
                # An h-type step adds the current pair, with its margins, to the filter; a step by the merit empties it
                # (as IPOPT's restoration phase ends with a point the old filter may reject).
                grow = accepted & ~tiny & ~f_type & ~fallback
                slot = st.filter_next % FILTER_SIZE
                f_theta = jnp.where(grow, f_theta.at[slot].set((1.0 - GAMMA_THETA) * theta), f_theta)
                f_phi = jnp.where(grow, f_phi.at[slot].set(phi0 - GAMMA_PHI * theta), f_phi)
                f_theta = jnp.where(fallback & accepted, jnp.inf, f_theta)
                f_phi = jnp.where(fallback & accepted, jnp.inf, f_phi)
                filter_next = jnp.where(reset | (fallback & accepted), 0, st.filter_next) + grow.astype(jnp.int32)

                zl_new, zu_new = zl + alpha_z * dzl, zu + alpha_z * dzu
                gl_new, gu_new = gaps(x_new)
                zl_new = jnp.where(hl, jnp.clip(zl_new, mu / (KAPPA_SIGMA * gl_new), KAPPA_SIGMA * mu / gl_new), 0.0)
                zu_new = jnp.where(hu, jnp.clip(zu_new, mu / (KAPPA_SIGMA * gu_new), KAPPA_SIGMA * mu / gu_new), 0.0)

                infeasible = pt.violation > constr_viol_tol
                negligible = jnp.max(jnp.abs(x_new - x) / (1.0 + jnp.abs(x)), initial=0.0) <= STALL_STEP
                stalls = jnp.where(infeasible & negligible, st.stalls + 1, 0).astype(st.stalls.dtype)
                failed = ~accepted | ~inertia_ok | (stalls >= STALL_COUNT)
                failure = jnp.where(infeasible, int(Status.INFEASIBLE), int(Status.NOT_CONVERGED))
                status = jnp.where(stop != RUNNING, stop, jnp.where(failed, failure, RUNNING)).astype(st.status.dtype)
                move = status == RUNNING
                pick = lambda new, old: jnp.where(move, new, old)  # noqa: E731
                return _State(pick(x_new, x), pick(lam_new, lam), pick(zl_new, zl), pick(zu_new, zu), pick(mu, st.mu),
                              pick(nu, st.nu), pick(theta_min, st.theta_min), pick(theta_max, st.theta_max),
                              pick(f_theta, st.filter_theta), pick(f_phi, st.filter_phi),
                              pick(filter_next, st.filter_next), pick(delta_w, st.delta_w),
                              st.k + move.astype(st.k.dtype), status, kkt, pt.objective, pt.violation, stalls, sigma,
                              row_scale)

            return jax.lax.cond(stop == RUNNING, advance, finish, None)

        one = jnp.ones((), dtype)
        empty = jnp.full(FILTER_SIZE, jnp.inf, dtype)
        int0 = jnp.array(0, jnp.int32)
        st0 = _State(x0, ws.lam, jnp.where(hl, ws.zl, 0.0), jnp.where(hu, ws.zu, 0.0), ws.mu, one, one, one,
                     empty, empty, int0, 0.0 * one, int0, jnp.array(RUNNING, jnp.int32), jnp.inf * one, jnp.nan * one,
                     jnp.inf * one, int0, ws.sigma, ws.row_scale)
        st = jax.lax.while_loop(lambda s: s.status == RUNNING, body, st0)

        gl, gu = gaps(st.x)
        held_l, held_u = hl & (st.zl > gl), hu & (st.zu > gu)
        y = layout.multipliers(st.lam, st.sigma, st.row_scale)
        slack_held = (held_l | held_u)[n:]
        rows_active = jnp.zeros(m, bool).at[layout.rows].set(
            jnp.concatenate([jnp.ones(layout.eq.size, bool), slack_held])) if m else jnp.zeros(0, bool)
        return InteriorPointSolution(
            z=st.x[:n] * scale, objective=st.objective, multipliers=y,
            bound_multipliers=(st.zl - st.zu)[:n] / (st.sigma * scale), iterations=st.k, status=st.status,
            kkt_error=st.kkt, violation=st.violation, mu=st.mu, active_lower=held_l[:n], active_upper=held_u[:n],
            active_rows=rows_active,
            warm=WarmStart(st.x, st.lam, st.zl, st.zu, jnp.maximum(st.mu, WARM_MU), st.sigma, st.row_scale,
                           jnp.zeros((), dtype)))

    return solve_fn, cold
