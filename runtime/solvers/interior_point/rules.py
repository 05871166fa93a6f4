r"""The step rules shared by the main iteration (:mod:`.loop`) and the restoration phase (:mod:`.restoration`), which
apply them to different barrier problems: the bounds' barrier, the monotone barrier update, the fraction to the
boundary, and IPOPT's filter line search (Wächter & Biegler 2006, sec. 2.3).

A trial point's pair (``theta``, the infeasibility ``||g||_1``, and ``phi``, the barrier objective) is accepted when
the filter does not dominate it and it decreases ``theta`` or ``phi`` enough, or, near feasibility under the switching
condition, by Armijo on ``phi`` (an f-type step, which leaves the filter as it is). The filter is a fixed array of
``FILTER_SIZE`` pairs (empty entries are ``inf``); when full, the oldest pair is replaced. That bound is what lets the
loop keep fixed shapes under ``jit`` and ``vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Bounds", "decrease_mu", "fraction_to_boundary", "alpha_min", "acceptable", "add_pair", "inertia_schedule",
           "residual_ratio", "condition_bound", "scaled_error", "regularized", "certified"]

# IPOPT's barrier defaults: the monotone update (kappa_epsilon, kappa_mu, theta_mu), tau_min, kappa_Sigma and s_max.
KAPPA_EPS, KAPPA_MU, THETA_MU, TAU_MIN, KAPPA_SIGMA, S_MAX = 10.0, 0.2, 1.5, 0.99, 1e10, 100.0
# IPOPT's defaults (W&B 2006 sec. 2.3 and 3.1); FILTER_SIZE bounds the filter for a fixed-shape loop (it is reset at
# every change of mu, and between two changes the problems here add a few pairs).
ETA, MAX_TRIALS = 1e-4, 45
GAMMA_THETA, GAMMA_PHI, GAMMA_ALPHA, DELTA, S_THETA, S_PHI = 1e-5, 1e-8, 0.05, 1.0, 1.1, 2.3
THETA_MIN_FACT, THETA_MAX_FACT, FILTER_SIZE = 1e-4, 1e4, 32
EPS = float(np.finfo(np.float64).eps)
# The inertia correction (both phases, dense and stage-wise): IPOPT's first_hessian_perturbation,
# min/max_hessian_perturbation, perturb_inc_fact(_first), perturb_dec_fact, jacobian_regularization_value and
# _exponent; the certificate's retries of rho (at rho0 * 1e4 and rho0 * 1e8, see kkt.py) and the attempts' limit.
DELTA_W_FIRST, DELTA_W_MIN, DELTA_W_MAX = 1e-4, 1e-20, 1e40
GROW_FIRST, GROW, SHRINK = 100.0, 8.0, 1.0 / 3.0
DELTA_C_BAR, DELTA_C_EXPONENT = 1e-8, 0.25
RHO_RETRY, RHO_RETRIES = 1e4, 2
MAX_ATTEMPTS = 60


class Bounds:
    """The finite bounds of ``x`` (the :class:`~.problem.Layout`'s) and their logarithmic barrier."""

    def __init__(self, layout):
        self.hl, self.hu = jnp.asarray(layout.has_lower), jnp.asarray(layout.has_upper)
        self.xl, self.xu = jnp.asarray(layout.x_lower), jnp.asarray(layout.x_upper)
        self.count = max(int(layout.has_lower.sum() + layout.has_upper.sum()), 1)

    def gaps(self, x):
        return jnp.where(self.hl, x - self.xl, 1.0), jnp.where(self.hu, self.xu - x, 1.0)

    def log_barrier(self, x):
        gl, gu = self.gaps(x)
        return jnp.sum(jnp.where(self.hl, jnp.log(gl), 0.0)) + jnp.sum(jnp.where(self.hu, jnp.log(gu), 0.0))

    def step_to_boundary(self, x, dx, tau):
        """The primal fraction-to-the-boundary step from ``x`` along ``dx``."""
        gl, gu = self.gaps(x)
        return jnp.minimum(fraction_to_boundary(jnp.where(self.hl, gl, 0.0), dx, tau),
                           fraction_to_boundary(jnp.where(self.hu, gu, 0.0), -dx, tau))

    def clip_multipliers(self, x, zl, zu, mu):
        """``z`` kept within ``[mu / (kappa_Sigma gap), kappa_Sigma mu / gap]`` (IPOPT's eq. 16)."""
        gl, gu = self.gaps(x)
        return (jnp.where(self.hl, jnp.clip(zl, mu / (KAPPA_SIGMA * gl), KAPPA_SIGMA * mu / gl), 0.0),
                jnp.where(self.hu, jnp.clip(zu, mu / (KAPPA_SIGMA * gu), KAPPA_SIGMA * mu / gu), 0.0))


def scaled_error(dual, primal, compl, lam, z_sum, count):
    """IPOPT's optimality error E_mu (its eq. 5, s_max = 100) from the dual, primal and complementarity residuals,
    ``lam`` the constraint multipliers and ``z_sum`` the 1-norm of the ``count`` bound multipliers."""
    inf = lambda v: jnp.max(jnp.abs(v), initial=0.0)  # noqa: E731
    s_d = jnp.maximum(S_MAX, (jnp.sum(jnp.abs(lam)) + z_sum) / (lam.shape[0] + count)) / S_MAX
    s_c = jnp.maximum(S_MAX, z_sum / count) / S_MAX
    return jnp.maximum(jnp.maximum(inf(dual) / s_d, inf(primal)), inf(compl) / s_c)


def decrease_mu(mu, mu_min):
    """One monotone barrier decrease, ``max(mu_min, min(kappa_mu mu, mu^theta_mu))``."""
    return jnp.maximum(mu_min, jnp.minimum(KAPPA_MU * mu, mu**THETA_MU))


def fraction_to_boundary(v, dv, tau):
    """The largest ``alpha`` in (0, 1] with ``v + alpha dv >= (1 - tau) v`` where ``v > 0`` (``v = 0``: no bound)."""
    limit = jnp.where((dv < 0) & (v > 0), -tau * v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.minimum(1.0, jnp.min(limit, initial=jnp.inf))


def _switching(alpha, slope, theta):
    return (slope < 0) & (alpha * (-slope) ** S_PHI > DELTA * theta**S_THETA)


def alpha_min(theta, slope, theta_min):
    """The step below which the search gives up (IPOPT's eq. 23)."""
    descent = slope < 0
    down = jnp.where(descent, -slope, 1.0)
    return GAMMA_ALPHA * jnp.where(descent, jnp.minimum(
        jnp.minimum(GAMMA_THETA, GAMMA_PHI * theta / down),
        jnp.where(theta <= theta_min, DELTA * theta**S_THETA / down**S_PHI, jnp.inf)), GAMMA_THETA)


def acceptable(alpha, theta_t, phi_t, theta, phi0, slope, theta_min, theta_max, f_theta, f_phi):
    """(accepted, f-type: by Armijo under the switching condition, which leaves the filter as it is) for the trial
    pair ``(theta_t, phi_t)`` at step ``alpha`` from ``(theta, phi0)`` with directional derivative ``slope``."""
    slack = 10.0 * EPS * jnp.abs(phi0)
    finite_t = jnp.isfinite(theta_t) & jnp.isfinite(phi_t)
    f_type = (theta <= theta_min) & _switching(alpha, slope, theta)
    armijo = phi_t <= phi0 + ETA * alpha * slope + slack
    decrease = (theta_t <= (1.0 - GAMMA_THETA) * theta) | (phi_t <= phi0 - GAMMA_PHI * theta + slack)
    outside = jnp.all((theta_t < f_theta) | (phi_t < f_phi))
    ok = jnp.where(f_type, armijo, decrease) & outside & (theta_t <= theta_max) & finite_t
    return ok, f_type


def add_pair(f_theta, f_phi, count, grow, theta, phi0) -> tuple[jax.Array, jax.Array]:
    """The filter with the pair ``(theta, phi0)``, with its margins, added where ``grow``, in slot ``count`` modulo the
    size (pairs added so far: the oldest goes when full)."""
    slot = count % FILTER_SIZE
    f_theta = jnp.where(grow, f_theta.at[slot].set((1.0 - GAMMA_THETA) * theta), f_theta)
    f_phi = jnp.where(grow, f_phi.at[slot].set(phi0 - GAMMA_PHI * theta), f_phi)
    return f_theta, f_phi


def inertia_schedule(k, delta_w, delta_w_last, first_grown):
    """IPOPT's ``delta_w`` for inertia attempt ``k`` after ``delta_w`` at attempt ``k - 1``: 0 before ``first_grown``,
    then ``1e-4`` (or a third of the last iteration's), growing 100x (8x after an earlier correction)."""
    start = jnp.where(delta_w_last > 0, jnp.maximum(DELTA_W_MIN, SHRINK * delta_w_last), DELTA_W_FIRST)
    grown = delta_w * jnp.where(delta_w_last > 0, GROW, GROW_FIRST)
    return jnp.where(k < first_grown, 0.0, jnp.where(k == first_grown, start, grown))


def regularized(factorize, delta_w_last, dtype, init=None):
    """``(factors, delta_w, ok)`` of ``factorize(delta_w) -> (factors, ok)`` at the least ``delta_w`` of IPOPT's
    schedule from 0 for which it succeeds (one factorisation an attempt), where positive definiteness alone certifies
    the inertia. ``init``: placeholder factors for the loop's carry (None: zeros of the factors' shapes)."""
    def attempt(a):
        k, delta_w, _, _ = a
        factors, ok = factorize(delta_w)
        grown = inertia_schedule(k + 1, delta_w, delta_w_last, 1)
        return jnp.where(ok, k, k + 1), jnp.where(ok, delta_w, grown), ok, factors

    _, delta_w, ok, factors = _attempts(attempt, (jnp.array(0), jnp.zeros((), dtype), jnp.array(False), init))
    return factors, delta_w, ok


def certified(factorize, rho0, m, mu, delta_w_last, dtype, init=None, retries=RHO_RETRIES):
    """IPOPT's inertia correction (Wächter & Biegler 2006, Algorithm IC) on the Cholesky certificate of :mod:`.kkt`,
    for either form of the Newton system: ``factorize(k, delta_w, rho, delta_c) -> (factors, H_rho ok, S ok)`` at
    attempt ``k``. ``delta_w = 0`` first, at ``rho0``, ``10^4 rho0`` and ``10^8 rho0``, then ``delta_w`` from ``1e-4``
    (or a third of the last iteration's), growing 100x (8x after a previous correction) up to ``1e40``; a
    rank-deficient ``A`` (``S`` fails while ``H_rho`` holds) gets ``delta_c = 1e-8 mu^(1/4)`` at the same
    ``delta_w``. ``init`` as for :func:`regularized`; ``retries``: the attempts at larger ``rho`` (0 where the
    factorisation's inertia is exact and ``rho`` plays no part: :mod:`.banded`). Returns ``(factors, delta_w, ok)``."""
    # Attempts 0..retries keep delta_w = 0 (rho, then larger); no retries for rho when there is no A.
    first_grown = 1 + retries if m else 1

    def attempt(a):
        k, delta_w, delta_c, _, _ = a
        rho = rho0 * RHO_RETRY ** jnp.minimum(k, retries).astype(dtype)
        rho = jnp.where(delta_c > 0, jnp.minimum(rho, 1e-2 / jnp.maximum(delta_c, 1e-300)), rho)
        factors, ok_h, ok_s = factorize(k, delta_w, rho, delta_c)
        # S fails alone: A is (numerically) rank deficient; regularise it and retry the same delta_w.
        rank_deficient = ok_h & ~ok_s & (delta_c == 0)
        delta_c = jnp.where(rank_deficient, DELTA_C_BAR * mu**DELTA_C_EXPONENT, delta_c)
        done = ok_h & ok_s
        advance = ~done & ~rank_deficient
        delta_w = jnp.where(advance, inertia_schedule(k + 1, delta_w, delta_w_last, first_grown), delta_w)
        return jnp.where(advance, k + 1, k), delta_w, delta_c, done, factors

    zero = jnp.zeros((), dtype)
    _, delta_w, _, done, factors = _attempts(attempt, (jnp.array(0), zero, zero, jnp.array(False), init))
    return factors, delta_w, done


def _attempts(attempt, start):
    """The ``lax.while_loop`` of ``attempt`` on ``(k, delta_w, ..., done, factors)`` until done or out of attempts."""
    if start[-1] is None:
        # Zeros of the factors' shapes: the loop always runs its first attempt. (Running that attempt before the loop
        # put a second copy of the factorisation in the program: a third of a vmapped Epidemic batch's XLA input.)
        shapes = jax.eval_shape(attempt, start)[-1]
        start = (*start[:-1], jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes))
    return jax.lax.while_loop(lambda a: ~a[-2] & (a[0] < MAX_ATTEMPTS) & (a[1] <= DELTA_W_MAX), attempt, start)


# IPOPT's residual_ratio_max and the max_cond of its residual ratio (PDFullSpaceSolver).
RESIDUAL_RATIO_MAX, MAX_COND = 1e-10, 1e6


def residual_ratio(rhs, sol, res) -> jax.Array:
    """IPOPT's measure of a linear solve's accuracy: ``||res|| / (min(||rhs||, max_cond ||sol||) + ||sol||)`` in the
    infinity norm over all blocks (``||res||`` itself when the right-hand side and solution are both 0)."""
    norm = lambda vs: jnp.max(jnp.stack([jnp.max(jnp.abs(v), initial=0.0) for v in vs]))  # noqa: E731
    n_rhs, n_sol, n_res = norm(rhs), norm(sol), norm(res)
    scale = jnp.minimum(n_rhs, MAX_COND * n_sol) + n_sol
    return jnp.where(n_rhs + n_sol == 0.0, n_res, n_res / jnp.where(scale > 0.0, scale, 1.0))


# The condition number of a matrix with unit diagonal (bounded below from its Cholesky factor, condition_bound) above
# which the stage-wise solve measures its residual: with errors ~ cond * eps, 1e6 keeps them near residual_ratio_max.
CHECK_COND = 1e6


def condition_bound(chol) -> jax.Array:
    """A lower bound on the condition number of ``S = L L^T`` scaled to a unit diagonal (``D^-1/2 S D^-1/2``, which a
    Cholesky solve's accuracy depends on rather than ``S``'s own row scales), from its Cholesky factor ``L``:
    ``1 / min_i (L_ii^2 / S_ii)`` (1 for an empty factor)."""
    if not chol.shape[0]:
        return jnp.ones((), chol.dtype)
    return 1.0 / jnp.min(jnp.diagonal(chol) ** 2 / jnp.sum(chol * chol, axis=1))
