"""The stochastic env's observed weak orders: Monte Carlo x(T) of the Ornstein-Uhlenbeck env (dx = -2 x dt + dW,
x(0) = 1, T = 1, u = 0) on three grids per scheme, errors of its mean and variance against the SDE's closed form, and
the order observed on the last pair of grids beside the scheme's own closed-form order there.

    python -m bench.sde_weak_order [--paths-euler N] [--paths-heun N]

The convergence study that was a test until 2026-12-06 (tests/runtime/rl/test_env_uncertainty.py now checks the
env's moments against each scheme's exact moments on the same grids, and those exact moments' orders, in seconds):
Euler-Maruyama on 4, 8, 16 steps with 10^6 episodes, stochastic Heun on 2, 4, 8 with 4 10^6 (its errors, 4e-3 at 8
steps, stand well above the Monte Carlo noise: standard errors 2.5e-4 of the mean, 1.7e-4 of the variance). Exits 1
when an observed order misses the stated one by more than 0.5 (mean) or 0.3 (variance), or the variance's error
does not fall grid by grid. About a minute on the 2-core machine.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from myriad.runtime import load  # noqa: E402
from myriad.runtime.rl import Env, EnvOptions, play  # noqa: E402

SPEC = Path(__file__).resolve().parents[1] / "tests" / "runtime" / "uncertainty" / "specs" / "ornstein_uhlenbeck.yaml"
THETA, SIGMA, X0, T = 2.0, 1.0, 1.0, 1.0
STUDIES = (("euler", "euler_maruyama", 1, (4, 8, 16)), ("heun", "heun", 2, (2, 4, 8)))


def exact_moments(n: int | None = None, scheme: str | None = None) -> np.ndarray:
    """Mean and variance of x(T): the SDE's (n None), else those of ``scheme`` on n steps (both schemes are linear
    here: x_{k+1} = R x_k + c sigma dW_k; tests/runtime/uncertainty/_systems.py derives R and c)."""
    if n is None:
        return np.array([X0 * math.exp(-THETA * T), SIGMA ** 2 * -math.expm1(-2 * THETA * T) / (2 * THETA)])
    h = T / n
    R, c = (1 - THETA * h, 1.0) if scheme == "euler_maruyama" else (1 - THETA * h + (THETA * h) ** 2 / 2,
                                                                     1 - THETA * h / 2)
    return np.array([X0 * R ** n, c * c * SIGMA ** 2 * h * sum(R ** (2 * i) for i in range(n))])


def final_states(env: Env, n_paths: int, chunk: int = 1_000_000) -> np.ndarray:
    """x(T) of ``n_paths`` episodes under zero control, one vmapped program run on chunks (each its own key)."""
    actions = jnp.zeros((env.options.steps, 1))
    data = env.default_params()
    fn = jax.jit(jax.vmap(lambda k: play(env, actions, data, k).states[-1, 0]))
    sizes = [min(chunk, n_paths - i) for i in range(0, n_paths, chunk)]
    keys = [jax.random.split(jax.random.fold_in(jax.random.PRNGKey(0), i), n) for i, n in enumerate(sizes)]
    return np.concatenate([np.asarray(fn(k)) for k in keys])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths-euler", type=int, default=1_000_000, metavar="N")
    ap.add_argument("--paths-heun", type=int, default=4_000_000, metavar="N")
    args = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    system, exact, ok = load(SPEC), exact_moments(), True
    for integrator, label, order, grids in STUDIES:
        paths = args.paths_euler if integrator == "euler" else args.paths_heun
        print(f"\n{label} (stated weak order {order}), {paths} episodes a grid")
        print(f"{'steps':>5s} {'mean error':>12s} {'var error':>12s} {'se mean':>10s} {'se var':>10s}")
        errors, closed = [], []
        for n in grids:
            x = final_states(Env(system, EnvOptions(steps=n, integrator=integrator)), paths)
            d = x - x.mean()
            se = (x.std() / math.sqrt(x.size), math.sqrt((np.mean(d ** 4) - np.mean(d ** 2) ** 2) / x.size))
            errors.append(np.abs(np.array([x.mean(), x.var(ddof=1)]) - exact))
            closed.append(np.abs(exact_moments(n, label) - exact))
            print(f"{n:5d} {errors[-1][0]:12.3e} {errors[-1][1]:12.3e} {se[0]:10.1e} {se[1]:10.1e}")
        observed, stated = np.log2(errors[-2] / errors[-1]), np.log2(closed[-2] / closed[-1])
        print(f"observed orders {grids[-2]} -> {grids[-1]} steps: mean {observed[0]:.2f}, variance {observed[1]:.2f} "
              f"(the scheme's closed form: {stated[0]:.2f}, {stated[1]:.2f})")
        if not (np.all(np.abs(observed - order) <= [0.5, 0.3]) and errors[0][1] > errors[1][1] > errors[2][1]):
            print(f"MISSED: {label}'s observed orders are not {order} within (0.5, 0.3)")
            ok = False
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
