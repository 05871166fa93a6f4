"""Environment steps per second: a batch of differently parameterised envs stepped as one vmapped program vs one env
at a time, through the functional core and through the Gymnasium adapter. Prints figures only, with the machine.

Rows (compile time excluded from every rate; each program is compiled once, the output says how many programs the
batched step compiled to, which must be 1 for new parameter values to reuse it):

* core, one env: the jit-compiled ``step`` called from a Python loop (what a Gymnasium env does per step);
* core, one env, scan: a whole episode of ``steps`` steps in one ``lax.scan`` (no Python per step);
* core, vmap B: ``jax.vmap(step)`` over B envs whose parameters and x0 differ (each scaled by U(1 -+ spread)),
  called from a Python loop;
* core, vmap B, scan: the batched episode in one program;
* Gymnasium MyriadEnv.step (NumPy in and out) and MyriadVectorEnv.step with B envs.

JAX's default dtype is used (float32 unless --x64), as an RL user meets it; JAX_PLATFORMS=cpu forces the CPU.

Usage: python -m bench.rl_throughput [--system van_der_pol] [--num-envs 1024] [--steps 100] [--repeats 5] [--x64]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import jax


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def best_rate(fn, steps: int, repeats: int) -> float:
    """Steps per second of the fastest of ``repeats`` timed calls (the first call, which compiles, is not timed)."""
    jax.block_until_ready(fn())
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return steps / best


def _envs(system, args):
    """B differently parameterised envs: every parameter and x0 scaled by U(1 -+ spread), x0 kept in its bounds."""
    import numpy as np

    from myriad.runtime.data import batch_data

    B = args.num_envs
    rng = np.random.default_rng(0)
    base = system.default_params()
    params = {k: float(v) * rng.uniform(1 - args.spread, 1 + args.spread, B) for k, v in base.items()
              if k not in system.structural_params}
    x0 = np.asarray(system.x0) * rng.uniform(1 - args.spread, 1 + args.spread, (B, system.n_states))
    a = system.arrays()
    x0 = np.clip(x0, a["x_lower"], a["x_upper"])
    return params, x0, batch_data(system, params, x0)


def _core_rows(env, batch, actions, key, keys, repeats) -> tuple[list, int]:
    """The functional core: one env and B envs, a jitted step per call and a whole episode in one scan; and how many
    programs the batched step compiled to (new parameter values must reuse it)."""
    N, B = actions.shape[:2]
    rows = []
    one = env.default_params()
    step1 = jax.jit(env.step)
    _, s1 = env.reset(key, one)
    per_step = [actions[k, 0] for k in range(N)]  # sliced once: an eager slice per step would be timed too

    def loop_one():
        s = s1
        for a_k in per_step:
            _, s, r, *_ = step1(key, s, a_k, one)
        return r

    rows.append(("core, one env, jit step per call", best_rate(loop_one, N, repeats)))

    def episode(state, acts, params, keys_):
        def body(s, a):
            _, s, r, *_ = env.step(keys_, s, a, params)
            return s, r
        return jax.lax.scan(body, state, acts)[1].sum(0)

    scan1 = jax.jit(episode)
    rows.append(("core, one env, episode in one scan", best_rate(lambda: scan1(s1, actions[:, 0], one, key), N,
                                                                  repeats)))

    stepB = jax.jit(jax.vmap(env.step))
    _, sB = jax.jit(jax.vmap(env.reset))(keys, batch)

    per_step_b = [actions[k] for k in range(N)]

    def loop_batch():
        s = sB
        for a_k in per_step_b:
            _, s, r, *_ = stepB(keys, s, a_k, batch)
        return r

    rows.append((f"core, vmap over {B} envs, jit step per call", best_rate(loop_batch, N * B, repeats)))
    scanB = jax.jit(jax.vmap(episode, in_axes=(0, 1, 0, 0)))
    rows.append((f"core, vmap over {B} envs, episode in one scan",
                 best_rate(lambda: scanB(sB, actions, batch, keys), N * B, repeats)))
    programs = stepB._cache_size()
    stepB(keys, sB, actions[0], batch._replace(params={k: v * 1.01 for k, v in batch.params.items()}))
    assert stepB._cache_size() == programs == 1, "new parameter values recompiled the batched step"
    return rows, programs


def _gym_rows(system, env, params, x0, actions, repeats) -> list:
    """The Gymnasium adapters, NumPy in and out: one env, and the vector env of B."""
    import jax.numpy as jnp
    import numpy as np

    from myriad.runtime.rl import MyriadEnv, MyriadVectorEnv

    N, B = actions.shape[:2]
    rows = []
    gym_env = MyriadEnv(system, steps=N)
    np_actions = np.asarray(actions, np.float32)

    def loop_gym():
        gym_env.reset(seed=0)
        for k in range(N):
            out = gym_env.step(np_actions[k, 0])
        return jnp.asarray(out[1])

    rows.append(("Gymnasium MyriadEnv.step (NumPy)", best_rate(loop_gym, N, repeats)))
    vec = MyriadVectorEnv(system, B, params=params, x0=x0, steps=N)

    def loop_vec():
        vec.reset(seed=0)
        for k in range(N):
            out = vec.step(np_actions[k])
        return jnp.asarray(out[1])

    rows.append((f"Gymnasium MyriadVectorEnv.step, {B} envs", best_rate(loop_vec, N * B, repeats)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--system", default="van_der_pol")
    ap.add_argument("--num-envs", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=100, help="steps per episode (the env's N)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--spread", type=float, default=0.1)
    ap.add_argument("--x64", action="store_true", help="float64 (default: JAX's float32)")
    args = ap.parse_args()
    # The bench package turns float64 on for every bench; this one measures what an RL user meets unless --x64.
    jax.config.update("jax_enable_x64", args.x64)

    import jax.numpy as jnp

    from myriad.runtime import load
    from myriad.runtime.rl import make_jax

    B, N = args.num_envs, args.steps
    system = load(args.system)
    env = make_jax(system, steps=N)
    params, x0, batch = _envs(system, args)
    key = jax.random.PRNGKey(0)
    actions = jax.random.uniform(key, (N, B, env.action_size), minval=-1.0, maxval=1.0)
    keys = jax.random.split(key, B)

    print(f"machine: {cpu_model()}; {os.cpu_count()} cores; {platform.system()} {platform.release()}")
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}; dtype {jnp.result_type(float)}; system "
          f"{system.name}; {N} steps per episode; {B} envs, parameters and x0 spread +-{args.spread:g}")
    rows, programs = _core_rows(env, batch, actions, key, keys, args.repeats)
    rows += _gym_rows(system, env, params, x0, actions, args.repeats)

    print(f"{'path':52s} {'env steps/s':>14s}")
    for label, rate in rows:
        print(f"{label:52s} {rate:14,.0f}")
    r = dict(rows)
    print(f"\nbatched vs one env at a time: {r[f'core, vmap over {B} envs, jit step per call'] / rows[0][1]:.0f}x "
          f"(jit step per call), {r[f'core, vmap over {B} envs, episode in one scan'] / rows[1][1]:.0f}x (scan); "
          f"the batched step is {programs} compiled program for {B} different parameter sets")


if __name__ == "__main__":
    main()
