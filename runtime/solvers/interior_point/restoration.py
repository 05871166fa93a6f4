r"""The feasibility restoration phase (Wächter & Biegler 2006, sec. 3.3), as iterations of the main ``while_loop``.

**Why.** When the filter rejects every trial step down to ``alpha_min`` the Newton direction is useless for the
filter, and backtracking on a merit function along it crawls (Predator-Prey: the solver-code measurements note).

**What.** From the point ``x_R`` where the search failed, the iterations solve the elastic feasibility problem

.. math::
    \min_{x, p, n}\ \rho \sum_i (p_i + n_i) + \frac{\zeta}{2} \|D_R (x - x_R)\|_2^2
    \quad\text{s.t.}\quad g(x) - p + n = 0,\quad x^l \le x \le x^u,\quad p, n \ge 0,

with IPOPT's ``rho = 1000``, ``zeta = sqrt(mu_R)`` and ``D_R = diag(min(1, 1 / |x_R|))`` on the NLP's variables (not
on the slacks), by the same primal-dual barrier iteration: its own barrier parameter ``mu_R`` (from ``max(mu,
||g||_inf)``, monotone), its own filter, fraction to the boundary and bound multipliers for ``p`` and ``n``. ``p``
and ``n`` start at the minimiser of ``rho (p + n) - mu_R (ln p + ln n)`` with ``p - n = g(x_R)`` (IPOPT's eq. 33),
so the elastic constraint starts satisfied. Eliminating ``dp``, ``dn`` and the bound multipliers leaves the main
Newton system with the constraints' Hessian (the derivatives' ``objective_weight`` is 0: the one call per iteration
serves both phases) plus ``zeta D_R^2`` and the diagonal (2,2) block ``-(Sigma_p^{-1} + Sigma_n^{-1})``. That block
is negative definite, so the system has inertia ``(n_x, m, 0)`` exactly when ``H_s + A^T (Sigma_p^{-1} +
Sigma_n^{-1})^{-1} A`` is positive definite: one Cholesky factorisation per inertia attempt, whatever the number of
rows.

The phase ends, as IPOPT's does, when a point reduces the infeasibility ``||g||_inf`` to ``kappa_resto = 0.9`` of the
entry point's and is acceptable to the main filter, to which the entry point was added (so the main iteration cannot
return to it). The main iteration then continues with IPOPT's multipliers: constraint multipliers 0, bound
multipliers from a Newton step for complementarity over the whole restoration (all 1 if one exceeds 1e3).

**Failure is honest.** If the restoration problem itself converges (its optimality error below ``tol``) at a point
the main filter still rejects, the point is a local minimiser of the infeasibility: ``INFEASIBLE`` (``NOT_CONVERGED``
when it is feasible after all). So does a failed restoration line search (IPOPT would start a restoration of the
restoration) and a failed inertia correction. Restoration iterations count towards ``max_iter``.

Fixed shapes: the phase's state (:class:`Restoration`) is part of the loop's state whether or not the phase is
active, and a restoration iteration is the body of a ``while_loop`` of at most one pass, taken while ``active``:
under ``vmap`` a ``cond`` runs both branches for every member (a fifth to a quarter of a vmapped Mould Fungicide
batch's throughput), a loop only while some member needs it.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve

from ...compilation.programs import register_namedtuple
from .kkt import regularized_cholesky
from .rules import (
    FILTER_SIZE,
    KAPPA_EPS,
    KAPPA_SIGMA,
    MAX_TRIALS,
    TAU_MIN,
    Bounds,
    acceptable,
    add_pair,
    alpha_min,
    decrease_mu,
    fraction_to_boundary,
    scaled_error,
)

__all__ = ["Restoration", "RestorationPhase"]

# IPOPT's resto_penalty_parameter, required_infeasibility_reduction, bound_mult_reset_threshold, and the restoration
# filter's theta_max_fact (1e8, raised from the main 1e4) and theta_min_fact on a problem that starts feasible.
RHO, KAPPA_RESTO, BOUND_MULT_RESET = 1e3, 0.9, 1e3
THETA_MAX_R, THETA_MIN_R = 1e8, 1e-4


@register_namedtuple  # part of the loop's state, which crosses between a solve's two programs (loop.py)
class Restoration(NamedTuple):
    """The restoration phase's state; while ``active``, the loop's ``lam``, ``zl`` and ``zu`` are the restoration
    problem's multipliers (of ``g - p + n = 0`` and of the bounds of ``x``)."""

    active: jax.Array
    p: jax.Array  # (m,) the elastic variables and their bound multipliers
    n: jax.Array
    zp: jax.Array
    zn: jax.Array
    x_ref: jax.Array  # the entry point x_R and its bound multipliers (the main problem's)
    zl_ref: jax.Array
    zu_ref: jax.Array
    mu: jax.Array  # the restoration problem's barrier parameter
    delta_w: jax.Array  # its last Hessian regularisation
    filter_theta: jax.Array  # its filter
    filter_phi: jax.Array
    filter_count: jax.Array
    inf_ref: jax.Array  # ||g(x_R)||_inf


class _Step(NamedTuple):
    """A restoration iteration's barrier parameter, Newton step (with the elastic variables' and the bound
    multipliers'), its fraction-to-the-boundary limits and the line search's reference values."""

    mu: jax.Array
    zeta: jax.Array
    delta_w: jax.Array
    inertia_ok: jax.Array
    stationary: jax.Array  # the restoration problem's optimality error is below tol
    dx: jax.Array
    dlam: jax.Array
    dp: jax.Array
    dn: jax.Array
    dzl: jax.Array
    dzu: jax.Array
    dzp: jax.Array
    dzn: jax.Array
    alpha_max: jax.Array
    alpha_z: jax.Array
    slope: jax.Array


class RestorationPhase:
    """The restoration phase of one barrier problem: ``idle(x0)``, an inactive :class:`Restoration`; ``enter(x, g,
    zl, zu, mu) -> (Restoration, lam, zl, zu)``; ``step(st, pt, data) -> (st, failed)``, one iteration on the loop's
    state at the point ``pt`` (the constraints' Hessian alone), leaving the phase when the main filter accepts."""

    def __init__(self, layout, tol: float, constr_viol_tol: float, mu_min: float):
        self.layout, self.tol, self.constr_viol_tol, self.mu_min = layout, tol, constr_viol_tol, mu_min
        self.n, self.m = layout.n, layout.m
        self.bounds = Bounds(layout)
        self.n_bounds = self.bounds.count + 2 * self.m
        self.on_w = jnp.arange(layout.n_x) < self.n  # the proximity term leaves the slacks free
        # The system stage by stage (riccati.py, banded.py) or dense: the same system, the same schedule.
        ric = layout.riccati or layout.banded
        self.factorize, self.solve = (ric.factorize_weighted, ric.solve_weighted) if ric else (_factorize, _solve)

    def idle(self, x0):
        # Ones, not zeros: a vmapped pass computes the inactive members' step too (and discards it); keep it finite.
        ones, dtype = jnp.ones(self.m, x0.dtype), x0.dtype
        empty = jnp.full(FILTER_SIZE, jnp.inf, dtype)
        zero = jnp.zeros((), dtype)
        return Restoration(jnp.array(False), ones, ones, ones, ones, x0, x0, x0, zero, zero, empty, empty,
                           jnp.array(0, jnp.int32), zero)

    def enter(self, x, g, zl, zu, mu):
        hl, hu = self.bounds.hl, self.bounds.hu
        mu_r = jnp.maximum(mu, jnp.max(jnp.abs(g), initial=0.0))
        # n = a + sqrt(a^2 + b) without the cancellation at large positive g (IPOPT's eq. 33)
        a, b = mu_r / (2.0 * RHO) - 0.5 * g, g * mu_r / (2.0 * RHO)
        r = jnp.sqrt(a * a + b)
        n_ = jnp.where(a >= 0, a + r, b / jnp.where(a >= 0, 1.0, r - a))
        p = g + n_
        empty = jnp.full(FILTER_SIZE, jnp.inf, x.dtype)
        rs = Restoration(jnp.array(True), p, n_, mu_r / p, mu_r / n_, x, zl, zu, mu_r, jnp.zeros_like(mu_r), empty,
                         empty, jnp.array(0, jnp.int32), jnp.max(jnp.abs(g), initial=0.0))
        return rs, jnp.zeros_like(g), jnp.where(hl, jnp.minimum(RHO, zl), 0.0), jnp.where(hu, jnp.minimum(RHO, zu), 0.0)

    def step(self, st, pt, data):
        # The state and point travel in the carry: computed from loop invariants, the pass would be hoisted out of
        # the loop by XLA and run for every member after all.
        def once(carry):
            st_, pt_, _, _ = carry
            new_, failed_ = self._iteration(st_, pt_, data)
            return new_, pt_, failed_, jnp.array(True)

        new, _, failed, _ = jax.lax.while_loop(lambda c: c[0].rs.active & ~c[3], once,
                                               (st, pt, jnp.array(False), jnp.array(False)))
        return new, failed

    def _proximity(self, rs):
        """``D_R^2``: the proximity term's weights (on the NLP's variables, not the slacks)."""
        return jnp.where(self.on_w, jnp.minimum(1.0, 1.0 / jnp.abs(rs.x_ref)) ** 2, 0.0)

    def _objective(self, rs, mu, zeta, x_, p_, n__):
        """The restoration problem's barrier objective at ``(x, p, n)``."""
        dev = x_ - rs.x_ref
        return (RHO * jnp.sum(p_ + n__) + 0.5 * zeta * jnp.sum(self._proximity(rs) * dev * dev)
                - mu * (self.bounds.log_barrier(x_) + jnp.sum(jnp.log(p_)) + jnp.sum(jnp.log(n__))))

    def _error(self, st, pt, mu_):
        """IPOPT's E_mu of the restoration problem (its eq. 5), at zeta = sqrt of the current mu."""
        rs, x, lam, zl, zu, bounds = st.rs, st.x, st.lam, st.zl, st.zu, self.bounds
        p, n_, zp, zn, g, jac = rs.p, rs.n, rs.zp, rs.zn, pt.g, pt.jac
        gl, gu = bounds.gaps(x)
        dual_x = jnp.sqrt(rs.mu) * self._proximity(rs) * (x - rs.x_ref) + jac.T @ lam - zl + zu
        dual = jnp.concatenate([dual_x, RHO - lam - zp, RHO + lam - zn])
        compl = jnp.concatenate([jnp.where(bounds.hl, gl * zl - mu_, 0.0), jnp.where(bounds.hu, gu * zu - mu_, 0.0),
                                 p * zp - mu_, n_ * zn - mu_])
        z_sum = jnp.sum(jnp.abs(zl)) + jnp.sum(jnp.abs(zu)) + jnp.sum(zp) + jnp.sum(zn)
        return scaled_error(dual, g - p + n_, compl, lam, z_sum, self.n_bounds)

    def _direction(self, st, pt) -> _Step:
        """The barrier update and the Newton step of the restoration problem, ``dp``, ``dn`` and the bound
        multipliers' eliminated (the module docstring), with its fraction-to-the-boundary limits."""
        rs, x, lam, zl, zu, bounds, mu_min = st.rs, st.x, st.lam, st.zl, st.zu, self.bounds, self.mu_min
        p, n_, zp, zn, g, jac = rs.p, rs.n, rs.zp, rs.zn, pt.g, pt.jac
        hl, hu = bounds.hl, bounds.hu
        gl, gu = bounds.gaps(x)
        d2 = self._proximity(rs)
        # A stationary point of the restoration problem that the main filter did not accept: locally infeasible.
        stationary = self._error(st, pt, 0.0) <= self.tol
        mu = jax.lax.while_loop(lambda mu_: (mu_ > mu_min) & (self._error(st, pt, mu_) <= KAPPA_EPS * mu_),
                                lambda mu_: decrease_mu(mu_, mu_min), rs.mu)
        zeta = jnp.sqrt(mu)
        sig_l, sig_u = jnp.where(hl, zl / gl, 0.0), jnp.where(hu, zu / gu, 0.0)
        sp, sn = zp / p, zn / n_
        dinv = sp * sn / (sp + sn)  # the inverse of the eliminated (2,2) block
        grad_x = zeta * d2 * (x - rs.x_ref) - jnp.where(hl, mu / gl, 0.0) + jnp.where(hu, mu / gu, 0.0)
        a_p, a_n = RHO - lam - mu / p, RHO + lam - mu / n_
        r1 = -(grad_x + jac.T @ lam)
        r2 = -(g - p + n_) - a_p / sp + a_n / sn
        factors, delta_w, inertia_ok = self.factorize(pt.hess, zeta * d2 + sig_l + sig_u, jac, dinv, rs.delta_w)
        dx, dlam = self.solve(factors, jac, dinv, r1, r2)
        dp, dn = (dlam - a_p) / sp, (-a_n - dlam) / sn
        dzl = jnp.where(hl, mu / gl - zl - sig_l * dx, 0.0)
        dzu = jnp.where(hu, mu / gu - zu + sig_u * dx, 0.0)
        dzp, dzn = mu / p - zp - sp * dp, mu / n_ - zn - sn * dn
        tau = jnp.maximum(TAU_MIN, 1.0 - mu)
        alpha_max = jnp.minimum(bounds.step_to_boundary(x, dx, tau), jnp.minimum(
            fraction_to_boundary(p, dp, tau), fraction_to_boundary(n_, dn, tau)))
        alpha_z = jnp.minimum(
            jnp.minimum(fraction_to_boundary(jnp.where(hl, zl, 0.0), dzl, tau),
                        fraction_to_boundary(jnp.where(hu, zu, 0.0), dzu, tau)),
            jnp.minimum(fraction_to_boundary(zp, dzp, tau), fraction_to_boundary(zn, dzn, tau)))
        slope = grad_x @ dx + (RHO - mu / p) @ dp + (RHO - mu / n_) @ dn
        return _Step(mu, zeta, delta_w, inertia_ok, stationary, dx, dlam, dp, dn, dzl, dzu, dzp, dzn, alpha_max,
                     alpha_z, slope)

    def _search(self, st, pt, d: _Step, data):
        """The filter line search on the restoration problem (its own filter, emptied when its mu changes):
        ``(accepted, alpha, f_type, f_t, g_t, theta, phi0, reset, f_theta, f_phi)``."""
        rs, x, dtype = st.rs, st.x, st.x.dtype
        p, n_, g = rs.p, rs.n, pt.g
        theta = jnp.sum(jnp.abs(g - p + n_))
        phi0 = self._objective(rs, d.mu, d.zeta, x, p, n_)
        reset = d.mu != rs.mu
        f_theta = jnp.where(reset, jnp.inf, rs.filter_theta)
        f_phi = jnp.where(reset, jnp.inf, rs.filter_phi)
        a_min = alpha_min(theta, d.slope, THETA_MIN_R)

        def trial(ls):
            j = ls[0]
            alpha = d.alpha_max * 0.5 ** j.astype(dtype)
            x_t, p_t, n_t = x + alpha * d.dx, p + alpha * d.dp, n_ + alpha * d.dn
            f_t, g_t = self.layout.values(x_t, data, st.sigma, st.row_scale)
            ok, f_type = acceptable(alpha, jnp.sum(jnp.abs(g_t - p_t + n_t)),
                                    self._objective(rs, d.mu, d.zeta, x_t, p_t, n_t), theta, phi0, d.slope,
                                    THETA_MIN_R, THETA_MAX_R, f_theta, f_phi)
            give_up = ~ok & ((0.5 * alpha < a_min) | (j + 1 >= MAX_TRIALS))
            return j + 1, ok, give_up, alpha, f_type, f_t, g_t

        ls0 = (jnp.array(0), jnp.array(False), ~d.inertia_ok, d.alpha_max, jnp.array(False), pt.f, g)
        _, accepted, _, alpha, f_type, f_t, g_t = jax.lax.while_loop(lambda ls: ~ls[1] & ~ls[2], trial, ls0)
        return accepted, alpha, f_type, f_t, g_t, theta, phi0, reset, f_theta, f_phi

    def _iteration(self, st, pt, data):
        """One restoration iteration: ``(the next state, failed)``."""
        d = self._direction(st, pt)
        accepted, alpha, f_type, f_t, g_t, theta, phi0, reset, f_theta, f_phi = self._search(st, pt, d, data)
        rs, x, lam, zl, zu, bounds, mu = st.rs, st.x, st.lam, st.zl, st.zu, self.bounds, d.mu
        x_new, p_new, n_new = x + alpha * d.dx, rs.p + alpha * d.dp, rs.n + alpha * d.dn
        zl_new, zu_new = bounds.clip_multipliers(x_new, zl + d.alpha_z * d.dzl, zu + d.alpha_z * d.dzu, mu)
        zp_new = jnp.clip(rs.zp + d.alpha_z * d.dzp, mu / (KAPPA_SIGMA * p_new), KAPPA_SIGMA * mu / p_new)
        zn_new = jnp.clip(rs.zn + d.alpha_z * d.dzn, mu / (KAPPA_SIGMA * n_new), KAPPA_SIGMA * mu / n_new)
        grow = accepted & ~f_type
        f_theta, f_phi = add_pair(f_theta, f_phi, rs.filter_count, grow, theta, phi0)
        count = jnp.where(reset, 0, rs.filter_count) + grow.astype(jnp.int32)

        # Back to the main iteration (IPOPT's RestoFilterConvergenceCheck): enough less infeasible, and acceptable to
        # the main filter (which holds the entry point with its margins) for the main barrier objective.
        inf = lambda v: jnp.max(jnp.abs(v), initial=0.0)  # noqa: E731
        theta_o, phi_o = jnp.sum(jnp.abs(g_t)), f_t - st.mu * bounds.log_barrier(x_new)
        done = accepted & (inf(g_t) <= jnp.maximum(KAPPA_RESTO * rs.inf_ref, min(self.tol, self.constr_viol_tol))) & (
            jnp.all((theta_o < st.filter_theta) | (phi_o < st.filter_phi)))
        zl_main, zu_main = _reset_bound_multipliers(bounds, rs, x_new, st.mu)
        rs_new = rs._replace(active=~done, p=p_new, n=n_new, zp=zp_new, zn=zn_new, mu=mu, delta_w=d.delta_w,
                             filter_theta=f_theta, filter_phi=f_phi, filter_count=count)
        new = st._replace(x=x_new, lam=jnp.where(done, 0.0, lam + alpha * d.dlam),
                          zl=jnp.where(done, zl_main, zl_new), zu=jnp.where(done, zu_main, zu_new), rs=rs_new)
        return new, d.stationary | ~d.inertia_ok | ~accepted


def _reset_bound_multipliers(bounds: Bounds, rs: Restoration, x, mu) -> tuple[Any, Any]:
    """The main bound multipliers after the phase: a Newton step for complementarity from the entry point's, with the
    whole change of ``x`` as the primal step, kept inside by the fraction to the boundary; all 1 if one exceeds
    ``BOUND_MULT_RESET`` (IPOPT's ``MinC_1NrmRestorationPhase``)."""
    (gl0, gu0), (gl, gu) = bounds.gaps(rs.x_ref), bounds.gaps(x)
    dzl = jnp.where(bounds.hl, (mu + (gl0 - gl) * rs.zl_ref) / gl0 - rs.zl_ref, 0.0)
    dzu = jnp.where(bounds.hu, (mu + (gu0 - gu) * rs.zu_ref) / gu0 - rs.zu_ref, 0.0)
    tau = jnp.maximum(TAU_MIN, 1.0 - mu)
    alpha = jnp.minimum(fraction_to_boundary(rs.zl_ref, dzl, tau), fraction_to_boundary(rs.zu_ref, dzu, tau))
    zl, zu = rs.zl_ref + alpha * dzl, rs.zu_ref + alpha * dzu
    large = jnp.maximum(jnp.max(zl, initial=0.0), jnp.max(zu, initial=0.0)) > BOUND_MULT_RESET
    return (jnp.where(bounds.hl, jnp.where(large, 1.0, zl), 0.0), jnp.where(bounds.hu, jnp.where(large, 1.0, zu), 0.0))


def _factorize(hess, d, jac, dinv, delta_w_last):
    """IPOPT's inertia correction on ``H_s + A^T diag(dinv) A``, ``H_s = hess + diag(d)`` (see the module docstring):
    ``((lower Cholesky factor, H_s with the accepted delta_w), delta_w, ok)``."""
    h_s = hess + jnp.diag(d)
    chol, delta_w, ok = regularized_cholesky(h_s + jac.T @ (dinv[:, None] * jac), delta_w_last)
    eye = jnp.eye(h_s.shape[0], dtype=h_s.dtype)
    return (chol, h_s + delta_w * eye), delta_w, ok


def _solve(factors, jac, dinv, r1, r2):
    """``(d_x, d_lambda)`` of ``[H_s A^T; A -diag(1/dinv)] (d_x, d_lambda) = (r1, r2)``, one step of refinement."""
    chol, h_s = factors

    def once(s1, s2):
        dx = cho_solve((chol, True), s1 + jac.T @ (dinv * s2))
        return dx, dinv * (jac @ dx - s2)

    dx, dl = once(r1, r2)
    cx, cl = once(h_s @ dx + jac.T @ dl - r1, jac @ dx - dl / dinv - r2)
    return dx - cx, dl - cl
