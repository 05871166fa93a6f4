"""Reference scores: what trajectory optimisation, zero control and a random policy cost in each shipped env
(README.md in this folder: how each is measured).

    myriad rl-reference --write      # regenerate reference_scores.json (all 18 systems: about 20 minutes)
    myriad rl-reference --check      # exit 1 when the shipped file is stale

``normalized_score(system, J) = 100 (J_random - J) / (J_random - J_optimal)``: 0 is the random policy, 100 the
optimiser's open-loop controls.
"""

from __future__ import annotations

import functools
import json
import math
import sys
from importlib import resources
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..loader import load
from ..system import System
from ..systems import NAMES
from .env import Env, EnvOptions, play

__all__ = ["FORMAT", "EPISODES", "SEED", "reference_env", "baseline_costs", "compute",
           "reference_scores", "normalized_score", "stale"]

FORMAT = 1  # of the JSON file; bump with a change of layout
ENV_VERSION = 0  # the -v0 of the Gymnasium ids: bump both when the env's definition changes
EPISODES = 100
SEED = 0
_FILE = "reference_scores.json"


def reference_env(system: System) -> Env:
    """The environment the scores are measured in: default options, controls in their own units."""
    return Env(system, EnvOptions(normalize_actions=False))


def _control_batch(env: Env, optimal: np.ndarray | None) -> jnp.ndarray:
    """(E + 1 [+ 1], N, m): the random episodes, zero control, then the optimal controls when given."""
    N, m = env.options.steps, env.action_size
    lo, hi = env.control_bounds
    dtype = jax.dtypes.canonicalize_dtype(np.float64)
    draws = jax.random.uniform(jax.random.PRNGKey(SEED), (EPISODES, N, m), dtype)
    rand = jnp.asarray(lo, dtype) + draws * jnp.asarray(hi - lo, dtype)
    zero = jnp.broadcast_to(jnp.asarray(np.clip(0.0, lo, hi), dtype), (1, N, m))
    parts = [rand, zero] + ([jnp.asarray(optimal, dtype)[None]] if optimal is not None else [])
    return jnp.concatenate(parts)


def baseline_costs(system: System, optimal_controls: Any = None) -> dict[str, Any]:
    """The env costs of the random policy (mean, std), zero control and, if given, the (N, m) optimal controls.

    One jit-compiled ``vmap`` over all episodes."""
    env = reference_env(system)
    batch = _control_batch(env, None if optimal_controls is None else np.asarray(optimal_controls))
    data = env.default_params()
    costs = np.asarray(jax.jit(jax.vmap(lambda u: play(env, u, data).cost))(batch))
    out = {"random": float(np.mean(costs[:EPISODES])), "random_std": float(np.std(costs[:EPISODES])),
           "zero_control": float(costs[EPISODES])}
    if optimal_controls is not None:
        out["optimal"] = float(costs[EPISODES + 1])
    return out


def _played_controls(env: Env, sol) -> np.ndarray:
    """A solution's control at the middle of each env step: (N, m)."""
    T, N = float(env.system.horizon), env.options.steps
    times = np.asarray(sol.times)
    us = np.asarray(sol.controls)
    tu = times if us.shape[0] == times.shape[0] else np.linspace(0.0, T, us.shape[0])
    mid = (np.arange(N) + 0.5) * (T / N)
    return np.stack([np.interp(mid, tu, us[:, j]) for j in range(us.shape[1])], axis=1)


def compute(name: str) -> dict[str, Any]:
    """One system's record (solves every candidate: seconds to a minute)."""
    from ..bench import ALTERNATIVES, PUBLISHED_SETTING, run_bench
    from ..transcriptions import ForwardBackwardSweep

    system = load(name)
    env = reference_env(system)
    settings = {t.label: t for t in (PUBLISHED_SETTING, *ALTERNATIVES, ForwardBackwardSweep(intervals=1000))}
    (row,) = run_bench([name])
    best = None
    for sol in (row.main, *row.alternatives):
        if not sol.converged:
            continue
        controls = _played_controls(env, sol)
        scores = baseline_costs(system, controls)
        if math.isfinite(scores["optimal"]) and (best is None or scores["optimal"] < best[0]["optimal"]):
            best = (scores, sol, controls)
    if best is None:
        raise RuntimeError(f"{name}: no transcription converged; no optimal reference")
    scores, sol, controls = best
    if not all(math.isfinite(v) for v in scores.values()):  # JSON has no NaN/inf, and a score needs both ends
        raise RuntimeError(f"{name}: a reference cost is not finite: {scores}")
    return {
        "spec_sha256": system.spec_sha256,
        "sense": system.sense,
        "action_bound": env.options.action_bound,
        "optimal": {
            "cost": scores["optimal"],
            "transcription": sol.transcription,
            "setting": repr(settings[sol.transcription]),
            "solver": sol.solver,
            "solver_cost": sol.cost,
            "simulated_cost": sol.simulated_cost,
            "controls": controls.tolist(),
        },
        "zero_control": {"cost": scores["zero_control"]},
        "random": {"cost": scores["random"], "std": scores["random_std"], "episodes": EPISODES, "seed": SEED},
    }


def _env_record() -> dict[str, Any]:
    o = EnvOptions()
    return {"version": ENV_VERSION, "steps": o.steps, "integrator": o.integrator.label, "substeps": o.substeps,
            "penalty": o.penalty, "hold": "zero-order"}


def _dumps(doc: dict[str, Any]) -> str:
    """JSON with one line per record field, the played controls of a system on one line (the file stays short)."""
    out = json.loads(json.dumps(doc))
    controls = {}
    for name, r in out["systems"].items():
        controls[name] = json.dumps(r["optimal"]["controls"])
        r["optimal"]["controls"] = f"@controls:{name}@"
    text = json.dumps(out, indent=1)
    for name, c in controls.items():
        text = text.replace(f'"@controls:{name}@"', c)
    return text + "\n"


def write(path, names=NAMES, previous: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compute ``names`` and write the file; the other shipped systems keep their ``previous`` records."""
    from ..atomic import atomic_write_text

    fresh = {}
    for name in names:
        fresh[name] = r = compute(name)
        print(f"{name:18s} optimal {r['optimal']['cost']:.6g} ({r['optimal']['transcription']}) "
              f"zero {r['zero_control']['cost']:.6g} random {r['random']['cost']:.6g}")
    previous = previous or {}
    systems = {n: fresh.get(n, previous.get(n)) for n in NAMES if n in fresh or n in previous}
    doc = {"format": FORMAT, "generated_by": "myriad rl-reference --write", "env": _env_record(),
           "systems": systems}
    atomic_write_text(path, _dumps(doc))
    return doc


@functools.cache
def reference_scores() -> dict[str, Any]:
    """The shipped reference scores (the parsed JSON)."""
    return json.loads(resources.files(__package__).joinpath(_FILE).read_text(encoding="utf-8"))


def normalized_score(system: System | str, cost: float) -> float:
    """100 (J_random - J) / (J_random - J_optimal) for a cost J = -return in the default env (minimisation form).

    Raises:
        KeyError: a system without reference scores (only the shipped systems have them).
    """
    name = system.name if isinstance(system, System) else system
    table = reference_scores()["systems"]
    if name not in table:
        raise KeyError(f"no reference scores for {name!r}: they exist for the shipped systems ({', '.join(table)})")
    r = table[name]
    j_random, j_opt = r["random"]["cost"], r["optimal"]["cost"]
    return 100.0 * (j_random - float(cost)) / (j_random - j_opt)


def stale(doc: dict[str, Any] | None = None, names=NAMES, rtol: float = 1e-9) -> list[str]:
    """What is stale in the reference scores (empty when fresh): the format, the env's definition, the systems and
    their spec hashes, and every env cost replayed (random, zero, the stored optimal controls) with today's code.
    The solves are not repeated (minutes): a better solver makes the file stale without this noticing."""
    doc = reference_scores() if doc is None else doc
    problems = []
    if doc.get("format") != FORMAT or doc.get("env") != _env_record():
        problems.append(f"format/env {doc.get('format')}/{doc.get('env')} != {FORMAT}/{_env_record()}")
    if set(doc.get("systems", {})) != set(NAMES):
        problems.append(f"systems {sorted(doc.get('systems', {}))} != shipped {sorted(NAMES)}")
    for name in names:
        r = doc.get("systems", {}).get(name)
        if r is None:
            continue
        system = load(name)
        if r["spec_sha256"] != system.spec_sha256 or r["action_bound"] != reference_env(system).options.action_bound:
            problems.append(f"{name}: spec or action bound changed")
            continue
        now = baseline_costs(system, r["optimal"]["controls"])
        for key, old in (("optimal", r["optimal"]["cost"]), ("zero_control", r["zero_control"]["cost"]),
                         ("random", r["random"]["cost"])):
            if not math.isclose(now[key], old, rel_tol=rtol, abs_tol=rtol):
                problems.append(f"{name}: {key} cost {now[key]!r} != stored {old!r}")
    return problems


def run(write_systems=None, check: bool = False) -> int:
    """Rewrite the records of ``write_systems`` (all shipped ones for ``NAMES``), then check the file when asked or
    when nothing was written; the exit code: 1 when stale."""
    jax.config.update("jax_enable_x64", True)  # the scores are float64 figures
    path = resources.files(__package__).joinpath(_FILE)
    if write_systems:
        previous = json.loads(path.read_text(encoding="utf-8"))["systems"] if path.is_file() else {}
        write(path, write_systems, previous)
        reference_scores.cache_clear()
    if check or not write_systems:
        problems = stale(json.loads(path.read_text(encoding="utf-8")))
        for p in problems:
            print(p, file=sys.stderr)
        print("reference scores: " + ("STALE: rerun with --write" if problems else "fresh"))
        return 1 if problems else 0
    return 0
