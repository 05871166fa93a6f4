"""The implicit gradient at scale (issue 32 item 3): the cost of pulling a cotangent back through a solved
collocation NLP against N, stage by stage against the dense reference, in the same run. Prints figures only.

For each N, Hermite-Simpson(N) (or ``--transcription``) of the system is solved once by the interior point; at its
solution (the solver's own free variables, active rows and multipliers) the implicit rule's backward pass
(``runtime.solvers.implicit.kkt_vjp``: assemble and factorise the KKT matrix, one solve, one VJP of the KKT rows in
the parameters and x0) is jit-compiled and timed with ``stages=True`` (block-tridiagonal, the default) and
``stages=False`` (a dense Hessian and ``jnp.linalg.solve``). Both give the same cotangents (the largest relative
difference is printed); warm time is the median of ``--repeat`` calls (wall, Python dispatch included), the range
beside it. The dense reference is skipped above ``--dense-max`` intervals (it grows like N^3). The growth exponent is
the least-squares slope of log(median) against log(N) over the N given (from the second when three or more).

Usage: python -m bench.implicit_scaling [--system van_der_pol] [--transcription hermite_simpson]
                                        [--intervals 100 400 1600 6400] [--repeat 7] [--dense-max 1600]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax
import jax.numpy as jnp
import numpy as np

from bench.casadi_transcriptions import SETTINGS
from myriad.runtime import clear_caches, load
from myriad.runtime.data import default_data
from myriad.runtime.solvers import InteriorPoint
from myriad.runtime.solvers.base import ScaledProblem
from myriad.runtime.solvers.implicit import Active, kkt_vjp
from myriad.runtime.status import Status

jax.config.update("jax_enable_x64", True)


def _timed(fn, repeat: int) -> tuple[float, float, float]:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), max(times)


def row(system, transcription: str, n: int, repeat: int, dense_max: int) -> dict:
    """Solve at N, then time the backward pass both ways at the solution."""
    nlp = SETTINGS[transcription](n).transcribe(system)
    data = default_data(system)
    out = jax.jit(InteriorPoint().pure_solve(nlp))(data, nlp.initial_guess(data))
    if int(out.status) != Status.CONVERGED:
        return {"n": n, "failed": Status(int(out.status)).name}
    problem = ScaledProblem.from_nlp(nlp)
    w = out.z / problem.scale
    y = jnp.where(out.active_rows, out.multipliers, 0.0)
    at = Active(y, ~(out.active_lower | out.active_upper), out.active_rows)
    w_bar = jnp.asarray(np.random.default_rng(0).standard_normal(w.shape[0]))
    result, pulled = {"n": n, "variables": nlp.n_variables}, {}
    for label, stages in (("stages", True), ("dense", False)):
        if not stages and n > dense_max:
            continue
        fn = jax.jit(lambda d, w_, s=stages: kkt_vjp(problem, d, w_, at, w_bar, stages=s))
        t0 = time.perf_counter()
        pulled[label], ok = jax.block_until_ready(fn(data, w))
        result[f"{label}_compile"] = time.perf_counter() - t0
        result[f"{label}_ok"] = bool(ok)
        result[label] = _timed(lambda fn=fn: fn(data, w), repeat)
    if "dense" in pulled:
        a, b = (np.concatenate([np.ravel(x) for x in jax.tree.leaves(p)]) for p in (pulled["stages"], pulled["dense"]))
        result["difference"] = float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))
    clear_caches()
    return result


def slope(rows: list[dict], label: str) -> float | None:
    pts = [(r["n"], r[label][0]) for r in rows if label in r]
    if len(pts) >= 3:
        pts = pts[1:]
    if len(pts) < 2:
        return None
    x, t = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, t, 1)[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--system", default="van_der_pol")
    ap.add_argument("--transcription", default="hermite_simpson", choices=["hermite_simpson", "trapezoidal",
                                                                             "multiple_shooting"])
    ap.add_argument("--intervals", type=int, nargs="+", default=[100, 400, 1600, 6400])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--dense-max", type=int, default=1600)
    args = ap.parse_args(argv)
    if args.repeat < 1 or any(n < 2 for n in args.intervals):
        ap.error("--repeat must be at least 1 and every --intervals at least 2")
    system = load(args.system)
    model = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?")
    print(f"{args.system}, {args.transcription}; {model}, {os.cpu_count()} cores; load {os.getloadavg()[0]:.1f}")
    print(f"{'N':>6} {'n':>6}  {'stages s (range)':>26}  {'dense s (range)':>26}  {'rel diff':>8}  compile s")
    rows = []
    for n in args.intervals:
        r = row(system, args.transcription, n, args.repeat, args.dense_max)
        rows.append(r)
        if "failed" in r:
            print(f"{n:>6}  the solve failed: {r['failed']}")
            continue
        cell = lambda k: (f"{r[k][0]:.4f} ({r[k][1]:.4f}-{r[k][2]:.4f})" if k in r else "skipped")  # noqa: E731
        diff = f"{r['difference']:.1e}" if "difference" in r else "-"
        comp = f"{r['stages_compile']:.1f}" + (f" / {r['dense_compile']:.1f}" if "dense_compile" in r else "")
        bad = "" if r["stages_ok"] and r.get("dense_ok", True) else "  (a KKT solve was refused)"
        print(f"{n:>6} {r['variables']:>6}  {cell('stages'):>26}  {cell('dense'):>26}  {diff:>8}  {comp}{bad}",
              flush=True)
    for label in ("stages", "dense"):
        s = slope([r for r in rows if "failed" not in r], label)
        if s is not None:
            print(f"growth exponent, {label}: {s:.2f}")
    print(f"load {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
