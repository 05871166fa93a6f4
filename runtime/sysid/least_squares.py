"""Nonlinear least squares for a parametric model: Levenberg-Marquardt on trajectory residuals, with standard errors.

For parameters theta, every fitted trajectory b, node k and state i the residual is

    r_{b,k,i}(theta) = w_{b,k,i} (x~_{b,k,i}(theta) - x_{b,k,i}),     w_{b,k,i} = 1 / s_i  or 0,

with x the observed states, s_i the per-state scale (``"range"``: :func:`.losses.state_scale`'s) and x~ the model
rolled out by the dataset's own integrator on its grid under the observed controls:

* single shooting: from each observed start x_{b,0} over the whole horizon, nodes k >= 1 (w = 0 at k = 0);
* multiple shooting: in windows of ``window`` steps, each from the observed state at its first node, which keeps the
  residuals of unstable or oscillating systems (Van der Pol, Cart-Pole) off one long, sensitive rollout;
* ``fit_starts`` (single shooting, the default on noisy data): the starts xi_b are unknowns too, x~_{b,0} = xi_b,
  with residuals at k = 0; noisy observed starts would otherwise bias theta (errors in variables) and make the
  standard errors overconfident (as multiple shooting's are on noisy data: each window starts at an observation).

On noisy data, observations at a finite state bound are dropped (w = 0; ``drop_clipped``): the dataset clips noisy
observations to the bounds, so they are censored, not Gaussian. Data made under a spec's declared noise (``noise``,
:mod:`.noise`: process noise and unclipped readings) are noisy data too, with nothing clipped.

The unknowns are scaled, theta = c p with c = theta0 where theta0 != 0 (else 1), so parameters of very different
magnitudes (HIV's k = 4.4e-5 and T_max = 1400) are equally conditioned; ``min_p 1/2 ||r(c p)||^2`` is one
``optimistix.least_squares`` call, jit-compiled once per (model, integrator, shapes, options).

Standard errors come from the Gauss-Newton Hessian at the solution: with J = dr/dp = U S V^T, m residuals (w > 0) and
K unknowns, sigma^2 = RSS / (m - K), Cov(p) = sigma^2 V S^-2 V^T and Cov(theta) = C Cov(p)_{PxP} C, C = diag(c).
Singular values below ``RCOND * max(S)`` are directions in which the residuals do not change: a parameter with a
component above ``NULL_TOL`` in them is listed in ``unidentifiable`` with a NaN standard error (and covariance row)
instead of a confident wrong number. On noise-free data sigma^2 ~ 0, and so are the standard errors.

Under a declared noise (``noise`` given, single shooting) the residuals of a trajectory are correlated (process
noise) and their variances known: the covariance is the sandwich (J^T J)^+ J^T Omega J (J^T J)^+ on J's range, Omega
the residuals' covariance under that noise (:func:`.noise.residual_covariance`), instead of sigma^2 (J^T J)^+.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..integrators import rollout
from ..learn.dataset import check_source
from ..status import Status
from ..uncertainty.sde import for_integrator
from .fit import METHODS
from .losses import state_scale
from .noise import DeclaredNoise, residual_covariance

__all__ = ["LeastSquaresResult", "least_squares"]

TOL = 1e-12  # Levenberg-Marquardt's rtol and atol (scaled parameters and residuals)
RCOND, NULL_TOL = 1e-8, 1e-6  # J's singular values below RCOND * max are zero; a larger component there: unidentifiable



@dataclasses.dataclass(frozen=True)
class LeastSquaresResult:
    """The outcome of :func:`least_squares` (host values, original units).

    Attributes:
        theta, standard_errors: {name: value}; the standard error is NaN for an unidentifiable parameter.
        covariance, names: (P, P) in ``names`` order; NaN rows and columns for unidentifiable parameters.
        residual_norm: ||r|| at the solution (scaled residuals, see the module docstring).
        n_obs, dof, sigma2: the residuals m that count (w > 0), m - K, and RSS / (m - K) (NaN when m <= K).
        converged, status, message: whether Levenberg-Marquardt met its tolerances (and, on noise-free data, fits
            them), as a :class:`~myriad.runtime.status.Status`, and why (with any identifiability warning).
        steps: Levenberg-Marquardt steps taken (accepted or not).
        unidentifiable: the names the data cannot identify (``message`` gives the direction).
        singular_values: of J = dr/dp (scaled parameters, then the starts), descending.
        method, starts: the method, and the fitted starts (B, n) with ``fit_starts`` (else None).
        seconds: wall time, compilation included.
    """

    theta: dict[str, float]
    standard_errors: dict[str, float]
    covariance: np.ndarray
    names: tuple[str, ...]
    residual_norm: float
    n_obs: int
    dof: int
    sigma2: float
    converged: bool
    status: Status
    message: str
    steps: int
    unidentifiable: tuple[str, ...]
    singular_values: np.ndarray
    seconds: float
    method: str = "single_shooting"
    starts: np.ndarray | None = None


def _predict(model, integrator, window, theta, spec, times, starts, x_obs, u_obs):
    """x~ at nodes 0..N, (B, N + 1, n): from ``starts`` (single shooting) or in windows from the observations."""
    f = lambda x, u, t: model.vector_field(x, u, t, theta, spec)  # noqa: E731
    t0, h = times[0], times[1] - times[0]
    if window is None:
        return jax.vmap(lambda x0, us: rollout(integrator, f, x0, t0, h, us))(starts, u_obs)
    n_batch, n_steps, n = x_obs.shape[0], x_obs.shape[1] - 1, x_obs.shape[2]
    n_win = -(-n_steps // window)
    pad = n_win * window - n_steps  # a short last window: its nodes past t_N (on the last control held) are cut
    u_pad = jnp.concatenate([u_obs, jnp.repeat(u_obs[:, -1:], pad, axis=1)], axis=1)
    idx = np.arange(n_win)[:, None] * window + np.arange(window + 1)[None, :]  # (W, w + 1) node indices
    t_win = t0 + jnp.arange(n_win, dtype=times.dtype) * (window * h)
    one = jax.vmap(lambda x0, tw, us: rollout(integrator, f, x0, tw, h, us))  # the windows of one trajectory
    xs = jax.vmap(one, in_axes=(0, None, 0))(x_obs[:, ::window][:, :n_win], t_win, u_pad[:, idx])
    return jnp.concatenate([x_obs[:, :1], xs[:, :, 1:].reshape(n_batch, n_win * window, n)[:, :n_steps]], axis=1)


# optimistix's outcomes onto myriad's; anything else (stagnation, divergence, a failed linear solve) is NOT_CONVERGED.
_RESULTS = ((optx.RESULTS.successful, Status.CONVERGED), (optx.RESULTS.max_steps_reached, Status.ITERATION_LIMIT),
            (optx.RESULTS.nonlinear_max_steps_reached, Status.ITERATION_LIMIT),
            (optx.RESULTS.nonfinite, Status.NOT_FINITE), (optx.RESULTS.nonfinite_input, Status.NOT_FINITE))


@functools.partial(jax.jit, static_argnames=("model", "integrator", "names", "window", "fit_starts", "max_steps"))
def _solve(p0, c, state_scale, spec, times, x_obs, u_obs, weights, *, model, integrator, names, window, fit_starts,
           max_steps):
    """The whole fit as one program: LM from p0, then the residuals and their Jacobian at the solution."""
    n_par = len(names)

    def residuals(p, _):
        theta = {k: c[i] * p[i] for i, k in enumerate(names)}
        starts = p[n_par:].reshape(x_obs.shape[0], x_obs.shape[2]) * state_scale if fit_starts else x_obs[:, 0]
        pred = _predict(model, integrator, window, theta, spec, times, starts, x_obs, u_obs)
        return ((pred - x_obs) * weights).ravel()

    jac = "fwd" if integrator.fixed_step else "bwd"  # an adaptive (diffrax) rollout has reverse-mode derivatives only
    sol = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=TOL, atol=TOL), p0, options={"jac": jac},
                             max_steps=max_steps, throw=False)
    code = jnp.asarray(int(Status.NOT_CONVERGED))
    for results, status in _RESULTS:
        code = jnp.where(sol.result == results, int(status), code)
    start_ok = jnp.all(jnp.isfinite(residuals(p0, None).reshape(x_obs.shape[0], -1)), axis=1)  # per trajectory
    jacobian = (jax.jacfwd if jac == "fwd" else jax.jacrev)(residuals)(sol.value, None)
    return sol.value, residuals(sol.value, None), jacobian, code, sol.stats["num_steps"], start_ok


def _state_scale(system, x_fit: np.ndarray, scale) -> np.ndarray:
    if isinstance(scale, str) and scale == "range":
        return state_scale(system, x_fit, "range")
    n = x_fit.shape[-1]
    try:
        s = np.ones(n) if scale is None else np.broadcast_to(np.asarray(scale, dtype=np.float64), (n,)).copy()
    except ValueError:  # another string, or the wrong length
        s = np.full(n, np.nan)
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise ValueError(f"least_squares: scale must be 'range', None or {n} positive numbers, got {scale!r}")
    return s


def _check(model, dataset, method, window, n_steps, fit_starts) -> None:
    check_source(dataset, model.system, "least_squares")
    if method not in METHODS:
        raise ValueError(f"least_squares: method must be one of {METHODS}, got {method!r}")
    if method == "multiple_shooting" and not (isinstance(window, int) and 1 <= window <= n_steps):
        raise ValueError(f"least_squares: window must be an integer in [1, {n_steps}] (grid steps), got {window!r}")
    if method == "multiple_shooting" and fit_starts:
        raise ValueError("least_squares: fit_starts is for single shooting (windows start at observations)")


def _direction(v: np.ndarray, names: tuple[str, ...], tol: float) -> str:
    """A null direction in original units with its largest component 1, e.g. "(+1 b, +1 mu)"."""
    v = v / v[np.argmax(np.abs(v))]
    return "(" + ", ".join(f"{x:+.3g} {k}" for k, x in zip(names, v) if abs(x) > tol) + ")"


def _start_values(model, theta0: dict | None) -> dict[str, float]:
    """The starting values by name, in the model's order: its guesses, overridden by ``theta0``'s."""
    guess = model.init_params(jax.random.PRNGKey(0))
    if not isinstance(guess, dict) or any(np.ndim(v) for v in guess.values()):
        raise ValueError(f"least_squares: fits a Parametric model's scalar parameters, not a {type(model).__name__}")
    theta_start = {k: float(v) for k, v in {**guess, **(theta0 or {})}.items()}
    if set(theta_start) != set(guess):
        raise ValueError(f"least_squares: {model.system.name} theta0 names {sorted(set(theta_start) - set(guess))} "
                         f"are not the model's {list(guess)}")
    return theta_start


def _weights(system, x_obs: np.ndarray, s: np.ndarray, fit_starts: bool, drop_clipped: bool) -> np.ndarray:
    """Each observation's residual weight: 1 / its state's scale; 0 for the starts unless they are fitted, and for
    observations clipped at a finite bound when ``drop_clipped``."""
    weights = np.broadcast_to(1.0 / s, x_obs.shape).copy()
    if not fit_starts:
        weights[:, 0] = 0.0
    if drop_clipped:
        a = system.arrays()
        weights[(x_obs == a["x_lower"]) | (x_obs == a["x_upper"])] = 0.0
    return weights


def _covariance(jac: np.ndarray, c: np.ndarray, names: tuple[str, ...], sigma2: float, finite: bool,
                meat: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], str]:
    """``(covariance of the parameters, singular values of J, unidentifiable names, a note for the message)``: the
    Gauss-Newton covariance on J's range, or with ``meat`` (J^T Omega J, unknowns x unknowns) the sandwich; NaN rows
    and columns for a parameter with a component in its null space."""
    n_par, n_all = len(names), jac.shape[1]
    sv, vt, keep = np.full(n_all, math.nan), np.zeros((n_all, n_all)), np.zeros(n_all, dtype=bool)
    if finite:
        _, sv, vt = np.linalg.svd(jac, full_matrices=False)
        keep = sv > RCOND * np.max(sv)
    v_null = vt[~keep, :n_par].T if finite else np.zeros((n_par, 0))  # the parameters' part of the null directions
    bad = np.linalg.norm(v_null, axis=1) > NULL_TOL
    v = vt[keep, :n_par]
    if meat is None:
        cov_p = (v.T / sv[keep] ** 2) @ v * sigma2
    else:  # (J^T J)^+ = V S^-2 V^T on the kept directions; the parameters' rows of it, then around the meat
        bread = (vt[keep, :n_par].T / sv[keep] ** 2) @ vt[keep, :]
        cov_p = bread @ meat @ bread.T
    cov = c[:, None] * cov_p * c[None, :]
    cov[bad | (not finite), :] = math.nan
    cov[:, bad | (not finite)] = math.nan
    unidentifiable, note = tuple(k for k, b in zip(names, bad) if b), ""
    if unidentifiable:
        dirs = "; ".join(_direction(c * col, names, NULL_TOL) for col in v_null.T if np.any(np.abs(col) > NULL_TOL))
        note = (f"; the data cannot identify: {', '.join(unidentifiable)} (the residuals do not change along "
                f"d theta ~ {dirs}: singular value(s) {', '.join(f'{x:.1e}' for x in sv[~keep])} < {RCOND:g} x "
                f"{np.max(sv):.2e}); their standard errors are NaN")
    return cov, sv, unidentifiable, note


def _meat(model, dataset, integrator, names, c, p, s, x_obs, u_obs, weights, jac, noise: DeclaredNoise,
          method: str) -> tuple[np.ndarray, str]:
    """``(sum_b J_b^T Omega_b J_b, a note)``: the sandwich's middle under the declared noise at the solution (NaN
    for multiple shooting, whose windows start at noisy readings: no standard errors then)."""
    if method != "single_shooting":
        return np.full((jac.shape[1],) * 2, math.nan), "; no standard errors under the declared noise by multiple " \
            "shooting (its windows start at noisy readings): refine by single shooting"
    n_par, (n_batch, n_nodes, n) = len(names), x_obs.shape
    theta = {k: jnp.asarray(c[i] * p[i]) for i, k in enumerate(names)}
    starts = p[n_par:].reshape(n_batch, n) * s if p.size > n_par else x_obs[:, 0]
    omega = np.asarray(residual_covariance(
        theta, model.system.default_params(jnp.float64), jnp.asarray(dataset.times, jnp.float64), jnp.asarray(starts),
        jnp.asarray(u_obs), jnp.asarray(weights), jnp.asarray(noise.process), jnp.asarray(noise.observation),
        model=model, scheme=for_integrator(integrator)))
    jb = jac.reshape(n_batch, n_nodes * n, -1)
    return np.einsum("bmi,bmk,bkj->ij", jb, omega, jb), ""


def least_squares(model, dataset, *, theta0: dict | None = None, method: str = "single_shooting",
                  window: int | None = None, fit_starts: bool | None = None, drop_clipped: bool | None = None,
                  max_steps: int = 200, scale: Any = "range", noise: DeclaredNoise | None = None) -> LeastSquaresResult:
    """Fit a :class:`~myriad.runtime.learn.models.Parametric` model's parameters to a dataset of its system by
    Levenberg-Marquardt (see the module docstring), from ``theta0`` (names left out start at the model's guesses).

    Args:
        method, window: "single_shooting" or "multiple_shooting" in windows of ``window`` steps (default N // 10).
        fit_starts: estimate each trajectory's start too (single shooting); None: on noisy data.
        drop_clipped: leave out observations at a finite state bound; None: on noisy data.
        max_steps: Levenberg-Marquardt's step limit.
        scale: the per-state residual scale: "range" (see the module docstring), None (1) or n positive numbers.
        noise: the noise the data were made with when the spec declares it (:func:`.noise.declared_noise`, data from
            :func:`.noise.noisy_dataset`): noisy data, and single shooting's standard errors are the sandwich's
            under it (the module docstring); multiple shooting's are then NaN (its windows start at noisy readings).

    Raises:
        ValueError: a dataset of another system or spec, a model with non-scalar parameters (a Neural ODE: use
            ``fit``), unknown ``theta0`` names, an unknown method or a bad window.
    """
    start = time.perf_counter()
    system = model.system
    theta_start = _start_values(model, theta0)
    names = tuple(theta_start)
    n_steps = int(np.shape(dataset.times)[0]) - 1
    window = max(1, n_steps // 10) if method == "multiple_shooting" and window is None else window
    noisy = dataset.sampling.noise > 0 or noise is not None
    fit_starts = noisy and method == "single_shooting" if fit_starts is None else fit_starts
    # (declared noise is never clipped: nothing to drop)
    drop_clipped = dataset.sampling.noise > 0 if drop_clipped is None else drop_clipped
    _check(model, dataset, method, window, n_steps, fit_starts)
    x_obs, u_obs = (np.asarray(a, dtype=np.float64) for a in (dataset.train.states, dataset.train.controls))
    integrator = dataset.sampling.integrator
    s = _state_scale(system, x_obs, scale)
    weights = _weights(system, x_obs, s, fit_starts, drop_clipped)
    g = np.array([theta_start[k] for k in names], dtype=np.float64)
    c = np.where(g != 0, g, 1.0)
    p0 = np.where(g != 0, 1.0, 0.0)
    if fit_starts:  # the starts, divided by the state scale, after the parameters
        p0 = np.concatenate([p0, (x_obs[:, 0] / s).ravel()])
    p, r, jac, code, steps, start_ok = (np.asarray(a) for a in _solve(
        jnp.asarray(p0), jnp.asarray(c), jnp.asarray(s), system.default_params(jnp.float64),
        jnp.asarray(dataset.times, dtype=jnp.float64), jnp.asarray(x_obs), jnp.asarray(u_obs), jnp.asarray(weights),
        model=model, integrator=integrator, names=names, window=window if method == "multiple_shooting" else None,
        fit_starts=fit_starts, max_steps=max_steps))
    status, message = Status(int(code)), ""
    finite = bool(np.all(np.isfinite(r)) and np.all(np.isfinite(p)) and np.all(np.isfinite(jac)))
    if not finite:
        status = Status.NOT_FINITE if status is Status.CONVERGED else status
        message = "; no standard errors (non-finite residuals or Jacobian)"
    if not np.all(start_ok):
        message += (f"; the model's rollout at the starting parameters is not finite on trajectories "
                    f"{np.flatnonzero(~start_ok).tolist()}: start closer (theta0, e.g. from multiple shooting)")

    n_obs, n_par = int(np.count_nonzero(weights)), len(names)
    dof, rss = n_obs - p.size, float(r @ r)
    sigma2 = rss / dof if dof > 0 else math.nan
    meat = None
    if noise is not None and finite:
        meat, note = _meat(model, dataset, integrator, names, c, p, s, x_obs, u_obs, weights, jac, noise, method)
        message += note
    cov, sv, unidentifiable, note = _covariance(jac, c, names, sigma2, finite, meat)
    message += note
    if finite and not noisy and status is Status.CONVERGED and rss > 1e-12 * n_obs:  # exact data, no fit
        status, message = Status.NOT_CONVERGED, message + (
            f"; stalled at RMS scaled residual {math.sqrt(rss / n_obs):.1e} on noise-free data (a local minimum; the "
            f"standard errors mean nothing there): try method='multiple_shooting' or another theta0")
    return LeastSquaresResult(
        theta={k: float(x) for k, x in zip(names, c * p[:n_par])},
        standard_errors={k: float(math.sqrt(cov[i, i])) if np.isfinite(cov[i, i]) else math.nan
                         for i, k in enumerate(names)},
        covariance=cov, names=names, residual_norm=math.sqrt(rss), n_obs=n_obs, dof=dof, sigma2=sigma2,
        converged=status is Status.CONVERGED, status=status, message=status.message + message, steps=int(steps),
        unidentifiable=unidentifiable, singular_values=sv, seconds=time.perf_counter() - start, method=method,
        starts=p[n_par:].reshape(x_obs.shape[0], -1) * s if fit_starts else None)
