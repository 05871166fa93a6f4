"""The robust table (issue 30 item 5): per system with declared parameter uncertainty, the expected cost of the
nominal plan, the robust (mean) plan and MPC under that uncertainty, out of sample, with Monte Carlo standard errors.

Every cost is J = -return in the system's reference env (default options: 100 steps, Heun, zero-order hold, the
terminal penalty on missed final values and final-state bounds) with the uncertain parameters drawn from the spec's
distributions; the plans are open loop, MPC closed loop:

* nominal plan: the held controls that minimise the env's cost at the spec's nominal values (the certified optimum's
  problem, ``runtime/rl/optimum.py``), solved by IPOPT from the shipped certified optimum's controls;
* robust plan: the held controls that minimise the mean of the env's cost over ``samples`` planning scenarios
  drawn from the spec's ``robust.seed`` (2048 by default; ``--samples 0``: the spec's own ``robust.samples``, 16 by
  default: ``runtime/uncertainty/scenarios.py``), from the nominal plan (``runtime/uncertainty/env_plans.py``);
* MPC: ``runtime/rl/mpc.py`` re-planning every ``replan_every`` steps on the nominal parameters, playing in the env
  at the drawn ones (the first ``mpc_episodes`` of the draws).

Out of sample: the ``draws`` evaluation parameters come from ``PRNGKey(seed)``, never the planning scenarios' key.
The robust - nominal difference is paired (the same draws), so its standard error is that of the differences.

Usage: python -m bench.robust_table [--systems pendulum ...] [--draws 2000] [--mpc-episodes 20]
       [--json out/robust.json] [--markdown out/robust.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import jax
import numpy as np

from myriad.runtime.configs import add_arguments, from_args, to_json, usage_message
from myriad.runtime.loader import load
from myriad.runtime.uncertainty.distributions import uncertain_spec
from myriad.runtime.uncertainty.env_plans import fresh_values, mean_and_error, nominal_values, plan_costs, scenario_plan
from myriad.runtime.uncertainty.scenarios import scenario_values

__all__ = ["RobustTableConfig", "uncertain_systems", "row", "markdown", "main"]


def uncertain_systems() -> tuple[str, ...]:
    """The shipped systems whose spec declares uncertain parameters."""
    from myriad.runtime.systems import NAMES

    return tuple(n for n in NAMES if uncertain_spec(load(n))[0])


@dataclasses.dataclass(frozen=True)
class RobustTableConfig:
    """The robust table's settings.

    Attributes:
        systems: the systems (shipped names or spec paths); empty: every shipped system that declares uncertainty.
        samples: the robust plan's scenarios: this many draws from the spec's robust seed (0: the spec's own,
            ``robust.samples`` or 16). 2048 by default: where the nominal plan is already near the expected cost's
            minimiser (small symmetric ranges, no terminal condition), a plan over 16 or 256 scenarios overfits
            them and loses to it out of sample (docs/notes/2026-12-06-robust-table.md).
        draws: the out-of-sample parameter draws of each open-loop plan's Monte Carlo.
        mpc_episodes: MPC's closed-loop episodes (the first of the draws; 0: no MPC column).
        replan_every: MPC re-plans at the steps 0, k, 2k, ...
        seed: the key of the out-of-sample draws (not the spec's robust seed).
        steps: the env's steps (the reference env's 100 by default; fewer for a quick check).
        json: write the rows here (JSON).
        markdown: write the table here (Markdown).
    """

    systems: tuple[str, ...] = ()
    samples: int = 2048
    draws: int = 2000
    mpc_episodes: int = 20
    replan_every: int = 10
    seed: int = 2026
    steps: int = 100
    json: str | None = None
    markdown: str | None = None

    def __post_init__(self):
        if self.draws < 2 or self.mpc_episodes < 0 or self.replan_every < 1 or self.steps < 1 or self.samples < 0:
            raise ValueError("draws must be at least 2, mpc_episodes and samples non-negative, replan_every and "
                             "steps positive")
        if self.mpc_episodes > self.draws:
            raise ValueError(f"mpc_episodes ({self.mpc_episodes}) must not exceed draws ({self.draws})")


def _start(env, steps: int) -> tuple[np.ndarray, str]:
    """The nominal plan's start: the shipped certified optimum's controls in the default env, else the
    transcriptions' cold guess."""
    from myriad.runtime.rl.reference import reference_scores
    from myriad.runtime.transcriptions.nlp_parts import guess_controls

    r = reference_scores()["systems"].get(env.system.name)
    if r is not None and r["spec_sha256"] == env.system.spec_sha256 and len(r["optimal"]["controls"]) == steps:
        return np.asarray(r["optimal"]["controls"], np.float64), "certified optimum"
    lo, hi = env.control_bounds
    return np.clip(guess_controls(env.system, steps), lo, hi), "cold guess"


def _planning(system, n: int) -> np.ndarray:
    """(n, n_uncertain): n draws from the spec's robust seed (the planning scenarios with another count)."""
    from myriad.runtime.uncertainty.distributions import sample

    with jax.enable_x64(True):
        return np.asarray(sample(system, jax.random.PRNGKey(int(getattr(system, "robust_seed", 0))), n), np.float64)


def _stats(costs) -> dict:
    mean, se = mean_and_error(costs)
    return {"mean": mean, "se": se, "n": int(np.size(costs))}


def _mpc(env, values: np.ndarray, replan_every: int) -> dict:
    """MPC's closed-loop costs at each row of ``values`` (planner on the nominal parameters)."""
    from myriad.runtime.rl.mpc import MPC

    names = uncertain_spec(env.system)[0]
    mpc = MPC(env, replan_every=replan_every)
    costs, failures = [], 0
    for theta in values:
        ep = mpc.run(env.default_params(dict(zip(names, theta.tolist()))))
        costs.append(ep.cost)
        failures += ep.failures
    return {**_stats(costs), "failed_replans": failures, "costs": costs}


def row(target: str, config: RobustTableConfig) -> dict:
    """One system's row: the three expected costs, the paired difference, the plans' in-sample objectives."""
    from myriad.runtime.rl.env import EnvOptions
    from myriad.runtime.rl.reference import reference_env

    started = time.perf_counter()
    system = load(target)
    env = reference_env(system, EnvOptions(steps=config.steps))
    start, start_label = _start(env, config.steps)
    planning = scenario_values(system) if not config.samples else _planning(system, config.samples)
    nominal, r_nom = scenario_plan(env, nominal_values(system), start)
    robust, r_rob = scenario_plan(env, planning, nominal)
    draws = fresh_values(system, config.draws, config.seed)
    c_nom, c_rob = plan_costs(env, nominal, draws), plan_costs(env, robust, draws)
    out = {
        "system": system.name, "uncertain": {n: [k, list(a)] for n, k, a in zip(*uncertain_spec(system))},
        "scenarios": int(planning.shape[0]), "start": start_label,
        "nominal_plan": {**_stats(c_nom), "converged": bool(r_nom.success),
                         "at_nominal": float(plan_costs(env, nominal, nominal_values(system))[0]),
                         "in_sample": float(np.mean(plan_costs(env, nominal, planning)))},
        "robust_plan": {**_stats(c_rob), "converged": bool(r_rob.success),
                        "at_nominal": float(plan_costs(env, robust, nominal_values(system))[0]),
                        "in_sample": float(np.mean(plan_costs(env, robust, planning)))},
        "robust_minus_nominal": _stats(c_rob - c_nom),
    }
    if config.mpc_episodes:
        mpc = _mpc(env, draws[: config.mpc_episodes], config.replan_every)
        paired = c_nom[: config.mpc_episodes], c_rob[: config.mpc_episodes]
        out["mpc"] = {**{k: v for k, v in mpc.items() if k != "costs"},
                      "nominal_plan_same_draws": _stats(paired[0]), "robust_plan_same_draws": _stats(paired[1]),
                      "mpc_minus_robust": _stats(np.asarray(mpc["costs"]) - paired[1])}
    out["seconds"] = time.perf_counter() - started
    return out


def _pm(s: dict | None, digits: int = 6) -> str:
    if s is None:
        return "-"
    return f"{s['mean']:.{digits}g} ± {s['se']:.2g}"


def markdown(rows: list[dict], config: RobustTableConfig) -> str:
    """The table: expected costs (mean ± standard error) under the declared uncertainty, out of sample."""
    lines = [f"Expected cost J = -return under the declared uncertainty (mean ± standard error; {config.draws} "
             f"out-of-sample draws, seed {config.seed}; MPC: the first {config.mpc_episodes}, re-planning every "
             f"{config.replan_every} steps on the nominal parameters). Lower is better.", "",
             "| system | uncertain | S | nominal plan | robust plan | robust - nominal (paired) | MPC | "
             "MPC - robust (paired) | MPC failed re-plans | s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['system']} | error: {r['error']} |  |  |  |  |  |  |  |  |")
            continue
        unc = ", ".join(f"{n} {k} {a}" for n, (k, a) in r["uncertain"].items())
        mpc = r.get("mpc")
        lines.append(f"| {r['system']} | {unc} | {r['scenarios']} | {_pm(r['nominal_plan'])} | "
                     f"{_pm(r['robust_plan'])} | {_pm(r['robust_minus_nominal'], 3)} | {_pm(mpc)} | "
                     f"{_pm(mpc and mpc['mpc_minus_robust'], 3)} | {mpc['failed_replans'] if mpc else '-'} | "
                     f"{r['seconds']:.0f} |")
    lines += ["", "In sample (the mean over the S planning scenarios: the robust plan minimises it) and at the nominal "
              "parameters (the nominal plan minimises that):", "",
              "| system | nominal plan, in sample | robust plan, in sample | nominal plan, at nominal | "
              "robust plan, at nominal |", "|---|---|---|---|---|"]
    for r in rows:
        if "error" not in r:
            n, b = r["nominal_plan"], r["robust_plan"]
            lines.append(f"| {r['system']} | {n['in_sample']:.8g} | {b['in_sample']:.8g} | {n['at_nominal']:.8g} | "
                         f"{b['at_nominal']:.8g} |")
    worse = [r["system"] for r in rows if "error" not in r and r["robust_minus_nominal"]["mean"] > 0]
    lines += ["", "Robust plan at or below the nominal plan on every system." if not worse else
              f"Robust plan ABOVE the nominal plan on: {', '.join(worse)}."]
    return "\n".join(lines) + "\n"


def machine() -> dict:
    from bench.rl_baselines import commit, cpu_model

    return {"cpu": cpu_model(), "cores": os.cpu_count(), "load": os.getloadavg(), "commit": commit()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser, RobustTableConfig)
    try:
        config = from_args(RobustTableConfig, parser.parse_args(argv))
    except ValueError as e:
        print(f"robust_table: error: {usage_message(e, RobustTableConfig)}", file=sys.stderr)
        return 2
    jax.config.update("jax_enable_x64", True)  # the costs are float64 figures
    systems = config.systems or uncertain_systems()
    for s in systems:
        try:
            if not uncertain_spec(load(s))[0]:
                raise ValueError("declares no uncertain parameters (schema 3's uncertain:)")
        except Exception as e:  # noqa: BLE001 -- any loader error is a bad --systems entry
            print(f"robust_table: error: --systems {s!r}: {e}", file=sys.stderr)
            return 2
    rows, start = [], machine()
    for s in systems:
        try:
            rows.append(row(s, config))
        except Exception as e:  # noqa: BLE001 -- a failed system is an error row, printed, and the table goes on
            rows.append({"system": s, "error": f"{type(e).__name__}: {e}"})
            print(f"{s:18s} ERROR {rows[-1]['error']}", flush=True)
            continue
        r = rows[-1]
        print(f"{r['system']:18s} nominal {_pm(r['nominal_plan'])}  robust {_pm(r['robust_plan'])}  "
              f"diff {_pm(r['robust_minus_nominal'], 3)}  mpc {_pm(r.get('mpc'))}  {r['seconds']:.0f} s", flush=True)
    text = markdown(rows, config)
    print(text)
    doc = {"config": to_json(config), "machine": {"start": start, "end": machine()}, "rows": rows}
    from myriad.runtime.atomic import atomic_write_text

    if config.json:
        atomic_write_text(config.json, json.dumps(doc, indent=1, allow_nan=True) + "\n")
    if config.markdown:
        atomic_write_text(config.markdown, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
