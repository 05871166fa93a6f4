r"""The iteration: one ``lax.while_loop`` of primal-dual barrier Newton steps (Wächter & Biegler 2006, Algorithm A).

With ``x = (w, s)``, equality residuals ``g(x) = 0`` and bound multipliers ``z_l, z_u`` (see :mod:`.problem`), each
iteration

1. evaluates ``sigma F``, its gradient, ``g``, ``A = dg/dx`` and the exact Hessian ``W`` of ``sigma F + lambda^T g``;
2. stops when the scaled optimality error ``E_0`` (IPOPT's eq. 5) is at most ``tol`` and the NLP's own violation at
   most ``constr_viol_tol``;
3. decreases the barrier parameter while ``E_mu <= 10 mu`` (monotone Fiacco-McCormick rule, :mod:`.rules`);
4. solves the Newton system with inertia correction (:mod:`.kkt`) and recovers the bound multipliers' steps;
5. limits the steps by the fraction-to-the-boundary rule (``tau = max(0.99, 1 - mu)``), primal and dual apart;
6. backtracks with IPOPT's filter line search on (``theta = ||g||_1``, barrier objective ``phi_mu``), with one
   second-order correction after a rejected full step that did not reduce ``theta`` (the Maratos effect);
7. keeps ``z`` within ``[mu / (1e10 gap), 1e10 mu / gap]`` of the primal-dual central path (IPOPT's eq. 16).

The filter is a fixed array of ``FILTER_SIZE`` pairs, emptied whenever ``mu`` changes, as IPOPT does.

Where the filter rejects every step down to ``alpha_min`` (IPOPT's eq. 23), or ``STALL_COUNT`` negligible steps in a
row leave the point infeasible, the current point joins the filter and the next iterations are IPOPT's feasibility
restoration phase (:mod:`.restoration`), in this same loop: the Hessian of the constraints alone (the derivatives'
objective weight is 0), an elastic feasibility problem, back to this iteration at a point the filter accepts. A failed
restoration ends the solve (the statuses: ``InteriorPoint``), as does a failed search at a point too feasible to
restore (IPOPT's rule) and ``STALL_COUNT`` negligible restoration steps in a row.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ...compilation.programs import register_namedtuple
from ...status import Status
from ..stepper import Staged, Stepper
from . import kkt
from .problem import Layout
from .restoration import Restoration, RestorationPhase
from .rules import (
    EPS,
    FILTER_SIZE,
    KAPPA_EPS,
    MAX_TRIALS,
    TAU_MIN,
    THETA_MAX_FACT,
    THETA_MIN_FACT,
    Bounds,
    acceptable,
    add_pair,
    alpha_min,
    decrease_mu,
    fraction_to_boundary,
    scaled_error,
)

__all__ = ["InteriorPointSolution", "InteriorPointStepper", "WarmStart"]

RUNNING = -1
# The status of a solve by the program without the restoration phase (InteriorPointStepper.first) that needs it: the
# program with it (InteriorPointStepper.rest) continues from the state it stopped at. Never a solve's final status.
NEEDS_RESTORATION = -2
MU_INIT = 0.1
# A step below STALL_STEP (relative to |x|) at an infeasible point, STALL_COUNT times in a row, sends the main phase to
# the restoration phase and ends the restoration phase as INFEASIBLE: the fraction-to-the-boundary rule shrinks every
# step towards bounds that block all progress.
STALL_STEP, STALL_COUNT = 1e-10, 3
# A primal-dual warm start (IPOPT's warm_start_init_point): the barrier parameter it restarts from (the last solve's
# ~tol/10 would leave no room to re-centre when the active set moves) and the push off the bounds (relative).
WARM_MU, WARM_PUSH = 1e-6, 1e-9


@register_namedtuple  # it crosses a stored program's boundary
class WarmStart(NamedTuple):
    """Where a solve starts, in the barrier problem's own terms: a cold start (:meth:`InteriorPointStepper.cold`,
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


@register_namedtuple
class InteriorPointSolution(NamedTuple):
    """One solve's output (pure JAX; a batch has a leading axis on every field); ``z``, ``objective`` and
    ``multipliers`` are differentiable with respect to ``data`` in reverse mode (:mod:`..implicit`), the rest not.

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


@register_namedtuple  # a first stage's state crosses into the second stage's program (InteriorPointStepper.rest)
class LoopState(NamedTuple):
    x: jax.Array
    lam: jax.Array
    zl: jax.Array
    zu: jax.Array
    mu: jax.Array
    rs: Restoration  # the restoration phase (active or not)
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
    fresh: jax.Array  # measure the scaling at the first iteration (a cold start)


class _Direction(NamedTuple):
    """A main iteration's barrier parameter, Newton step and its fraction-to-the-boundary limits."""

    mu: jax.Array
    factors: Any
    delta_w: jax.Array
    inertia_ok: jax.Array
    r1: jax.Array
    dx: jax.Array
    dlam: jax.Array
    dzl: jax.Array
    dzu: jax.Array
    tau: jax.Array
    alpha_max: jax.Array
    alpha_z: jax.Array
    slope: jax.Array  # the barrier objective's directional derivative along dx


class _Filter(NamedTuple):
    """The filter line search's reference at the current point (Wächter & Biegler 2006, sec. 2.3)."""

    theta: jax.Array  # ||g||_1
    phi0: jax.Array  # the barrier objective
    theta_min: jax.Array
    theta_max: jax.Array
    reset: jax.Array  # mu changed: the filter is emptied
    f_theta: jax.Array
    f_phi: jax.Array
    a_min: jax.Array
    tiny: jax.Array  # the step is negligible against x


class InteriorPointStepper:
    """The interior-point solve of one :class:`~.problem.Layout` and configuration as a
    :class:`~myriad.runtime.solvers.stepper.Stepper` (:attr:`stepper`; built once). A step evaluates the point
    (:meth:`_evaluate`), stops there or takes a restoration iteration or a main one (:meth:`_advance`)."""

    def __init__(self, layout: Layout, tol: float, constr_viol_tol: float, max_iter: int,
                 second_order_correction: bool = True):
        self.layout, self.n, self.m = layout, layout.n, layout.m
        self.tol, self.constr_viol_tol, self.max_iter = tol, constr_viol_tol, max_iter
        self.second_order_correction = second_order_correction
        self.bounds = Bounds(layout)
        self.scale = jnp.asarray(layout.problem.scale)
        self.mu_min = tol / 10.0
        self.restoration = RestorationPhase(layout, tol, constr_viol_tol, self.mu_min)
        # The Newton system: dense (kkt.py) or stage by stage (riccati.py, banded.py), one interface.
        structured = layout.riccati or layout.banded
        self.factorize_with_inertia, self.newton_solve = (
            (structured.factorize_with_inertia, structured.solve) if structured
            else (kkt.factorize_with_inertia, kkt.solve))
        self.stepper = Stepper(self.begin, self.step, self.running, self.end)
        # The same solve in two programs, the second compiled only where a solve needs the restoration phase (about
        # a third of the program's compile time; lax.cond would compile both branches): the first stops a solve
        # where it would enter the phase, the second resumes from that state with the phase in its loop.
        first = Stepper(self.begin, lambda data, st: self._step(data, st, False), self.running,
                        lambda data, st: (self.end(data, st), st))
        self.staged = Staged(first, Stepper(self.resume, self.step, self.running, self.end),
                             lambda out: np.asarray(out.status) == NEEDS_RESTORATION)

    def cold(self, data: Any, z0: Any) -> WarmStart:
        """IPOPT's default start from the NLP's variables ``z0``."""
        b, m = self.bounds, self.m
        x0 = self.layout.start(jnp.asarray(z0) / self.scale, data)
        one = jnp.ones((), x0.dtype)
        return WarmStart(x0, jnp.zeros(m, x0.dtype), jnp.where(b.hl, 1.0, 0.0), jnp.where(b.hu, 1.0, 0.0),
                         MU_INIT * one, one, jnp.ones(m, x0.dtype), one)

    def error(self, x, lam, zl, zu, grad, g, jac, mu):
        """IPOPT's E_mu (its eq. 5) with s_max = 100."""
        b = self.bounds
        gl, gu = b.gaps(x)
        dual = grad + (jac.T @ lam if self.m else 0.0) - zl + zu
        compl = jnp.concatenate([jnp.where(b.hl, gl * zl - mu, 0.0), jnp.where(b.hu, gu * zu - mu, 0.0)])
        return scaled_error(dual, g, compl, lam, jnp.sum(jnp.abs(zl)) + jnp.sum(jnp.abs(zu)), b.count)

    def _evaluate(self, data: Any, st: LoopState) -> tuple[Any, jax.Array, jax.Array, jax.Array, jax.Array]:
        """``(point, sigma, row_scale, kkt, stop)`` at the state's iterate: its derivatives (with the scaling
        measured here at a fresh start), the optimality error and the status it stops with (``RUNNING``: none)."""
        layout, n = self.layout, self.n
        x, fresh = st.x, st.fresh
        y = layout.multipliers(st.lam, st.sigma, st.row_scale)
        # One derivative program for both phases: the restoration phase weighs the objective by 0.
        f, c, grad_f, jac_c, hess = layout.derivatives(x[:n], y, data, jnp.where(st.rs.active, 0.0, 1.0))
        # The scaling is IPOPT's, measured at the start (the first iteration's point; lam = 0 there).
        first_sigma, first_rows = layout.scaling(grad_f, jac_c)
        sigma = jnp.where((st.k == 0) & fresh, first_sigma, st.sigma)
        row_scale = jnp.where((st.k == 0) & fresh, first_rows, st.row_scale)
        pt = layout.point(x, f, c, grad_f, jac_c, hess, sigma, row_scale)
        finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(
            (pt.f, pt.grad, pt.g, pt.jac, pt.hess))]))
        kkt = self.error(x, st.lam, st.zl, st.zu, pt.grad, pt.g, pt.jac, 0.0)
        converged = finite & ~st.rs.active & (kkt <= self.tol) & (pt.violation <= self.constr_viol_tol)
        stop = jnp.where(~finite, int(Status.NOT_FINITE), jnp.where(
            converged, int(Status.CONVERGED), jnp.where(st.k >= self.max_iter, int(Status.ITERATION_LIMIT), RUNNING)))
        return pt, sigma, row_scale, kkt, stop

    def step(self, data: Any, st: LoopState) -> LoopState:
        """One iteration (or, for a member that has stopped, its final values)."""
        return self._step(data, st, True)

    def _step(self, data: Any, st: LoopState, restores: bool) -> LoopState:
        """:meth:`step`; without the restoration phase in the program (``restores`` False: :attr:`first`), an
        iteration that would enter it stops the solve at its start with the status ``NEEDS_RESTORATION``."""
        pt, sigma, row_scale, kkt, stop = self._evaluate(data, st)

        def finish(_):
            # The iterate is final: no step, no line search (a cond, so a single solve skips their cost; under
            # vmap both branches run, as every member's step did before).
            return st._replace(status=stop.astype(st.status.dtype), kkt=kkt, objective=pt.objective,
                               violation=pt.violation, sigma=sigma, row_scale=row_scale)

        def iterate(_):
            return self._iterate(data, st, pt, sigma, row_scale, kkt, restores)

        return jax.lax.cond(stop == RUNNING, iterate, finish, None)

    def _iterate(self, data: Any, st: LoopState, pt: Any, sigma, row_scale, kkt, restores: bool) -> LoopState:
        """A restoration iteration (while that phase is active) or a main one, then the stall count and status."""
        x = st.x

        def restore(_):
            return self.restoration.step(st, pt, data)

        def advance(_):
            return self._advance(data, st, pt, sigma, row_scale, restores)

        if restores and self.m:
            new, failed = jax.lax.cond(st.rs.active, restore, lambda _: advance(_)[:2], None)
        else:
            new, failed, needs = advance(None)
        infeasible = pt.violation > self.constr_viol_tol
        negligible = _negligible(new.x, x)
        entered = new.rs.active & ~st.rs.active
        # The restoration phase counts its own stalls from its entry (where x does not move).
        stalls = jnp.where(entered, 0, jnp.where(infeasible & negligible, st.stalls + 1, 0))
        failed = failed | (stalls >= STALL_COUNT)
        failure = jnp.where(infeasible, int(Status.INFEASIBLE), int(Status.NOT_CONVERGED))
        status = jnp.where(failed, failure, RUNNING).astype(st.status.dtype)
        move = status == RUNNING
        out = jax.tree.map(lambda a, b: jnp.where(move, a, b), new, st)
        out = out._replace(k=st.k + move.astype(st.k.dtype), status=status, kkt=kkt, objective=pt.objective,
                           violation=pt.violation, stalls=stalls.astype(st.stalls.dtype), sigma=sigma,
                           row_scale=row_scale)
        if restores or not self.m:
            return out
        # The iteration is left to the program with the restoration phase (:attr:`rest`), from its start.
        stopped = st._replace(status=jnp.full_like(st.status, NEEDS_RESTORATION))
        return jax.tree.map(lambda a, b: jnp.where(needs, a, b), stopped, out)

    def _direction(self, st: LoopState, pt: Any) -> _Direction:
        """The barrier update (monotone: as many decreases as the current point allows), the Newton step with
        inertia correction and the bound multipliers' steps, and the fraction-to-the-boundary limits."""
        b, m, mu_min = self.bounds, self.m, self.mu_min
        x, lam, zl, zu = st.x, st.lam, st.zl, st.zu
        mu = jax.lax.while_loop(
            lambda mu_: (mu_ > mu_min) & (self.error(x, lam, zl, zu, pt.grad, pt.g, pt.jac, mu_) <= KAPPA_EPS * mu_),
            lambda mu_: decrease_mu(mu_, mu_min), st.mu)
        hl, hu = b.hl, b.hu
        gl, gu = b.gaps(x)
        sig_l, sig_u = jnp.where(hl, zl / gl, 0.0), jnp.where(hu, zu / gu, 0.0)
        grad_phi = pt.grad - jnp.where(hl, mu / gl, 0.0) + jnp.where(hu, mu / gu, 0.0)
        r1 = -(grad_phi + (pt.jac.T @ lam if m else 0.0))
        factors, delta_w, inertia_ok = self.factorize_with_inertia(pt.hess, sig_l + sig_u, pt.jac, mu, st.delta_w,
                                                                   r1)
        dx, dlam = self.newton_solve(factors, pt.jac, r1, -pt.g, presolved=True)
        dzl = jnp.where(hl, mu / gl - zl - sig_l * dx, 0.0)
        dzu = jnp.where(hu, mu / gu - zu + sig_u * dx, 0.0)
        tau = jnp.maximum(TAU_MIN, 1.0 - mu)
        alpha_max = b.step_to_boundary(x, dx, tau)
        alpha_z = jnp.minimum(fraction_to_boundary(jnp.where(hl, zl, 0.0), dzl, tau),
                              fraction_to_boundary(jnp.where(hu, zu, 0.0), dzu, tau))
        return _Direction(mu, factors, delta_w, inertia_ok, r1, dx, dlam, dzl, dzu, tau, alpha_max, alpha_z,
                          grad_phi @ dx)

    def _filter(self, st: LoopState, pt: Any, d: _Direction) -> _Filter:
        """The filter line search's reference at the current point: ``theta``, ``phi``, the filter's thresholds
        (fixed at the first iteration) and the filter itself, emptied when ``mu`` changed (as IPOPT does)."""
        x = st.x
        theta = jnp.sum(jnp.abs(pt.g))
        phi0 = pt.f - d.mu * self.bounds.log_barrier(x)
        theta_min = jnp.where(st.k == 0, THETA_MIN_FACT * jnp.maximum(1.0, theta), st.theta_min)
        theta_max = jnp.where(st.k == 0, THETA_MAX_FACT * jnp.maximum(1.0, theta), st.theta_max)
        reset = d.mu != st.mu
        f_theta = jnp.where(reset, jnp.inf, st.filter_theta)
        f_phi = jnp.where(reset, jnp.inf, st.filter_phi)
        a_min = alpha_min(theta, d.slope, theta_min)
        tiny = jnp.max(jnp.abs(d.dx) / (1.0 + jnp.abs(x)), initial=0.0) < 10.0 * EPS
        return _Filter(theta, phi0, theta_min, theta_max, reset, f_theta, f_phi, a_min, tiny)

    def _search(self, data: Any, st: LoopState, pt: Any, d: _Direction, flt: _Filter, sigma, row_scale):
        """IPOPT's filter line search from ``x`` along the Newton step: ``(accepted, x_new, lam_new, alpha,
        f_type)``."""
        x, lam, m, dtype = st.x, st.lam, self.m, st.x.dtype
        soc = self.second_order_correction

        def trial(ls):
            j, _, _, x_t, lam_t, _, g_first, theta_first, _ = ls
            alpha = d.alpha_max * 0.5 ** jnp.maximum(j - 1, 0).astype(dtype)
            x_t, lam_t = x + alpha * d.dx, lam + alpha * d.dlam
            if soc:
                # Trial 1: the full step plus a correction for the constraints' curvature (IPOPT's eq. 27),
                # taken only when the full step did not reduce the infeasibility. A loop of at most one pass,
                # not a cond: under vmap a cond is a select, and the correction's solves would be paid on
                # every trial of every member; a loop runs only while some member needs it.
                def corrected(c):
                    dx_c, dlam_c = self.newton_solve(d.factors, pt.jac, d.r1, -(d.alpha_max * pt.g + c[3]),
                                                     presolved=True)
                    a_c = self.bounds.step_to_boundary(x, dx_c, d.tau)
                    return jnp.array(False), x + a_c * dx_c, lam + a_c * dlam_c, c[3]

                use_soc = (j == 1) & jnp.all(jnp.isfinite(g_first)) & (theta_first >= flt.theta)
                _, x_t, lam_t, _ = jax.lax.while_loop(lambda c: c[0], corrected, (use_soc, x_t, lam_t, g_first))
            f_t, g_t = self.layout.values(x_t, data, sigma, row_scale)
            theta_t = jnp.sum(jnp.abs(g_t))
            ok, f_type = acceptable(alpha, theta_t, f_t - d.mu * self.bounds.log_barrier(x_t), flt.theta, flt.phi0,
                                    d.slope, flt.theta_min, flt.theta_max, flt.f_theta, flt.f_phi)
            g_first = jnp.where(j == 0, g_t, g_first)
            theta_first = jnp.where(j == 0, theta_t, theta_first)
            # The search gives up below alpha_min (after the full step and its correction).
            give_up = ~ok & (j >= 1) & (
                (d.alpha_max * 0.5 ** j.astype(dtype) < flt.a_min) | (j + 1 >= MAX_TRIALS))
            return j + 1, ok, give_up, x_t, lam_t, alpha, g_first, theta_first, f_type

        first_trial = 0 if soc else 1
        ls0 = (jnp.array(first_trial), flt.tiny, jnp.array(False), x + d.alpha_max * d.dx, lam + d.alpha_max * d.dlam,
               d.alpha_max, jnp.zeros(m, dtype), jnp.inf * jnp.ones((), dtype), jnp.array(True))
        _, accepted, _, x_new, lam_new, alpha, _, _, f_type = jax.lax.while_loop(
            lambda ls: ~ls[1] & ~ls[2] & (ls[0] < MAX_TRIALS), trial, ls0)
        return accepted, x_new, lam_new, alpha, f_type

    def _advance(self, data: Any, st: LoopState, pt: Any, sigma, row_scale,
                 restores: bool = True) -> tuple[LoopState, jax.Array, jax.Array]:
        """A main iteration: ``(the next state, failed, restore)``; where the line search fails, the restoration
        phase starts from the current point, which joins the filter (``restores`` False: ``restore`` says only that
        it would, and the state is not the restoration's)."""
        m, tol = self.m, self.tol
        x, zl, zu = st.x, st.zl, st.zu
        d = self._direction(st, pt)
        flt = self._filter(st, pt, d)
        accepted, x_new, lam_new, alpha, f_type = self._search(data, st, pt, d, flt, sigma, row_scale)
        # The STALL_COUNT-th negligible step in a row at an infeasible point goes to the restoration phase as a failed
        # search does: ending the solve there reported INFEASIBLE with restoration never tried (Predator-Prey on
        # multiple shooting, banded: delta_w ~1e12 where Sigma ~1e21 blurs the pivots' inertia, steps ~1e-12).
        stalled = (accepted & (st.stalls + 1 >= STALL_COUNT) & (pt.violation > self.constr_viol_tol)
                   & _negligible(x_new, x))
        # Every step rejected: the restoration phase, unless the point is too feasible for it (IPOPT's rule).
        restore = (~accepted | stalled) & d.inertia_ok & (
            (flt.theta > 1e-2 * tol) | (pt.violation > 0.1 * self.constr_viol_tol))
        restore = restore if m else jnp.array(False)
        # An h-type step, and the point the restoration phase starts from, add the pair to the filter.
        grow = (accepted & ~flt.tiny & ~f_type) | restore
        f_theta, f_phi = add_pair(flt.f_theta, flt.f_phi, st.filter_next, grow, flt.theta, flt.phi0)
        filter_next = jnp.where(flt.reset, 0, st.filter_next) + grow.astype(jnp.int32)

        zl_new, zu_new = self.bounds.clip_multipliers(x_new, zl + d.alpha_z * d.dzl, zu + d.alpha_z * d.dzu, d.mu)
        if restores:
            rs, lam_r, zl_r, zu_r = self.restoration.enter(x, pt.g, zl, zu, d.mu)
            pick = lambda new, old: jnp.where(restore, new, old)  # noqa: E731
            x_new, lam_new, rs = pick(x, x_new), pick(lam_r, lam_new), jax.tree.map(pick, rs, st.rs)
            zl_new, zu_new = pick(zl_r, zl_new), pick(zu_r, zu_new)
        else:
            rs = st.rs
        new = st._replace(x=x_new, lam=lam_new, zl=zl_new, zu=zu_new, mu=d.mu, rs=rs, theta_min=flt.theta_min,
                          theta_max=flt.theta_max, filter_theta=f_theta, filter_phi=f_phi, filter_next=filter_next,
                          delta_w=d.delta_w)
        return new, ~(accepted | restore) | ~d.inertia_ok, restore

    def begin(self, data: Any, start: Any) -> LoopState:
        """The state before the first iteration, from ``z0`` (IPOPT's default start) or a :class:`WarmStart`."""
        ws = start if isinstance(start, WarmStart) else self.cold(data, start)
        hl, hu, xl, xu = self.bounds.hl, self.bounds.hu, self.bounds.xl, self.bounds.xu
        # A warm point sits on its active bounds up to the barrier's ~mu: keep it (barely) inside.
        push = WARM_PUSH * (1.0 + jnp.maximum(jnp.abs(xl), jnp.abs(xu)))
        x0 = jnp.where(hl, jnp.maximum(ws.x, xl + push), ws.x)
        x0 = jnp.where(hu, jnp.minimum(x0, xu - push), x0)
        one = jnp.ones((), x0.dtype)
        empty = jnp.full(FILTER_SIZE, jnp.inf, x0.dtype)
        int0 = jnp.array(0, jnp.int32)
        rs = self.restoration.idle(x0)
        return LoopState(x0, ws.lam, jnp.where(hl, ws.zl, 0.0), jnp.where(hu, ws.zu, 0.0), ws.mu, rs, one, one,
                      empty, empty, int0, 0.0 * one, int0, jnp.array(RUNNING, jnp.int32), jnp.inf * one,
                      jnp.nan * one, jnp.inf * one, int0, ws.sigma, ws.row_scale, ws.fresh > 0.5)

    def resume(self, data: Any, st: LoopState) -> LoopState:
        """A state that :attr:`staged`'s first program stopped for the restoration phase, running again (any other
        stopped state stays stopped)."""
        return st._replace(status=jnp.where(st.status == NEEDS_RESTORATION, RUNNING, st.status).astype(st.status.dtype))

    def running(self, st: LoopState) -> jax.Array:
        return st.status == RUNNING

    def end(self, data: Any, st: LoopState) -> InteriorPointSolution:
        layout, n, m, scale, b = self.layout, self.n, self.m, self.scale, self.bounds
        gl, gu = b.gaps(st.x)
        held_l, held_u = b.hl & (st.zl > gl), b.hu & (st.zu > gu)
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
                           jnp.zeros((), st.x.dtype)))


def _negligible(x_new, x) -> jax.Array:
    """Whether the step from ``x`` to ``x_new`` is below ``STALL_STEP`` relative to ``|x|`` in every entry."""
    return jnp.max(jnp.abs(x_new - x) / (1.0 + jnp.abs(x)), initial=0.0) <= STALL_STEP
