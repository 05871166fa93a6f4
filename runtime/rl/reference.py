"""Reference scores for any system: what the certified optimum, zero control and a random policy cost in the
environment (README.md in this folder: how each is measured).

    reference_record("peers/hager", EnvOptions(action_bound=3))  # computed once, then read from the cache
    normalized_score("my/spec.yaml", -episode_return)            # any spec; 0 = random, 100 = certified optimum
    myriad rl-reference --write      # regenerate reference_scores.json (the 18 shipped systems, default env)
    myriad rl-reference --check      # exit 1 when the shipped file is stale

``normalized_score(system, J) = 100 (J_random - J) / (J_random - J_optimal)``.

A schema 3 spec that declares uncertain parameters gets one more part, ``uncertainty``: the expected env cost (mean
and Monte Carlo standard error over fresh parameter draws) of the nominal plan (the certified optimum's controls) and
of the robust plan (the mean over the spec's planning scenarios, :mod:`myriad.runtime.uncertainty.env_plans`), and
their paired difference (:func:`expected_costs`). The score itself stays normalised against the nominal problem.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import sys
from importlib import resources
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..loader import load
from ..system import System
from ..systems import NAMES
from ..uncertainty.distributions import uncertain_spec
from .env import Env, EnvOptions, play

__all__ = ["FORMAT", "ENV_VERSION", "EPISODES", "SEED", "UNCERTAIN_DRAWS", "CACHE_ENV_VAR", "reference_env",
           "baseline_costs", "expected_costs", "env_settings", "compute", "reference_record", "reference_cache_dir",
           "cache_key", "reference_scores", "normalized_score", "stale"]

FORMAT = 2  # of a record and of the JSON file; bump with a change of layout or of how a record is measured
ENV_VERSION = 0  # the -v0 of the Gymnasium ids: bump both when the env's definition changes
EPISODES = 100
SEED = 0
UNCERTAIN_DRAWS = 1000  # the parameter draws of the expected costs under a schema 3 spec's declared uncertainty
CACHE_ENV_VAR = "MYRIAD_RL_REFERENCE_CACHE"  # a folder, else $MYRIAD_CACHE/rl-reference, else ~/.cache/myriad/...
_FILE = "reference_scores.json"


def _system(target: System | str | os.PathLike) -> System:
    return target if isinstance(target, System) else load(os.fspath(target))


def reference_env(system: System | str, options: EnvOptions | None = None) -> Env:
    """The environment the scores are measured in: ``options`` (default :class:`EnvOptions`) with controls in their
    own units, whole episodes (no ``max_steps``) from x0 exactly (no ``start_noise``), and the nominal problem of a
    schema 3 spec (no draw of its uncertain parameters, no process or observation noise): the scores normalise
    against the nominal optimum, so none of these is part of a record's key."""
    options = EnvOptions() if options is None else options
    return Env(_system(system), dataclasses.replace(options, normalize_actions=False, max_steps=None,
                                                    start_noise=0.0, randomize=False, process_noise_scale=0.0,
                                                    observation_noise_scale=0.0))


def _control_batch(env: Env, optimal: np.ndarray | None) -> jnp.ndarray:
    """(E + 1 [+ 1], N, m): the random episodes, zero control, then the optimal controls when given."""
    N, m = env.options.steps, env.action_size
    env.require_finite_controls("a uniformly random policy has no distribution to draw from")
    lo, hi = env.control_bounds
    dtype = jax.dtypes.canonicalize_dtype(np.float64)
    draws = jax.random.uniform(jax.random.PRNGKey(SEED), (EPISODES, N, m), dtype)
    rand = jnp.asarray(lo, dtype) + draws * jnp.asarray(hi - lo, dtype)
    zero = jnp.broadcast_to(jnp.asarray(np.clip(0.0, lo, hi), dtype), (1, N, m))
    parts = [rand, zero] + ([jnp.asarray(optimal, dtype)[None]] if optimal is not None else [])
    return jnp.concatenate(parts)


def baseline_costs(system: System | str, optimal_controls: Any = None,
                   options: EnvOptions | None = None) -> dict[str, Any]:
    """The env costs of the random policy (mean, std), zero control and, if given, the (N, m) optimal controls, in
    :func:`reference_env` of ``options``. One jit-compiled ``vmap`` over all episodes."""
    env = reference_env(system, options)
    batch = _control_batch(env, None if optimal_controls is None else np.asarray(optimal_controls))
    data = env.default_params()
    costs = np.asarray(jax.jit(jax.vmap(lambda u: play(env, u, data).cost))(batch))
    out = {"random": float(np.mean(costs[:EPISODES])), "random_std": float(np.std(costs[:EPISODES])),
           "zero_control": float(costs[EPISODES])}
    if optimal_controls is not None:
        out["optimal"] = float(costs[EPISODES + 1])
    return out


def env_settings(env: Env) -> dict[str, Any]:
    """What defines the env's control problem (with the spec): the record's ``env`` and part of its key."""
    o = env.options
    return {"version": ENV_VERSION, "steps": o.steps, "integrator": o.integrator.label, "substeps": o.substeps,
            "penalty": o.penalty, "hold": "zero-order", "action_bound": o.action_bound}


def cache_key(system: System | str, options: EnvOptions | None = None) -> str:
    """The SHA-256 (hex) of the spec's hash, the env's settings (the integrator's full repr, not only its label)
    and the record's format, episodes and seed: a changed spec or setting is a new key."""
    env = reference_env(system, options)
    blob = {"spec_sha256": env.system.spec_sha256, "env": env_settings(env),
            "integrator": repr(env.options.integrator), "format": FORMAT, "episodes": EPISODES, "seed": SEED}
    return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()


def compute(target: System | str, options: EnvOptions | None = None) -> dict[str, Any]:
    """One system's record, solved now (seconds to a minute), in float64 whatever the caller's JAX mode.

    Raises:
        CertificationError: the two methods do not certify an optimum (:func:`.optimum.certified_optimum`).
        RuntimeError: a reference cost is not finite.
    """
    from .optimum import certified_optimum

    with jax.enable_x64(True):
        env = reference_env(target, options)
        base = baseline_costs(env.system, None, options)
        controls, certificate = certified_optimum(
            env, lambda j: max(abs(j), abs(base["random"] - j), np.finfo(np.float64).tiny))
        scores = baseline_costs(env.system, controls, options)
        uncertainty = expected_costs(env, controls) if uncertain_spec(env.system)[0] else None
    name = env.system.name
    if not all(math.isfinite(v) for v in scores.values()):  # JSON has no NaN/inf, and a score needs both ends
        raise RuntimeError(f"{name}: a reference cost is not finite: {scores}")
    return {
        "system": name,
        "spec_sha256": env.system.spec_sha256,
        "sense": env.system.sense,
        "action_bound": env.options.action_bound,
        "env": env_settings(env),
        "optimal": {"cost": scores["optimal"], "certificate": certificate, "controls": controls.tolist()},
        "zero_control": {"cost": scores["zero_control"]},
        "random": {"cost": scores["random"], "std": scores["random_std"], "episodes": EPISODES, "seed": SEED},
        **({"uncertainty": uncertainty} if uncertainty is not None else {}),
    }


def _evaluation_seed(system: System) -> int:
    """The key of the out-of-sample draws: 1, or 2 where the spec's robust seed (its planning scenarios) is 1."""
    return 2 if int(getattr(system, "robust_seed", 0)) == 1 else 1


def expected_costs(env: Env, optimal: Any) -> dict[str, Any]:
    """Under a schema 3 spec's declared uncertainty: the expected env cost (J = -return, mean and Monte Carlo
    standard error over :data:`UNCERTAIN_DRAWS` fresh parameter draws) of the nominal plan (``optimal``, the
    certified optimum's controls) and of the robust plan (the held controls that minimise the mean cost over the
    spec's planning scenarios, from the nominal plan: :func:`myriad.runtime.uncertainty.env_plans.scenario_plan`),
    the paired difference, and the robust plan's controls. Float64 is the caller's (``jax.enable_x64``)."""
    from ..uncertainty.env_plans import fresh_values, mean_and_error, plan_costs, scenario_plan
    from ..uncertainty.scenarios import scenario_values

    system, optimal = env.system, np.asarray(optimal, np.float64)
    planning = scenario_values(system)
    robust, result = scenario_plan(env, planning, optimal)
    seed = _evaluation_seed(system)
    draws = fresh_values(system, UNCERTAIN_DRAWS, seed)
    c_nom, c_rob = plan_costs(env, optimal, draws), plan_costs(env, robust, draws)

    def stats(c):
        mean, se = mean_and_error(c)
        return {"cost": mean, "se": se}

    return {"draws": UNCERTAIN_DRAWS, "seed": seed, "scenarios": int(planning.shape[0]),
            "nominal_plan": stats(c_nom),
            "robust_plan": {**stats(c_rob), "converged": bool(result.success), "controls": robust.tolist()},
            "robust_minus_nominal": stats(c_rob - c_nom)}


def _stale_uncertainty(name: str, system: System, record: dict[str, Any], rtol: float) -> list[str]:
    """What is stale in a record's expected costs under uncertainty: missing or present against the spec, or the
    stored plans' Monte Carlo means replayed with today's code (the robust solve is not repeated)."""
    from ..uncertainty.env_plans import fresh_values, mean_and_error, plan_costs

    u, declared = record.get("uncertainty"), bool(uncertain_spec(system)[0])
    if u is None:
        return [f"{name}: the spec declares uncertainty and the record has no expected costs"] if declared else []
    if not declared:
        return [f"{name}: the record has expected costs under uncertainty, but the spec declares none"]
    env = reference_env(system)
    draws = fresh_values(system, u["draws"], u["seed"])
    problems = []
    for key, controls in (("nominal_plan", record["optimal"]["controls"]),
                          ("robust_plan", u["robust_plan"]["controls"])):
        with jax.enable_x64(True):
            now = mean_and_error(plan_costs(env, np.asarray(controls, np.float64), draws))[0]
        if not math.isclose(now, u[key]["cost"], rel_tol=rtol, abs_tol=rtol):
            problems.append(f"{name}: {key} expected cost {now!r} != stored {u[key]['cost']!r}")
    return problems


def reference_cache_dir() -> Path:
    """``$MYRIAD_RL_REFERENCE_CACHE``, else ``$MYRIAD_CACHE/rl-reference``, else ``~/.cache/myriad/rl-reference``
    (beside the compiled specs of :func:`myriad.runtime.loader.spec_build_dir`); safe to delete."""
    if os.environ.get(CACHE_ENV_VAR):
        return Path(os.path.expanduser(os.environ[CACHE_ENV_VAR]))
    base = os.environ.get("MYRIAD_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "myriad")
    return Path(base) / "rl-reference"


_memo: dict[str, dict[str, Any]] = {}  # records of this process, by key


def _shipped(env: Env) -> dict[str, Any] | None:
    """The shipped record of a shipped system in the default env, if this is one (same spec and settings)."""
    r = reference_scores()["systems"].get(env.system.name)
    if r is not None and r["spec_sha256"] == env.system.spec_sha256 and r.get("env") == env_settings(env) \
            and env.options.integrator == EnvOptions().integrator:
        return r
    return None


def _cached(path: Path, env: Env) -> dict[str, Any] | None:
    """The record at ``path`` if it is there, parses and is this spec's in these settings (else None: computed
    again and overwritten; the writes are atomic, so only a hand-edited or foreign file fails this)."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    ok = isinstance(record, dict) and record.get("spec_sha256") == env.system.spec_sha256 \
        and record.get("env") == env_settings(env) \
        and ("uncertainty" in record) == bool(uncertain_spec(env.system)[0])  # one cached before the field: again
    return record if ok else None


def reference_record(target: System | str | os.PathLike, options: EnvOptions | None = None, *,
                     cache_dir: str | os.PathLike | None = None) -> dict[str, Any]:
    """The reference record of any system (a ``System``, a shipped name, ``peers/<name>`` or a spec path) in
    :func:`reference_env` of ``options``: the certified optimum (its cost, controls and certificate), zero
    control, the random policy, the spec's hash and the env's settings.

    Read from the shipped JSON (a shipped system, default settings), else from ``cache_dir`` (default
    :func:`reference_cache_dir`; a file ``<cache_key>.json``), else computed (:func:`compute`) and written there
    atomically.

    Raises:
        CertificationError: computing, the two methods did not certify an optimum.
        ValueError: a control without finite bounds and no ``action_bound`` (a random policy needs bounds).
    """
    env = reference_env(target, options)
    env.require_finite_controls("a uniformly random policy has no distribution to draw from")
    shipped = _shipped(env)
    if shipped is not None:
        return shipped
    key = cache_key(env.system, options)
    if key in _memo:
        return _memo[key]
    path = Path(cache_dir if cache_dir is not None else reference_cache_dir()) / f"{key}.json"
    record = _cached(path, env)
    if record is None:
        from ..atomic import atomic_write_text

        record = compute(env.system, options)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(record) + "\n")
    _memo[key] = record
    return record


def _env_record() -> dict[str, Any]:
    """The shipped file's env: the default settings (each record carries its own, with its action bound)."""
    settings = env_settings(Env(load("van_der_pol"), EnvOptions(normalize_actions=False)))
    del settings["action_bound"]
    return settings


def _dumps(doc: dict[str, Any]) -> str:
    """JSON with one line per record field, the played controls of a system on one line (the file stays short)."""
    out = json.loads(json.dumps(doc))
    controls = {}
    for name, r in out["systems"].items():
        controls[name] = json.dumps(r["optimal"]["controls"])
        r["optimal"]["controls"] = f"@controls:{name}@"
        if "uncertainty" in r:
            controls[name + ":robust"] = json.dumps(r["uncertainty"]["robust_plan"]["controls"])
            r["uncertainty"]["robust_plan"]["controls"] = f"@controls:{name}:robust@"
    text = json.dumps(out, indent=1)
    for name, c in controls.items():
        text = text.replace(f'"@controls:{name}@"', c)
    return text + "\n"


def write(path, names=NAMES, previous: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compute ``names`` (:func:`compute`, default env) and write the file; the other shipped systems keep their
    ``previous`` records."""
    from ..atomic import atomic_write_text
    from .optimum import CertificationError

    fresh, failed = {}, []
    for name in names:
        try:
            fresh[name] = r = compute(name)
        except CertificationError as e:  # the others are still written; the file is then stale (exit 1)
            print(f"{name:18s} NOT CERTIFIED: {e}", file=sys.stderr, flush=True)
            failed.append(name)
            continue
        c = r["optimal"]["certificate"]
        print(f"{name:18s} optimal {r['optimal']['cost']:.10g} (ipopt/interior point agree to {c['agreement']:.1e}, "
              f"{c['start']} start) zero {r['zero_control']['cost']:.6g} random {r['random']['cost']:.6g}",
              flush=True)
    previous = previous or {}
    systems = {n: fresh.get(n, previous.get(n)) for n in NAMES if n in fresh or (n in previous and n not in failed)}
    doc = {"format": FORMAT, "generated_by": "myriad rl-reference --write", "env": _env_record(),
           "systems": systems}
    atomic_write_text(path, _dumps(doc))
    return doc


@functools.cache
def reference_scores() -> dict[str, Any]:
    """The shipped reference scores (the parsed JSON): :func:`compute`'s records of the 18 shipped systems in the
    default env. Any other system or setting: :func:`reference_record`."""
    return json.loads(resources.files(__package__).joinpath(_FILE).read_text(encoding="utf-8"))


def normalized_score(target: System | str | os.PathLike, cost: float, options: EnvOptions | None = None) -> float:
    """100 (J_random - J) / (J_random - J_optimal) for a cost J = -return (minimisation form) in the env of
    ``options`` (default settings when None), for any system: the record is :func:`reference_record`'s (shipped,
    cached, or computed now: seconds to a minute the first time)."""
    r = reference_record(target, options)
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
        if r["spec_sha256"] != system.spec_sha256 or r.get("env") != env_settings(reference_env(system)):
            problems.append(f"{name}: spec or env settings (action bound included) changed")
            continue
        now = baseline_costs(system, r["optimal"]["controls"])
        for key, old in (("optimal", r["optimal"]["cost"]), ("zero_control", r["zero_control"]["cost"]),
                         ("random", r["random"]["cost"])):
            if not math.isclose(now[key], old, rel_tol=rtol, abs_tol=rtol):
                problems.append(f"{name}: {key} cost {now[key]!r} != stored {old!r}")
        problems += _stale_uncertainty(name, system, r, rtol)
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
