"""The reference table: every system in the published setting, plus the best over all transcriptions.

Published setting (Table A of the paper): single shooting, 100 control intervals with controls at the 101 nodes
linearly interpolated, Heun, IPOPT; state bounds enforced on the shooting node (the final state). A system meets its
target when it converged, its cost is at most target + 0.5 % of |target| and every required final value is met to
1e-6. The targets are each spec's ``reference`` block (``System.reference``), copied from the published tables.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Callable

import numpy as np

from .integrators import RK4, Heun
from .loader import load
from .solve import Solution, solve
from .solvers import Ipopt
from .transcriptions import ForwardBackwardSweep, HermiteSimpson, MultipleShooting, SingleShooting, Trapezoidal

__all__ = ["BenchRow", "run_bench", "bench_system", "markdown_table", "PUBLISHED_SETTING", "ALTERNATIVES",
           "meets_target", "usable_cores"]

PUBLISHED_SETTING = SingleShooting(intervals=100, integrator=Heun())
ALTERNATIVES = (
    MultipleShooting(intervals=50, steps_per_interval=2, integrator=RK4()),
    Trapezoidal(intervals=100),
    HermiteSimpson(intervals=50),
)
DEFECT_TOL = 1e-6


def meets_target(sol: Solution, target: float | None) -> bool | None:
    if target is None:
        return None
    return bool(sol.converged and sol.cost <= target + 0.005 * abs(target) and sol.max_defect <= DEFECT_TOL)


@dataclasses.dataclass
class BenchRow:
    system: str
    published: float | None
    target: float | None
    main: Solution
    meets: bool | None
    best: Solution | None = None
    alternatives: list[Solution] = dataclasses.field(default_factory=list)
    wall_seconds: float = 0.0
    failures: list[str] = dataclasses.field(default_factory=list)  # methods that raised, and why

    def records(self) -> list[dict]:
        ref = {"published": self.published, "target": self.target}
        return [{**self.main.record(), **ref, "setting": "published", "meets_target": self.meets},
                *({**s.record(), **ref, "setting": "alternative", "best": s is self.best} for s in self.alternatives)]


# A re-simulated solution that misses a required final value by more than this is not a candidate for "best": a
# lower cost with a missed terminal condition is not a better solution (Heun's error on 100 steps makes single
# shooting miss Cart-Pole's final angular velocity by about 1.2).
RESIMULATED_DEFECT_TOL = 1e-3


def _resample(system, transcription, sol: Solution):
    """The decision vector of ``transcription`` that samples a solution's trajectories (linear interpolation)."""
    def interp(values):
        return lambda times: np.stack([np.interp(np.asarray(times), sol.times, values[:, j])
                                       for j in range(values.shape[1])], 1)

    return transcription.sample(system, interp(sol.states), interp(sol.controls))


def _best(solutions: list[Solution]) -> Solution | None:
    """Lowest re-simulated cost among converged solves that, re-simulated, still meet their final values and stay
    within the state bounds (the one comparison that is fair across discretisations); else the closest one."""
    ok = [s for s in solutions if s.converged and math.isfinite(s.simulated_cost)]
    if not ok:
        return None
    # A re-simulated trajectory that leaves a state bound (collocation enforces bounds at its nodes only) or misses
    # a final value is not feasible for the continuous problem.
    miss = {id(s): max([abs(d) for d in s.simulated_defect] + [s.simulated_bound_violation]) for s in ok}
    feasible = [s for s in ok if miss[id(s)] <= RESIMULATED_DEFECT_TOL]
    if feasible:
        return min(feasible, key=lambda s: s.simulated_cost)
    return min(ok, key=lambda s: miss[id(s)])


def run_bench(names, *, alternatives: bool = True, solver=None, progress: Callable[[str], None] | None = None,
              plots_dir=None, jobs: int | None = 1) -> list[BenchRow]:
    """One :class:`BenchRow` per system, in the order of ``names``.

    Args:
        jobs: processes solving, this one included; 1: this process alone, None: one per core this process may run
            on. A first run (empty compilation cache) is compile-bound: tracing holds the GIL and XLA compiles a
            program on one thread, so separate processes are what keep every core busy (see :func:`_parallel`).
    """
    names = list(names)
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise ValueError(f"run_bench: jobs must be an integer >= 1 or None, got {jobs!r}")
    processes = min(len(names), jobs or usable_cores())
    if processes <= 1:
        return [bench_system(name, alternatives, solver, plots_dir, progress) for name in names]
    return _parallel(names, processes, alternatives, solver, plots_dir, progress)


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the platform says, else the CPU count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def bench_system(name: str, alternatives: bool = True, solver=None, plots_dir=None,
                 progress: Callable[[str], None] | None = None) -> BenchRow:
    """One system's row: the published setting, then (``alternatives``) every other transcription and the best."""
    solver = solver or Ipopt()
    t0 = time.perf_counter()
    system = load(name)
    ref = dict(system.reference)
    main = solve(system, PUBLISHED_SETTING, solver)
    row = BenchRow(name, ref.get("published"), ref.get("target"), main, meets_target(main, ref.get("target")))
    if alternatives:
        methods = list(ALTERNATIVES)
        if system.optimal_control_kind == "stationary":
            methods.append(ForwardBackwardSweep(intervals=1000))
        for tr in methods:
            try:
                sol = solve(system, tr, solver if tr.uses_solver else None)
                if not sol.converged and hasattr(tr, "sample"):
                    # Cold guesses (states interpolated straight to the target) strand collocation on swing-ups
                    # such as Pendulum ("local infeasibility"); the published-setting solution, resampled onto
                    # this grid, is the usual homotopy. Marked as such in the record.
                    warm = solve(system, tr, solver, z0=_resample(system, tr, main))
                    sol = dataclasses.replace(warm, message=f"{warm.message} [warm-started from the "
                                              f"published-setting solution; cold start: {sol.message}]")
                row.alternatives.append(sol)
            except Exception as exc:  # one method failing must not lose the table; it is recorded as such
                row.failures.append(f"  {name}: {type(tr).__name__} failed: {exc}")
                if progress:
                    progress(row.failures[-1])
        row.best = _best([main, *row.alternatives])
    row.wall_seconds = time.perf_counter() - t0
    if plots_dir is not None:
        from .plotting import plot_solution

        plot_solution(main, f"{plots_dir}/{name}.png", system)
    if progress:
        progress(_line(row))
    return row


def _worker_setup(cache_folder: str | None, x64: bool, compiler_options: dict | None) -> None:
    """A worker's JAX as its parent's: float width, XLA options and the same compilation cache (so programs compiled
    by one process are read back by the others and by later runs)."""
    import jax

    from .compilation import programs
    from .compilation.jax_cache import enable_compilation_cache

    jax.config.update("jax_enable_x64", x64)
    programs.set_compiler_options(compiler_options)
    if cache_folder:
        enable_compilation_cache(cache_folder)
    # Python's collector as in `myriad` itself (runtime/cli.py): fewer passes while tracing, and at the exit, which the
    # bench waits for, no walk over the heap (frozen before Python's last collections; 0.7-0.9 s a process, issue 31).
    import atexit
    import gc

    gc.set_threshold(50_000, 10, 10)
    atexit.register(gc.freeze)


def _expected_work(name: str) -> int:
    """The size of a shipped system's generated module: its programs' trace and compile time grows with it (the
    largest, Cart-Pole's, took 2.6 s, the smallest 1.1 s), so the biggest go first and the last to finish is a small
    one (longest-processing-time-first scheduling). 0 for anything else."""
    import importlib.util

    from .systems import MODULES

    spec = importlib.util.find_spec(MODULES[name]) if name in MODULES else None
    return os.path.getsize(spec.origin) if spec is not None and spec.origin else 0


def _parallel(names, jobs, alternatives, solver, plots_dir, progress) -> list[BenchRow]:
    """The systems spread over this process and ``jobs - 1`` spawned ones (JAX must not be forked once started), each
    taking the next system when it finishes one, the largest first (:func:`_expected_work`); rows from the workers
    come back pickled (a :class:`Solution` is NumPy and plain values) and are reported as they finish.

    This process works too rather than wait: it has imported JAX and the package already (~2.3 s of CPU that a
    further worker would spend again). A thread per worker hands it one system at a time and waits.
    """
    import jax

    from .compilation import programs

    queue = collections.deque(sorted(names, key=_expected_work, reverse=True))
    lock = threading.Lock()
    rows: dict[str, BenchRow] = {}
    errors: list[BaseException] = []

    def work(bench: Callable[..., BenchRow]) -> None:
        """Solve the next system until none is left or a solve raised (one that raised ends the bench)."""
        try:
            while True:
                with lock:
                    if not queue or errors:
                        return
                    name = queue.popleft()
                row = bench(name, alternatives, solver, plots_dir)
                with lock:
                    rows[name] = row
                    for line in [*row.failures, _line(row)] if progress else ():
                        progress(line)
        except BaseException as exc:  # noqa: BLE001 (re-raised in the main thread, an interrupt included)
            with lock:
                errors.append(exc)

    pool = ProcessPoolExecutor(
        max_workers=jobs - 1, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_setup,
        initargs=(jax.config.jax_compilation_cache_dir or None, bool(jax.config.jax_enable_x64),
                  programs.compiler_options()))
    threads = [threading.Thread(target=work, args=(lambda *a: pool.submit(bench_system, *a).result(),),
                                name="bench-worker", daemon=True) for _ in range(jobs - 1)]
    for thread in threads:
        thread.start()
    try:
        work(bench_system)
    finally:
        for thread in threads:
            thread.join()
        pool.shutdown(wait=True, cancel_futures=True)
    if errors:
        raise errors[0]
    return [rows[name] for name in names]


def _f(v, fmt="{:.6g}") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def _line(row: BenchRow) -> str:
    m = row.main
    verdict = {True: "meets target", False: "MISSES target", None: "no target"}[row.meets]
    text = (f"{row.system:18s} cost {m.cost:12.6g} (target {_f(row.target)}) defect {m.max_defect:.1e} {verdict}; "
            f"compile {m.compile_seconds:.2f} s solve {m.solve_seconds:.2f} s")
    if row.best is not None:
        text += f"; best {row.best.transcription} {row.best.simulated_cost:.6g} (re-simulated)"
    return text


def markdown_table(rows: list[BenchRow], total_seconds: float | None = None) -> str:
    head = ("| system | published | target | cost | max defect | converged | meets target | compile s | solve s "
            "| re-simulated cost | best transcription | its re-simulated cost | its defect |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        m, b = r.main, r.best
        lines.append("| " + " | ".join([
            r.system, _f(r.published), _f(r.target), _f(m.cost, "{:.4f}"), _f(m.max_defect, "{:.1e}"),
            "yes" if m.converged else "NO", {True: "yes", False: "NO", None: "-"}[r.meets],
            _f(m.compile_seconds, "{:.2f}"), _f(m.solve_seconds, "{:.2f}"), _f(m.simulated_cost, "{:.4f}"),
            b.transcription if b else "-", _f(b.simulated_cost, "{:.4f}") if b else "-",
            _f(max((abs(d) for d in b.simulated_defect), default=0.0), "{:.1e}") if b else "-",
        ]) + " |")
    if total_seconds is not None:
        lines.append("")
        lines.append(f"Total wall time: {total_seconds:.1f} s.")
    return "\n".join(lines) + "\n"
