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
6. backtracks on the exact-penalty merit ``phi_mu(x) + nu ||g(x)||_1`` (Armijo, ``eta = 1e-4``), trying one
   second-order correction after a rejected full step (against the Maratos effect); a non-finite trial is rejected;
7. keeps ``z`` within ``[mu / (1e10 gap), 1e10 mu / gap]`` of the primal-dual central path (IPOPT's eq. 16).

Why a merit function and not IPOPT's filter: its state is two scalars (``nu`` and the merit), which fits a fixed-shape
``while_loop`` and a ``vmap`` with no filter list to bound or reset; the second-order correction and the
inertia-corrected steps keep what the filter's flexibility buys on these problems (measured in README.md).
``nu`` only grows, to ``(grad phi^T d + max(d^T H d, 0) / 2) / (0.9 ||g||_1) + 1`` when smaller (Nocedal & Wright,
eq. 18.36), which makes every Newton step a descent direction of the merit.

There is no restoration phase: a line search that cannot decrease the merit ends the solve, ``INFEASIBLE`` when the
point is infeasible (the honest failure the issue allows) and ``NOT_CONVERGED`` otherwise; so do three consecutive
negligible steps (below ``1e-10 (1 + |x|)``) at an infeasible point, where bounds block every move towards
feasibility and the fraction-to-the-boundary rule shrinks the steps geometrically.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ...status import Status
from .kkt import factorize_with_inertia, solve
from .problem import Layout

__all__ = ["InteriorPointSolution", "make_solve_fn"]

RUNNING = -1
MU_INIT, KAPPA_EPS, KAPPA_MU, THETA_MU, TAU_MIN, KAPPA_SIGMA, S_MAX = 0.1, 10.0, 0.2, 1.5, 0.99, 1e10, 100.0
ETA, MAX_TRIALS = 1e-4, 45
# A step below STALL_STEP (relative to |x|) at an infeasible point, STALL_COUNT times in a row, ends the solve as
# INFEASIBLE: the fraction-to-the-boundary rule shrinks every step towards bounds that block all progress.
STALL_STEP, STALL_COUNT = 1e-10, 3
EPS = float(np.finfo(np.float64).eps)


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


class _State(NamedTuple):
    x: jax.Array
    lam: jax.Array
    zl: jax.Array
    zu: jax.Array
    mu: jax.Array
    nu: jax.Array
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
                  second_order_correction: bool = True) -> Callable[[Any, Any], InteriorPointSolution]:
    """The pure solve ``(data, z0) -> InteriorPointSolution`` (not jitted; see the module docstring)."""
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

    def solve_fn(data: Any, z0: Any) -> InteriorPointSolution:
        w0 = jnp.asarray(z0) / scale
        x0 = layout.start(w0, data)
        dtype = x0.dtype

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
            sigma = jnp.where(st.k == 0, first_sigma, st.sigma)
            row_scale = jnp.where(st.k == 0, first_rows, st.row_scale)
            pt = layout.point(x, f, c, grad_f, jac_c, hess, sigma, row_scale)
            finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(a)) for a in (pt.f, pt.grad, pt.g, pt.jac, pt.hess)]))
            kkt = error(x, lam, zl, zu, pt.grad, pt.g, pt.jac, 0.0)
            converged = finite & (kkt <= tol) & (pt.violation <= constr_viol_tol)
            stop = jnp.where(~finite, int(Status.NOT_FINITE), jnp.where(
                converged, int(Status.CONVERGED), jnp.where(st.k >= max_iter, int(Status.ITERATION_LIMIT), RUNNING)))

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

            # Merit penalty large enough for descent, then the directional derivative of the merit.
            theta = jnp.sum(jnp.abs(pt.g))
            slope = grad_phi @ dx
            curvature = dx @ (factors.h_s @ dx)
            nu_req = (slope + 0.5 * jnp.maximum(curvature, 0.0)) / jnp.maximum(0.9 * theta, 1e-300)
            nu = jnp.where((theta > 0) & (st.nu < nu_req), nu_req + 1.0, st.nu)
            derivative = slope - nu * theta
            merit0 = pt.f - mu * log_barrier(x) + nu * theta

            def merit(x_, f_, g_):
                return f_ - mu * log_barrier(x_) + nu * jnp.sum(jnp.abs(g_))

            tiny = jnp.max(jnp.abs(dx) / (1.0 + jnp.abs(x)), initial=0.0) < 10.0 * EPS
            slack = 10.0 * EPS * jnp.abs(merit0)

            def trial(ls):
                j, _, _, _, _, g_first = ls
                alpha = alpha_max * 0.5 ** jnp.maximum(j - 1, 0).astype(dtype)
                x_t, lam_t = x + alpha * dx, lam + alpha * dlam
                if second_order_correction:
                    # Trial 1: the full step plus a correction for the constraints' curvature (IPOPT's eq. 27).
                    c_soc = alpha_max * pt.g + g_first
                    dx_c, dlam_c = solve(factors, pt.jac, r1, -c_soc)
                    a_c = jnp.minimum(_fraction_to_boundary(jnp.where(hl, gl, 0.0), dx_c, tau),
                                      _fraction_to_boundary(jnp.where(hu, gu, 0.0), -dx_c, tau))
                    use_soc = (j == 1) & jnp.all(jnp.isfinite(g_first))
                    x_t = jnp.where(use_soc, x + a_c * dx_c, x_t)
                    lam_t = jnp.where(use_soc, lam + a_c * dlam_c, lam_t)
                f_t, g_t = layout.values(x_t, data, sigma, row_scale)
                m_t = merit(x_t, f_t, g_t)
                ok = jnp.isfinite(m_t) & (m_t <= merit0 + ETA * alpha * derivative + slack)
                g_first = jnp.where(j == 0, g_t, g_first)
                return j + 1, ok, x_t, lam_t, alpha, g_first

            first_trial = 0 if second_order_correction else 1
            ls0 = (jnp.array(first_trial), tiny, x + alpha_max * dx, lam + alpha_max * dlam, alpha_max,
                   jnp.zeros(m, dtype))
            _, accepted, x_new, lam_new, alpha, _ = jax.lax.while_loop(
                lambda ls: ~ls[1] & (ls[0] < MAX_TRIALS), trial, ls0)

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
                          pick(nu, st.nu), pick(delta_w, st.delta_w), st.k + move.astype(st.k.dtype), status, kkt,
                          pt.objective, pt.violation, stalls, sigma, row_scale)

        zeros = lambda k: jnp.zeros(k, dtype)  # noqa: E731
        one = jnp.ones((), dtype)
        st0 = _State(x0, zeros(m), jnp.where(hl, 1.0, 0.0), jnp.where(hu, 1.0, 0.0), MU_INIT * one, one,
                     0.0 * one, jnp.array(0, jnp.int32), jnp.array(RUNNING, jnp.int32), jnp.inf * one,
                     jnp.nan * one, jnp.inf * one, jnp.array(0, jnp.int32), one, jnp.ones(m, dtype))
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
            active_rows=rows_active)

    return solve_fn
