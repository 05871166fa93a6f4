"""Implicit gradients of InteriorPoint's solves against the envelope theorem and finite differences, per system.

For each system at the published setting (single shooting, Heun, 100 controls), with ``solve_fn`` the interior
point's differentiable solve (its ``jax.custom_vjp``: the implicit function theorem on the KKT system):

- d(optimal cost)/d(p) by ``jax.jacrev`` through the solve, against the partial derivative of the Lagrangian
  L(z*, lambda*, p) = J(z*, p) + lambda* . c(z*, p) at the solution (envelope theorem), for every parameter;
- the same against central differences of re-solves, for every parameter (step 1e-5 relative);
- d(w . u*)/d(x0) for a fixed random w against central differences, for every state.

Printed per system: the largest relative differences (|a - b| / max(1, |b|)), against the issue's bars (envelope
1e-6, finite differences 1e-5), and the seconds (compilations included). Exit code 1 when a bar is missed.

Usage: python -m bench.ipm_gradients [--systems NAME ...]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see bench/interior_point_table.py

import jax
import jax.numpy as jnp
import numpy as np

from myriad.runtime import load
from myriad.runtime.bench import PUBLISHED_SETTING
from myriad.runtime.data import ProblemData, default_data
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.solvers.base import canonical_data
from myriad.runtime.status import Status

ENVELOPE_BAR, FD_BAR = 1e-6, 1e-5
DEFAULT = ["mould_fungicide", "cancer_treatment", "bioreactor", "bacteria", "van_der_pol", "timber_harvest"]


def rel(a: float, b: float) -> float:
    return abs(a - b) / max(1.0, abs(b))


def check(name: str) -> dict:
    t0 = time.perf_counter()
    system = load(name)
    nlp = PUBLISHED_SETTING.transcribe(system)
    data = canonical_data(default_data(system))
    solve_fn = InteriorPoint().solve_fn(nlp)
    z0 = nlp.initial_guess(data)
    out = solve_fn(data, z0)
    if int(out.status) != Status.CONVERGED:
        return {"system": name, "error": f"the solve did not converge (status {int(out.status)})"}
    n_u = int(np.asarray(jax.jit(nlp.unravel)(out.z, data)[2]).size)
    w = jnp.asarray(np.random.default_rng(2).standard_normal(n_u))

    @jax.jit
    def outputs(params, x0):
        """(optimal cost, w . the optimal controls), each as a function of the problem data through the solve."""
        dat = ProblemData(params, x0)
        sol = solve_fn(dat, z0)
        return jnp.stack([sol.objective, jnp.dot(w, nlp.unravel(sol.z, dat)[2].ravel())]), sol.status

    (d_params, d_x0) = jax.jacrev(lambda p, x: outputs(p, x)[0], argnums=(0, 1))(data.params, data.x0)

    def lagrangian(params):
        dat = ProblemData(params, data.x0)
        value = nlp.objective(out.z, dat)
        if nlp.constraints is None:  # bounds only: their multipliers do not depend on p
            return value
        return value + jnp.dot(out.multipliers, nlp.constraints(out.z, dat))

    envelope = jax.grad(lagrangian)(data.params)
    env_err, fd_err, x0_err, unconverged = 0.0, 0.0, 0.0, 0
    for key in data.params:
        g = float(d_params[key][0])
        env_err = max(env_err, rel(g, float(envelope[key])))
        eps = 1e-5 * max(1.0, abs(float(data.params[key])))
        vals = []
        for s in (eps, -eps):
            v, st = outputs({**data.params, key: data.params[key] + s}, data.x0)
            unconverged += int(st) != Status.CONVERGED
            vals.append(np.asarray(v))
        fd_err = max(fd_err, rel(g, float((vals[0][0] - vals[1][0]) / (2 * eps))))
    eps = 1e-5 * max(1.0, float(jnp.max(jnp.abs(data.x0))))
    for i, e in enumerate(np.eye(data.x0.shape[0])):
        vals = []
        for s in (eps, -eps):
            v, st = outputs(data.params, data.x0 + s * e)
            unconverged += int(st) != Status.CONVERGED
            vals.append(np.asarray(v))
        x0_err = max(x0_err, rel(float(d_x0[1, i]), float((vals[0][1] - vals[1][1]) / (2 * eps))))
    return {"system": name, "parameters": len(data.params), "states": int(data.x0.shape[0]), "envelope": env_err,
            "fd_params": fd_err, "fd_x0": x0_err, "unconverged_resolves": unconverged,
            "seconds": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", nargs="+", default=DEFAULT)
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} on "
          f"{jax.default_backend()}, float64; published setting (single shooting, Heun, 100 controls)")
    print(f"{'system':17s} {'params':>6s} {'dJ/dp vs envelope':>18s} {'dJ/dp vs FD':>12s} {'du/dx0 vs FD':>13s} "
          f"{'unconv.':>7s} {'s':>6s}  meets bars")
    ok = 0
    for name in args.systems:
        try:
            r = check(name)
        except Exception as exc:  # noqa: BLE001 -- one system's failure is its row, not the table's
            r = {"error": f"{type(exc).__name__}: {exc}"}
        if "error" in r:
            print(f"{name:17s} {r['error']}")
            continue
        good = (r["envelope"] <= ENVELOPE_BAR and r["fd_params"] <= FD_BAR and r["fd_x0"] <= FD_BAR
                and not r["unconverged_resolves"])
        ok += good
        print(f"{name:17s} {r['parameters']:6d} {r['envelope']:18.1e} {r['fd_params']:12.1e} {r['fd_x0']:13.1e} "
              f"{r['unconverged_resolves']:7d} {r['seconds']:6.1f}  {'yes' if good else 'no'}", flush=True)
    print(f"systems meeting every bar (envelope {ENVELOPE_BAR:g}, finite differences {FD_BAR:g}): {ok} / "
          f"{len(args.systems)}")
    return 0 if ok == len(args.systems) else 1


if __name__ == "__main__":
    sys.exit(main())
