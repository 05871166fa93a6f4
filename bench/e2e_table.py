"""End-to-end learning (Algorithm 2) benchmarks: the cost of a gradient, and learning runs per system.

    python bench/e2e_table.py gradients [--system cancer_treatment]
        time of one reverse pass: unrolled through K = 10 (and 30) planner steps against the implicit-function
        backward pass at a converged plan (and the forward solve it needs), published grid (100 controls)
    python bench/e2e_table.py learn SYSTEM... [--gradient unrolled|implicit] [--unroll K] [--iterations N]
        parametric end-to-end runs: learned against true parameters, the plan's cost on the true system against
        the optimum, time per system (published: about 0.5 h per system on a laptop)

Times depend on the machine and its load; the script prints the machine's CPU count and load average with them.
"""

from __future__ import annotations

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from myriad.runtime import load  # noqa: E402
from myriad.runtime.data import ProblemData, default_data  # noqa: E402
from myriad.runtime.e2e import E2EConfig, UnrolledPlanner, make_implicit_solve, run_e2e  # noqa: E402
from myriad.runtime.sysid.models import Parametric  # noqa: E402
from myriad.runtime.transcriptions import SingleShooting  # noqa: E402
from myriad.runtime.transcriptions.base import transcribe  # noqa: E402


def _machine() -> str:
    return f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"


def _best(fn, *args, repeat: int = 7) -> float:
    jax.block_until_ready(fn(*args))  # compile
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return min(times)


def gradients(name: str) -> None:
    system = load(name)
    model = Parametric(system)
    theta = model.init_params()
    nlp = transcribe(model.as_system(theta), SingleShooting())
    data = default_data(model.as_system(theta))
    w = jnp.asarray(np.random.default_rng(0).normal(size=nlp.n_variables))
    mk = lambda th: ProblemData({"spec": data.params["spec"], "model": th}, data.x0)  # noqa: E731
    planner = UnrolledPlanner(nlp)
    state = jax.jit(planner.reset)(data)
    run = jax.jit(lambda s: planner.run(s, data, 100))
    for _ in range(60):  # converge the warm start (and the implicit solve's start) at these parameters
        state = run(state)
    print(f"{name}: planner KKT residual at the warm start {float(planner.kkt(state)):.1e}; {_machine()}")
    for k in (10, 30):
        fwd = jax.jit(lambda th, s, k=k: jnp.dot(w, planner.z(planner.run(s, mk(th), k))))
        both = jax.jit(jax.value_and_grad(lambda th, s, k=k: jnp.dot(w, planner.z(planner.run(s, mk(th), k)))))
        f, b = _best(fwd, theta, state), _best(both, theta, state)
        print(f"  unrolled K = {k:3d}: forward {f * 1e3:8.2f} ms, forward + reverse {b * 1e3:8.2f} ms, "
              f"reverse alone {max(b - f, 0) * 1e3:8.2f} ms")
    isolve = make_implicit_solve(nlp)
    z = planner.z(state)
    fwd = jax.jit(lambda th: jnp.dot(w, isolve(mk(th).params, data.x0, z).z))
    both = jax.jit(jax.value_and_grad(lambda th: jnp.dot(w, isolve(mk(th).params, data.x0, z).z)))
    f, b = _best(fwd, theta), _best(both, theta)
    print(f"  implicit (warm, converged start): solve {f * 1e3:8.2f} ms, solve + backward {b * 1e3:8.2f} ms, "
          f"backward alone {max(b - f, 0) * 1e3:8.2f} ms")


def learn(names, gradient: str, unroll: int | None, iterations: int) -> None:
    print(f"| system | parameter | learned | true | rel. error | cost on true system | optimum | gap | "
          f"time (s) |\n|---|---|---|---|---|---|---|---|---|   ({_machine()}; {gradient}, "
          f"K = {unroll or 'default'}, {iterations} iterations)")
    for name in names:
        t = time.perf_counter()
        report = run_e2e(name, E2EConfig(gradient=gradient, unroll=unroll, iterations=iterations), progress=False)
        seconds = time.perf_counter() - t
        rec = report.record()
        for i, (k, v) in enumerate(report.learned.items()):
            true = report.true[k]
            head = (f"| {name} | " if i == 0 else "| | ")
            tail = (f" {rec['achieved_cost']:.6g} | {rec['optimal_cost']:.6g} | {rec['relative_gap']:.1e} | "
                    f"{seconds:.1f} |" if i == 0 else " | | | |")
            print(f"{head}{k} | {v:.6g} | {true:.6g} | {abs(v - true) / abs(true):.1e} |{tail}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="part", required=True)
    g = sub.add_parser("gradients")
    g.add_argument("--system", default="cancer_treatment")
    lr = sub.add_parser("learn")
    lr.add_argument("systems", nargs="+")
    lr.add_argument("--gradient", choices=["unrolled", "implicit"], default="unrolled")
    lr.add_argument("--unroll", type=int, default=None)
    lr.add_argument("--iterations", type=int, default=600)
    args = p.parse_args()
    if args.part == "gradients":
        gradients(args.system)
    else:
        learn(args.systems, args.gradient, args.unroll, args.iterations)


if __name__ == "__main__":
    main()
