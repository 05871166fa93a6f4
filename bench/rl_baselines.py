"""Baselines side by side in the RL environments: normalised scores of the open-loop optimum, MPC (nominal, under
parameter mismatch, under observation noise), an RL agent and the random policy, with wall times and the machine.

Every score is ``myriad.runtime.rl.normalized_score`` of J = -return in the reference env (default options, 100
steps, Heun, zero-order hold): 0 is the uniform random policy, 100 the trajectory optimiser's controls played open
loop (the shipped reference scores).

* open loop: the shipped optimal controls replayed (checks the scores are fresh: 100.00);
* MPC: ``myriad.runtime.rl.mpc.MPC``, re-planning every ``--replan-every`` steps with IPOPT on the env's own
  discretisation, cold-started at step 0 (the transcriptions' default guess, not the reference controls). Nominal:
  the env's parameters; mismatch: the planner's uncertain (learnable) parameters off by +-``--mismatch`` (random
  signs, one draw per episode); noise: the state observed with ``--noise`` * scale * N(0, 1) added. On a schema 3
  spec that declares its uncertainty (``myriad.runtime.rl.mpc.perturbed``; ``--hard-coded``: the perturbations
  above on every spec), mismatch draws the env's true parameters from their declared distributions at each
  episode's reset (the planner keeps the nominal ones), and noise runs the env with the declared process and
  observation noise (MPC sees the env's noisy observations); the summary line says which systems. Mismatch and
  noise are the mean over ``--episodes`` seeded episodes;
* PPO: rejax's PPO (a pure-JAX trainer, the optional extra ``pip install 'myriad-control[rl]'``) on the functional
  env with actions in [-1, 1], float32, observation and reward normalisation (rejax's own), ``--rl-steps`` env
  steps, then its deterministic policy (the Gaussian's mean) scored in float64; "not installed" without rejax. The
  budget is small (default 3 M steps, under a minute per system on 2 cores): the column is a baseline for this
  budget, not a tuned agent;
* random: the reference's 100 uniform random episodes (seed 0) recomputed (0.00 by construction).

Usage: python -m bench.rl_baselines [--systems van_der_pol pendulum ...] [--rl-steps 1000000] [--json out/rl.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from datetime import date

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import jax
import jax.numpy as jnp
import numpy as np

from myriad.runtime.loader import load
from myriad.runtime.rl.env import Env, play
from myriad.runtime.rl.mpc import MPC, perturbed
from myriad.runtime.rl.reference import baseline_costs, normalized_score, reference_env, reference_scores

SYSTEMS = ["van_der_pol", "pendulum", "cancer_treatment", "mountain_car", "cartpole"]
COLUMNS = ["open loop", "MPC", "MPC mismatch", "MPC noise", "PPO", "random"]


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), platform.machine())
    except OSError:
        return platform.processor() or platform.machine()


def commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


# ---- the RL agent (optional) ---------------------------------------------------------------------------------------
def rejax_available() -> bool:
    try:
        import gymnax  # noqa: F401
        import rejax  # noqa: F401
    except ImportError:
        return False
    return True


def train_ppo(name: str, total_steps: int, seed: int) -> tuple[float, float]:
    """Train rejax's PPO on the functional env; the deterministic policy's cost in the reference env (float64)
    and the training's wall time (compilation included)."""
    from rejax import PPO

    from myriad.runtime.rl.gymnax import GymnaxEnv

    system = load(name)
    g = GymnaxEnv(Env(system))  # actions in [-1, 1], float32
    env = g.env
    algo = PPO.create(env=g, env_params=g.default_params, total_timesteps=total_steps, eval_freq=total_steps,
                      num_envs=64, num_steps=env.options.steps, num_epochs=4, num_minibatches=8,
                      learning_rate=3e-4, gamma=0.999, ent_coef=0.0, normalize_observations=True,
                      normalize_rewards=True, skip_initial_evaluation=True)
    start = time.perf_counter()
    with jax.enable_x64(False):  # rejax's running statistics are created in the default dtype: float32 throughout
        ts, _ = jax.jit(algo.train)(jax.random.PRNGKey(seed))
        jax.block_until_ready(ts)
    wall = time.perf_counter() - start

    ref = reference_env(system)  # controls in their units, float64: the reference scores' env
    lo, hi = ref.control_bounds
    data = ref.default_params()

    def policy(obs):
        o = algo.normalize_obs(ts.obs_rms_state, obs)
        mean = algo.actor.apply(ts.actor_ts.params, o[None], method=lambda m, x: m._action_dist(x).mean())[0]
        return lo + 0.5 * (jnp.clip(mean, -1.0, 1.0) + 1.0) * (hi - lo)

    def episode():
        obs, state = ref.reset(jax.random.PRNGKey(0), data)

        def body(carry, _):
            obs, state, total = carry
            obs, state, reward, _, _, _ = ref.step_env(state, policy(obs), data)
            return (obs, state, total + reward), None

        (_, _, total), _ = jax.lax.scan(body, (obs, state, jnp.zeros(())), None, ref.options.steps)
        return total

    return -float(jax.jit(episode)()), wall


# ---- one system ----------------------------------------------------------------------------------------------------
def run_system(name: str, args, rl: bool) -> dict:
    system = load(name)
    env = reference_env(system)
    data = env.default_params()
    record = reference_scores()["systems"][name]
    out = {"system": name, "optimal_cost": record["optimal"]["cost"], "cost": {}, "score": {}, "seconds": {}}

    def put(column, cost, seconds):
        out["cost"][column], out["seconds"][column] = cost, seconds
        out["score"][column] = normalized_score(name, cost)

    start = time.perf_counter()
    costs = baseline_costs(system, record["optimal"]["controls"])
    put("open loop", costs["optimal"], time.perf_counter() - start)
    unpenalised = Env(system, dataclasses.replace(env.options, penalty=0.0))
    controls = np.asarray(record["optimal"]["controls"])
    out["optimal_penalty"] = costs["optimal"] - float(play(unpenalised, controls, data).cost)
    out["cost"]["random"] = costs["random"]
    out["score"]["random"] = normalized_score(name, costs["random"])
    out["seconds"]["random"] = out["seconds"]["open loop"]  # one vmapped program evaluates both

    nominal = MPC(env, replan_every=args.replan_every)
    ep = nominal.run(data)
    put("MPC", ep.cost, ep.wall_seconds)
    out["mpc"] = {"replans": ep.replans, "failures": ep.failures, "iterations": ep.iterations, "penalty": ep.penalty,
                  "solve_seconds": ep.solve_seconds, "compile_seconds": ep.compile_seconds}
    hard = MPC(env, replan_every=args.replan_every, terminal="constraint").run(data)
    out["mpc_constraint"] = {"cost": hard.cost, "penalty": hard.penalty, "failures": hard.failures,
                             "score": normalized_score(name, hard.cost), "wall_seconds": hard.wall_seconds}
    failures, declared = {}, {}
    for column, mismatch, noise in (("MPC mismatch", args.mismatch, 0.0), ("MPC noise", 0.0, args.noise)):
        start = time.perf_counter()
        eps = []
        for s in range(args.episodes):
            played, params, obs_noise = perturbed(env, mismatch, noise, s, declared=not args.hard_coded)
            mpc = nominal if played is env and params is None else MPC(played, params,
                                                                      replan_every=args.replan_every)
            eps.append(mpc.run(data, obs_noise=obs_noise, seed=s))
        put(column, float(np.mean([e.cost for e in eps])), time.perf_counter() - start)
        failures[column] = sum(e.failures for e in eps)
        declared[column] = played is not env  # the spec's declared uncertainty, not the hard-coded perturbation
    out["mpc"]["failures_disturbed"] = failures
    if any(declared.values()):  # (the rows of specs without declared uncertainty keep their keys)
        out["declared"] = declared

    if rl:
        cost, seconds = train_ppo(name, args.rl_steps, args.seed)
        put("PPO", cost, seconds)
    return out


def table(rows: list[dict], rl: str | None) -> str:
    head = "| system | " + " | ".join(COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 1)]
    for r in rows:
        cells = []
        for c in COLUMNS:
            if c == "PPO" and rl is not None:
                cells.append(rl)
            else:
                cells.append(f"{r['score'][c]:.2f} ({r['seconds'][c]:.1f} s)")
        lines.append(f"| {r['system']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--systems", nargs="+", default=SYSTEMS)
    ap.add_argument("--replan-every", type=int, default=10)
    ap.add_argument("--mismatch", type=float, default=0.1, help="relative error of the planner's parameters")
    ap.add_argument("--noise", type=float, default=0.02, help="observation noise per unit of state scale")
    ap.add_argument("--episodes", type=int, default=3, help="seeded episodes of the mismatch and noise columns")
    ap.add_argument("--hard-coded", action="store_true",
                    help="the +-mismatch and noise perturbations also on specs that declare their uncertainty")
    ap.add_argument("--rl-steps", type=int, default=3_000_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-rl", action="store_true", help="skip the RL agent even when rejax is installed")
    ap.add_argument("--json", help="also write the figures here")
    args = ap.parse_args()

    absent = "not installed" if not rejax_available() else "skipped (--no-rl)" if args.no_rl else None
    rl = absent is None
    start = time.perf_counter()
    rows = []
    for name in args.systems:
        rows.append(run_system(name, args, rl))
        print(f"{name}: done at {time.perf_counter() - start:.0f} s", flush=True)
    total = time.perf_counter() - start
    machine = (f"{cpu_model()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}, jax {jax.__version__}, "
               f"{date.today()}, commit {commit()}")
    print(f"\nNormalised scores (0 random, 100 open-loop optimum), wall time in brackets (the column's runs, "
          f"PPO's training and compilation included); machine: {machine}")
    print(f"MPC: every {args.replan_every} steps; mismatch +-{args.mismatch:g}, noise {args.noise:g} (mean of "
          f"{args.episodes}); PPO: " + (f"rejax, {args.rl_steps} steps" if rl else f"rejax {absent}"))
    spec_declared = [f"{r['system']} ({', '.join(c for c, on in r['declared'].items() if on)})"
                     for r in rows if "declared" in r]
    print("the spec's declared uncertainty instead: " + ("; ".join(spec_declared) or "none") + "\n")
    print(table(rows, absent))
    print("\nNominal MPC against the optimum: J (of which terminal penalty); the planner's terminal part is the env's "
          "penalty (the table above) or the published hard final-value rows (constraint)\n")
    print("| system | J optimum | J MPC | vs optimum | J MPC, constraint | vs optimum | score, constraint | re-plans | "
          "failed re-plans (nominal / mismatch / noise) | compile s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        m, h, j_opt = r["mpc"], r["mpc_constraint"], r["optimal_cost"]
        gap = lambda j: f"{100 * (j - j_opt) / abs(j_opt):+.2f} %"  # noqa: E731
        d = m["failures_disturbed"]
        print(f"| {r['system']} | {j_opt:.6g} ({r['optimal_penalty']:.2g}) | {r['cost']['MPC']:.6g} "
              f"({m['penalty']:.2g}) | {gap(r['cost']['MPC'])} | {h['cost']:.6g} ({h['penalty']:.2g}) | "
              f"{gap(h['cost'])} | {h['score']:.2f} | {m['replans']} | {m['failures']} / {d['MPC mismatch']} / "
              f"{d['MPC noise']} | {m['compile_seconds']:.1f} |")
    print(f"\ntotal {total:.0f} s")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "settings": vars(args), "rows": rows, "total_seconds": total}, f, indent=1)


if __name__ == "__main__":
    main()
