"""The single-shooting Lagrangian's derivatives two ways: stage by stage against forward over reverse.

For each system at the published setting (SingleShooting(100), Heun): the time of one jitted evaluation of
``(F, c, dF/dw, dc/dw, Hessian)`` as the interior point takes it (``Layout.derivatives``) with the transcription's
``lagrangian_derivatives`` (``runtime/transcriptions/staged.py``) and without it (``jax.jvp`` of the gradient along
the unit vectors), and the largest relative difference of the two Hessians. Times are the minimum and the median of
``--repeat`` calls after the first, the two programs interleaved so that both see the same machine.

Usage: python -m bench.staged_hessian [--systems NAME ...] [--repeat R]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import jax.numpy as jnp
import numpy as np

from myriad.runtime import load
from myriad.runtime.bench import PUBLISHED_SETTING
from myriad.runtime.data import default_data
from myriad.runtime.solvers.base import ScaledProblem
from myriad.runtime.solvers.interior_point.problem import Layout
from myriad.runtime.systems import NAMES
from myriad.runtime.transcriptions.base import transcribe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", nargs="+", default=list(NAMES), choices=NAMES, metavar="NAME")
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args()
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")
    print(f"{'system':18s} {'n':>4s} {'m':>3s} {'staged ms':>16s} {'fwd-rev ms':>16s} {'speed-up':>8s} "
          f"{'hess diff':>9s}")
    ups = []
    for name in args.systems:
        system = load(name)
        nlp = transcribe(system, PUBLISHED_SETTING)
        staged = ScaledProblem.from_nlp(nlp)
        plain = dataclasses.replace(staged, derivatives=None)
        data = default_data(system)
        w = jnp.asarray(nlp.initial_guess(data)) / staged.scale
        lam = jnp.asarray(np.random.default_rng(0).normal(size=nlp.n_constraints))
        fns = [jax.jit(lambda w_, l_, d_, lay=Layout(p): lay.derivatives(w_, l_, d_)) for p in (staged, plain)]
        outs = [jax.block_until_ready(fn(w, lam, data)) for fn in fns]
        times: list[list[float]] = [[], []]
        for _ in range(args.repeat):
            for fn, ts in zip(fns, times):
                t0 = time.perf_counter()
                jax.block_until_ready(fn(w, lam, data))
                ts.append(time.perf_counter() - t0)
        h_s, h_p = np.asarray(outs[0][4]), np.asarray(outs[1][4])
        diff = float(np.max(np.abs(h_s - h_p)) / max(np.max(np.abs(h_p)), 1e-300))
        med = [statistics.median(ts) * 1e3 for ts in times]
        ups.append(med[1] / med[0])
        print(f"{name:18s} {nlp.n_variables:4d} {nlp.n_constraints:3d} "
              f"{min(times[0]) * 1e3:7.3f} / {med[0]:6.3f} {min(times[1]) * 1e3:7.3f} / {med[1]:6.3f} "
              f"{ups[-1]:8.2f} {diff:9.1e}")
    print(f"speed-up (median fwd-rev / median staged): median {statistics.median(ups):.2f} "
          f"(min {min(ups):.2f}, max {max(ups):.2f}) over {len(ups)} systems; times are min / median of {args.repeat}")


if __name__ == "__main__":
    main()
