"""Table E: imitation learners against MPC, PPO and the certified optimum, by the number of demonstrations.

For each system, the normalised score (0: the uniform random policy, 100: the env's certified optimum,
``runtime/rl/reference.py``) of

* BC and DAgger (``runtime/imitation``, ``run_imitation`` with its default settings unless ``--set``) and the
  end-to-end learner (``method="e2e"``) where ``ImitateConfig`` accepts it, at each of ``--demos`` optimal
  demonstrations and each of ``--seeds``;
* MPC (``runtime/rl/mpc.py``: nominal, re-planning every 10 steps with IPOPT, cold-started; no demonstrations);
* PPO (``bench/rl_baselines.py``'s rejax trainer, one run per seed) when the ``rl`` extra is installed, else the
  column says "not installed";
* the optimum: 100 by definition; the table shows its certificate (the cost J*, IPOPT and the interior point's
  agreement).

Aggregation is rliable's (Agarwal et al., 2021): the interquartile mean over the seeds (per row) or over all runs of
all systems (the aggregate), with a 95 % percentile interval of the stratified bootstrap (runs resampled with
replacement within each system, the systems being the strata), written here with NumPy (:func:`iqm`,
:func:`stratified_bootstrap_ci`): two short functions do not earn a dependency.

BC from DAgger: ``run_imitation(method="dagger")`` fits the behaviour-cloning policy first (the same call, the same
seed, the same demonstrations) and records that policy's nominal env cost as its iteration 0 (``dagger_history``),
which is exactly BC's nominal score (test: equal to a separate BC run's). So where both are asked for, one DAgger run
gives both rows; BC's seconds are then its demonstrations and fit. ``--separate-bc`` runs BC on its own.

Resume: every row goes into ``--json`` (atomically) as it finishes; a rerun with the same file skips the rows it
holds, so a killed table loses only the row in progress. The file remembers the learners' settings and refuses
(exit 2) a rerun with other ones.

Usage: python -m bench.imitation_table [--systems ...] [--demos 1 10 100] [--seeds 0 1 2] [--methods bc dagger e2e]
       [--json F] [--markdown F] [--png F] [--set fit.epochs=200 ...] [--skip-ppo] [--retry-ppo]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from datetime import datetime, timezone

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import numpy as np

# Ordered fast first (the imitation README's and the reference scores' measured times): a short run covers most.
SYSTEMS = ["van_der_pol", "cancer_treatment", "simple_case", "bacteria", "mould_fungicide", "harvest",
           "predator_prey", "pendulum", "mountain_car", "bear_populations", "epidemic", "timber_harvest", "glucose",
           "tumour", "hiv_treatment", "bioreactor", "cartpole", "rocket_landing"]
LEARNERS = ("bc", "dagger", "e2e")
FORMAT = 1


# ---- aggregation (rliable's method, in NumPy) ----------------------------------------------------------------------
def iqm(x, axis: int = -1) -> np.ndarray:
    """The interquartile mean along ``axis``: the mean of what is left after dropping ``floor(n / 4)`` values from
    each end of the sorted sample (``scipy.stats.trim_mean(x, 0.25)``, rliable's ``aggregate_iqm``)."""
    x = np.sort(np.asarray(x, np.float64), axis=axis)
    n = x.shape[axis]
    if n == 0:
        raise ValueError("iqm of an empty sample")
    cut = int(0.25 * n)
    return np.take(x, np.arange(cut, n - cut), axis=axis).mean(axis=axis)


def stratified_bootstrap_ci(tasks, statistic=iqm, *, reps: int = 10_000, confidence: float = 0.95,
                            seed: int = 0) -> tuple[float, float]:
    """The percentile interval of ``statistic`` (of the runs of all tasks, concatenated) under the stratified
    bootstrap: each task's runs resampled with replacement, independently per task, ``reps`` times (rliable's
    ``get_interval_estimates``). ``tasks``: one 1-D sample of runs per task (sizes may differ)."""
    tasks = [np.asarray(t, np.float64).ravel() for t in tasks]
    if not tasks or any(t.size == 0 for t in tasks):
        raise ValueError("stratified_bootstrap_ci needs at least one run in every task")
    rng = np.random.default_rng(seed)
    draws = np.concatenate([t[rng.integers(0, t.size, (reps, t.size))] for t in tasks], axis=1)
    stats = statistic(draws, axis=1)
    alpha = 100 * (1 - confidence) / 2
    lo, hi = np.percentile(stats, [alpha, 100 - alpha])
    return float(lo), float(hi)


def summarise(tasks) -> dict:
    """IQM and its 95 % interval of the finite runs of ``tasks`` (a failed run has no score), with the counts."""
    finite = [np.asarray([v for v in t if v is not None and np.isfinite(v)]) for t in tasks]
    runs, ok = sum(len(t) for t in tasks), sum(t.size for t in finite)
    finite = [t for t in finite if t.size]
    if not finite:
        return {"iqm": None, "ci": None, "runs": runs, "finite": 0}
    return {"iqm": float(iqm(np.concatenate(finite))), "ci": list(stratified_bootstrap_ci(finite)), "runs": runs,
            "finite": ok}


# ---- the results file (resume) -------------------------------------------------------------------------------------
class Results:
    """The table's JSON: settings, rows (one learner run each), baselines (one per system and column); every
    change is written atomically at once, so a killed run keeps what it finished."""

    def __init__(self, path: str | None, settings: dict):
        self.path, self.settings = path, settings
        self.data = {"format": FORMAT, "settings": settings, "rows": [], "baselines": {}, "machine": {}}
        if path and os.path.exists(path):
            with open(path, encoding="utf-8") as f:
                old = json.load(f)
            theirs = old.get("settings") or {}
            differ = sorted(k for k in theirs.keys() & settings.keys() if theirs[k] != settings[k])
            if old.get("format") != FORMAT or differ:
                raise ValueError(f"--json {path} holds rows of other settings ({', '.join(differ) or 'format'}: "
                                 f"{ {k: theirs[k] for k in differ} }); give another file, or the same --set values, "
                                 "to resume it")
            # A field added to (or gone from) ImitateConfig since: its default did not make the old rows.
            old["settings"] = {**theirs, **settings}
            self.data = old
        self._done = {self.key(r) for r in self.data["rows"]}

    @staticmethod
    def key(row: dict) -> tuple:
        return row["system"], row["method"], int(row["demos"]), int(row["seed"])

    def done(self, system: str, method: str, demos: int, seed: int) -> bool:
        return (system, method, demos, seed) in self._done

    def baseline(self, system: str) -> dict:
        return self.data["baselines"].setdefault(system, {})

    def add(self, *rows: dict) -> None:
        for row in rows:
            if self.key(row) not in self._done:
                self.data["rows"].append(row)
                self._done.add(self.key(row))
        self.save()

    def save(self) -> None:
        if self.path:
            from myriad.runtime.atomic import atomic_write_text

            atomic_write_text(self.path, json.dumps(self.data, indent=1, allow_nan=False) + "\n")


# ---- the runs ------------------------------------------------------------------------------------------------------
def e2e_available() -> bool:
    """Whether ``run_imitation`` takes ``method="e2e"`` (another engineer's work in progress)."""
    from myriad.runtime.imitation import ImitateConfig

    try:
        ImitateConfig(method="e2e")
    except ValueError:
        return False
    return True


def _row(record: dict, method: str, wall: float) -> dict:
    return {"system": record["system"], "method": method, "demos": record["demos"], "seed": record["seed"],
            "normalized_score": record["normalized_score"], "episode_return": record["episode_return"],
            "status": record["status"], "message": record.get("message"), "seconds": wall, "parts": record["seconds"],
            "mismatch": (record.get("mismatch") or {}).get("normalized_score"),
            "noise": (record.get("noise") or {}).get("normalized_score"),
            "expert_labels": record.get("expert_labels"), "expert_failures": record.get("expert_failures")}


def bc_from_dagger(record: dict) -> dict:
    """BC's row from a DAgger record: its iteration 0 is the behaviour-cloning policy's nominal env cost J."""
    from myriad.runtime.rl.reference import normalized_score

    if not record["dagger_history"]:  # the fit failed, so DAgger never started: the record is BC's own
        return {**_row(record, "bc", sum(record["seconds"].values())), "status": record["status"]}
    _, _, cost = record["dagger_history"][0]
    parts = {k: record["seconds"][k] for k in ("demonstrations", "bc")}
    row = _row(record, "bc", sum(parts.values()))
    row.update(normalized_score=None if cost is None else normalized_score(record["system"], cost),
               episode_return=None if cost is None else -cost, parts=parts, mismatch=None, noise=None,
               status="from dagger's iteration 0", expert_labels=None, expert_failures=None)
    return row


def refused(system: str, method: str, demos: int, seed: int, why: str) -> dict:
    """The row of a method that does not apply to the system (e2e without learnable parameters)."""
    return {"system": system, "method": method, "demos": demos, "seed": seed, "normalized_score": None,
            "status": "refused", "message": why, "seconds": 0.0}


def run_learners(system: str, demos: int, seed: int, methods: list[str], values: dict,
                 separate_bc: bool = False) -> list:
    """The rows of ``methods`` at one (system, demos, seed), each by ``run_imitation`` with the ``--set`` values
    (module docstring). The config is built per method, not replaced from one: ImitateConfig's defaults depend on
    the method (e2e's start noise is 0)."""
    from myriad.runtime.configs import build
    from myriad.runtime.imitation import ImitateConfig, run_imitation
    from myriad.runtime.imitation.e2e import require_learnable
    from myriad.runtime.loader import load

    rows = []
    for method in methods:
        if method == "bc" and "dagger" in methods and not separate_bc:
            continue  # from DAgger's run below
        config = build(ImitateConfig, {**values, "method": method, "demos": demos, "seed": seed})
        if method == "e2e":
            try:
                require_learnable(load(system), config.e2e)
            except ValueError as exc:
                rows.append(refused(system, method, demos, seed, str(exc)))
                continue
        t = time.perf_counter()
        record = run_imitation(system, config, progress=False).record()
        rows.append(_row(record, method, time.perf_counter() - t))
        if method == "dagger" and "bc" in methods and not separate_bc:
            rows.append(bc_from_dagger(record))
    return rows


def optimum(system: str) -> dict:
    """The certified reference: J*, the two methods' agreement and its tolerance (score 100 by definition)."""
    from myriad.runtime.rl.reference import reference_record

    rec = reference_record(system)
    cert = rec["optimal"]["certificate"]
    return {"score": 100.0, "cost": rec["optimal"]["cost"], "agreement": cert["agreement"],
            "tolerance": cert["tolerance"], "methods": cert.get("methods"), "random_cost": rec["random"]["cost"]}


def mpc_baseline(system: str, replan_every: int = 10) -> dict:
    """Nominal MPC's score and wall time (``bench/rl_baselines.py``'s MPC column)."""
    from myriad.runtime.rl.mpc import MPC
    from myriad.runtime.rl.reference import normalized_score, reference_env

    env = reference_env(system)
    ep = MPC(env, replan_every=replan_every).run(env.default_params())
    return {"score": normalized_score(system, ep.cost), "cost": ep.cost, "seconds": ep.wall_seconds,
            "failures": ep.failures, "replan_every": replan_every}


def ppo_baseline(system: str, seeds: list[int], steps: int) -> dict:
    """PPO (rejax, ``bench/rl_baselines.train_ppo``) per seed, or why not."""
    from bench.rl_baselines import rejax_available, train_ppo
    from myriad.runtime.rl.reference import normalized_score

    if not rejax_available():
        return {"status": "not installed"}
    import jax

    with jax.numpy_dtype_promotion("standard"):  # rejax mixes Python scalars and bools (strict under the tests)
        runs = [train_ppo(system, steps, s) for s in seeds]
    scores = [normalized_score(system, cost) for cost, _ in runs]
    return {"status": "ok", "steps": steps, "seeds": seeds, "scores": scores, "seconds": [s for _, s in runs],
            **summarise([scores])}


def jobs(args) -> list[tuple]:
    """What the table runs, in order: per system its baselines, then (demos, seed) from the fewest demos up."""
    out = []
    for system in args.systems:
        out.append((system, "baselines", None, None))
        out += [(system, "learners", d, s) for d in args.demos for s in args.seeds]
    return out


def pending(results: Results, job: tuple, methods: list[str], args) -> list[str]:
    system, kind, demos, seed = job
    if kind == "baselines":
        have = results.data["baselines"].get(system, {})  # not baseline(): a look must not add an empty entry
        columns = ("optimum", "mpc") if getattr(args, "skip_ppo", False) else ("optimum", "mpc", "ppo")
        return [c for c in columns
                if c not in have or (c == "ppo" and args.retry_ppo and have[c].get("status") != "ok")]
    return [m for m in methods if not results.done(system, m, demos, seed)]


def run_table(args, values: dict, results: Results, methods: list[str], runner=run_learners, progress=None) -> Results:
    """Every job not yet in ``results``, each written as it finishes; the progress meter counts the jobs."""
    from myriad.runtime.learn.progress import progress_meter

    todo = [j for j in jobs(args) if pending(results, j, methods, args)]
    total = len(jobs(args))
    with progress_meter(progress, total, initial=total - len(todo), desc="table E", unit="run") as meter:
        for job in todo:
            system, kind, demos, seed = job
            t = time.perf_counter()
            if kind == "baselines":
                have = results.baseline(system)
                for column in pending(results, job, methods, args):
                    have[column] = {"optimum": lambda: optimum(system), "mpc": lambda: mpc_baseline(system),
                                    "ppo": lambda: ppo_baseline(system, args.seeds, args.rl_steps)}[column]()
                    results.save()
            else:
                todo_methods = pending(results, job, methods, args)
                separate = args.separate_bc or ("bc" in todo_methods and "dagger" not in todo_methods)
                try:
                    rows = runner(system, demos, seed, todo_methods, values, separate_bc=separate)
                except Exception as exc:  # noqa: BLE001 -- one run's crash is its rows' failure, not the table's
                    traceback.print_exc()
                    rows = [{**refused(system, m, demos, seed, f"{type(exc).__name__}: {exc}"), "status": "error"}
                            for m in todo_methods]
                results.add(*rows)
            meter.update(f"{system} {kind}{'' if demos is None else f' {demos} demos seed {seed}'} "
                         f"{time.perf_counter() - t:.0f} s")
    return results


# ---- the tables and the figure -------------------------------------------------------------------------------------
def aggregate(results: Results, systems: list[str], methods: list[str], demos: list[int]) -> dict:
    """Per (system, method, demos) and over all systems per (method, demos): IQM, 95 % interval, counts, seconds."""
    rows = results.data["rows"]
    per, overall = {}, {}
    for method in methods:
        for d in demos:
            strata = []
            for system in systems:
                mine = [r for r in rows if (r["system"], r["method"], r["demos"]) == (system, method, d)]
                if not mine:
                    continue
                if all(r["status"] == "refused" for r in mine):
                    per[f"{system}|{method}|{d}"] = {"refused": mine[0]["message"], "runs": len(mine)}
                    continue
                mine = [r for r in mine if r["status"] != "refused"]
                scores = [r["normalized_score"] for r in mine]
                secs = [r["seconds"] for r in mine]
                per[f"{system}|{method}|{d}"] = {**summarise([scores]), "seeds": [r["seed"] for r in mine],
                                                 "scores": scores, "median_seconds": float(np.median(secs)),
                                                 "max_seconds": float(np.max(secs))}
                strata.append(scores)
            if strata:
                overall[f"{method}|{d}"] = {**summarise(strata), "systems": len(strata)}
    mpc = [[b["mpc"]["score"]] for s, b in results.data["baselines"].items() if s in systems and "mpc" in b]
    if mpc:
        overall["mpc"] = {**summarise(mpc), "systems": len(mpc)}
    return {"per": per, "overall": overall}


def _cell(s: dict | None) -> str:
    if s and "refused" in s:
        return "does not apply" + (" (no learnable parameters)" if "learnable" in s["refused"] else "")
    if not s or s.get("iqm") is None:
        return "-" if not s else f"failed ({s['runs']} runs)"
    lo, hi = s["ci"]
    failed = "" if s["finite"] == s["runs"] else f", {s['runs'] - s['finite']} failed"
    secs = f", {s['median_seconds']:.0f} s" if "median_seconds" in s else ""
    # Three decimals: most learners here land within 0.1 of the optimum, where two would print 100.00 for all.
    return f"{s['iqm']:.3f} [{lo:.3f}, {hi:.3f}] (n={s['runs']}{failed}{secs})"


def system_seconds(results: Results, system: str) -> float:
    """The system's wall time: its learner runs (BC from DAgger not counted twice) and its baselines."""
    rows = [r for r in results.data["rows"] if r["system"] == system and r["status"] != "from dagger's iteration 0"]
    b = results.data["baselines"].get(system, {})
    extra = b.get("mpc", {}).get("seconds", 0.0) + sum(b.get("ppo", {}).get("seconds", []) or [])
    return sum(r["seconds"] for r in rows) + extra


def markdown(results: Results, systems: list[str], methods: list[str], demos: list[int], labels: dict) -> str:
    agg = aggregate(results, systems, methods, demos)
    names = " | ".join(f"{d} demo{'s' * (d != 1)}" for d in demos)
    head = f"| system | method | {names} | slowest run, s |"
    lines = ["Normalised scores: IQM over seeds [95 % stratified-bootstrap interval] (runs, median wall seconds of a "
             "run); 0 = uniform random, 100 = the certified optimum.", "", head,
             "|---|---|" + "---|" * len(demos) + "---|"]
    for system in systems:
        b = results.data["baselines"].get(system, {})
        if "optimum" in b:
            o = b["optimum"]
            lines.append(f"| {labels[system]} | optimum | 100 by definition: J* = {o['cost']:.8g}; IPOPT and the "
                         f"interior point agree to {o['agreement']:.1e} of the score's scale (bar "
                         f"{o['tolerance']:.0e}) |"
                         + " |" * len(demos))
        if "mpc" in b:
            m = b["mpc"]
            lines.append(f"| | MPC (no demonstrations) | {m['score']:.3f} |" + " |" * (len(demos) - 1)
                         + f" {m['seconds']:.1f} |")
        if "ppo" in b:
            p = b["ppo"]
            cell = p["status"] if p["status"] != "ok" else f"{_cell(p)} ({p['steps']} env steps)"
            lines.append(f"| | PPO (no demonstrations) | {cell} |" + " |" * (len(demos) - 1) + " |")
        for method in methods:
            cells = [agg["per"].get(f"{system}|{method}|{d}") for d in demos]
            if not any(cells):
                continue
            slowest = max((c["max_seconds"] for c in cells if c and "max_seconds" in c), default=0.0)
            lines.append(f"| | {method} | " + " | ".join(_cell(c) for c in cells) + f" | {slowest:.0f} |")
    lines += ["", "Over all systems (IQM of every run, systems as the bootstrap's strata):", "",
              f"| method | {names} |",
              "|---|" + "---|" * len(demos)]
    for method in methods:
        cells = [agg["overall"].get(f"{method}|{d}") for d in demos]
        if any(cells):
            lines.append(f"| {method} | " + " | ".join(_cell(c) for c in cells) + " |")
    if "mpc" in agg["overall"]:
        lines.append("| MPC | " + _cell(agg["overall"]["mpc"]) + " |" * len(demos))
    lines += ["", "| system | learner rows | minutes | DAgger >= BC (IQM, per demos) |", "|---|---|---|---|"]
    for system in systems:
        done = sum(r["system"] == system for r in results.data["rows"])
        if not done and not results.data["baselines"].get(system):
            lines.append(f"| {labels[system]} | not run | | |")
            continue
        cmp = [(d, agg["per"].get(f"{system}|dagger|{d}"), agg["per"].get(f"{system}|bc|{d}")) for d in demos]
        cmp = [f"{d}: {'yes' if a['iqm'] >= b['iqm'] else 'NO'}" for d, a, b in cmp
               if a and b and a["iqm"] is not None and b["iqm"] is not None]
        lines.append(f"| {labels[system]} | {done} | {system_seconds(results, system) / 60:.1f} | "
                     f"{', '.join(cmp) or '-'} |")
    return "\n".join(lines) + "\n"


def plot(results: Results, systems: list[str], methods: list[str], demos: list[int], labels: dict, path: str):
    """Score against demonstrations (log x): one panel per system and one of the aggregate; IQM with its 95 %
    interval per learner, MPC dashed, the optimum (100) dotted."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from myriad.runtime.atomic import atomic_open

    agg = aggregate(results, systems, methods, demos)
    panels = [s for s in systems if any(f"{s}|{m}|{d}" in agg["per"] for m in methods for d in demos)] + ["all"]
    cols = min(4, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.9 * rows), squeeze=False)
    for ax, panel in zip(axes.flat, panels):
        for i, method in enumerate(methods):
            key = (lambda d: f"{method}|{d}") if panel == "all" else (lambda d: f"{panel}|{method}|{d}")
            src = agg["overall"] if panel == "all" else agg["per"]
            pts = [(d, src[key(d)]) for d in demos if (src.get(key(d)) or {}).get("iqm") is not None]
            if pts:
                x = np.array([d for d, _ in pts]) * (1 + 0.04 * (i - 1))  # side by side, not on top of each other
                y = np.array([s["iqm"] for _, s in pts])
                err = np.abs(np.array([s["ci"] for _, s in pts]).T - y)
                ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=method)
        mpc = (agg["overall"].get("mpc", {}).get("iqm") if panel == "all"
               else results.data["baselines"].get(panel, {}).get("mpc", {}).get("score"))
        if mpc is not None:
            ax.axhline(mpc, ls="--", c="grey", lw=1, label="MPC")
        ax.axhline(100, ls=":", c="k", lw=1, label="optimum")
        ax.set_xscale("log")
        ax.set_xticks(demos, [str(d) for d in demos])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xlim(min(demos) / 1.6, max(demos) * 1.6)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_title("all systems (IQM)" if panel == "all" else labels[panel], fontsize=9)
        ax.set_xlabel("demonstrations")
        ax.set_ylabel("normalised score")
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_open(path) as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


# ---- the command ---------------------------------------------------------------------------------------------------
def parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--systems", nargs="+", default=SYSTEMS[:10])
    ap.add_argument("--demos", nargs="+", type=int, default=[1, 10, 100])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--methods", nargs="+", choices=LEARNERS, default=list(LEARNERS))
    ap.add_argument("--json", help="the rows, written as each finishes; an existing file is resumed")
    ap.add_argument("--markdown", help="the tables")
    ap.add_argument("--png", help="score against demonstrations")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="an ImitateConfig field for every learner run (--set fit.epochs=200, dagger.iterations=2)")
    ap.add_argument("--separate-bc", action="store_true", help="run BC on its own, not from DAgger's iteration 0")
    ap.add_argument("--rl-steps", type=int, default=3_000_000, help="PPO's env steps per seed (with rejax)")
    ap.add_argument("--retry-ppo", action="store_true", help="run PPO again where the file has no PPO scores")
    ap.add_argument("--skip-ppo", action="store_true", help="leave PPO to a later run (learners first)")
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None)
    ap.add_argument("--no-run", action="store_true", help="only print (and write) the tables of what --json holds")
    return ap.parse_args(argv)


def setup(args):
    """The ``--set`` values, the settings record (the config they make, less what each run sets), the methods that
    run and the systems' titles (exit 2 on bad input)."""
    from myriad.runtime.configs import build, parse_value, to_json
    from myriad.runtime.imitation import ImitateConfig
    from myriad.runtime.loader import load

    def bad(message):
        print(f"imitation_table: {message}", file=sys.stderr)
        raise SystemExit(2)

    values = {}
    for item in args.set:
        key, eq, value = item.partition("=")
        if not eq:
            bad(f"--set {item!r}: expected KEY=VALUE (e.g. --set fit.epochs=200)")
        values[key] = parse_value(value)
    try:
        base = build(ImitateConfig, values)
    except ValueError as exc:
        bad(f"--set: {exc}")
    if any(d < 1 for d in args.demos) or any(s < 0 for s in args.seeds):
        bad("--demos must be positive and --seeds non-negative integers")
    labels = {}
    for s in args.systems:
        try:
            labels[s] = load(s).title or s
        except Exception as exc:  # noqa: BLE001 -- any loader error is a bad --systems entry
            bad(f"--systems {s!r}: {exc}")
    skipped = [m for m in args.methods if m == "e2e" and not e2e_available()]
    methods = [m for m in args.methods if m not in skipped]
    settings = to_json(base, skip=("method", "demos", "seed"))
    settings["bc"] = "separate" if args.separate_bc else "from dagger"
    return values, settings, methods, skipped, labels


def machine() -> dict:
    from bench.rl_baselines import commit, cpu_model

    return {"cpu": cpu_model(), "cores": os.cpu_count(), "load": os.getloadavg()[0],
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "commit": commit()}


def main(argv=None) -> None:
    args = parse(argv)
    values, settings, methods, skipped, labels = setup(args)
    try:
        results = Results(args.json, settings)
    except ValueError as exc:
        print(f"imitation_table: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    if skipped:
        print(f"imitation_table: {', '.join(skipped)}: not available (ImitateConfig does not take the method yet)",
              file=sys.stderr)
    if not args.no_run:
        start = time.perf_counter()
        results.data["machine"].setdefault("runs", []).append({"start": machine(), "argv": sys.argv[1:]})
        run_table(args, values, results, methods, progress=args.progress)
        results.data["machine"]["runs"][-1].update(end=machine(), seconds=time.perf_counter() - start)
        results.save()
    text = markdown(results, args.systems, methods, args.demos, labels)
    if skipped:
        text += f"\n{', '.join(skipped)}: not available (run_imitation has no such method yet).\n"
    print(text)
    if args.markdown:
        from myriad.runtime.atomic import atomic_write_text

        atomic_write_text(args.markdown, text)
    if args.png:
        plot(results, args.systems, methods, args.demos, labels, args.png)


if __name__ == "__main__":
    main()
