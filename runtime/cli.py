"""``myriad``: solve one system, or run the reference table. A thin argparse shell over :mod:`myriad.runtime`.

Exit codes: 0 ok, 1 a solve failed or missed its target, 2 usage. Usage errors (a solver for a method that takes
none, an output file whose folder is missing or not writable, ...) are found before any system is loaded or solved.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import gc
import importlib
import json
import os
import sys
import time

from ._command_args import output_file_error, output_folder_error, plot_format_error
from .configs import add_arguments, from_args, usage_message

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        print(f"myriad: error: {message}", file=sys.stderr)
        raise SystemExit(2)

    def _get_value(self, action, arg_string):
        # A choice matches case-insensitively where only one choice folds to it (--solver IPOPT is ipopt).
        value = super()._get_value(action, arg_string)
        if action.choices is not None and isinstance(value, str) and value not in action.choices:
            folded = [c for c in action.choices if isinstance(c, str) and c.lower() == value.lower()]
            if len(folded) == 1:
                return folded[0]
        return value

    def _check_value(self, action, value):
        if action.choices is not None and value not in action.choices:
            names = [str(c) for c in action.choices]
            close = difflib.get_close_matches(str(value), names, n=3)
            hint = f"did you mean {' or '.join(close)}?" if close else f"choose from {', '.join(names)}"
            raise argparse.ArgumentError(action, f"invalid choice {value!r}; {hint}")

    def reject_unknown(self, extras):
        """Exit 2 naming the first unknown argument, with the closest of this parser's flags."""
        flag = extras[0].split("=", 1)[0]
        known = [o for a in self._actions for o in a.option_strings]
        close = difflib.get_close_matches(flag, known, n=3) if flag.startswith("-") else []
        hint = f"; did you mean {' or '.join(close)}?" if close else f"; see {self.prog} --help"
        self.error(f"unrecognized argument {extras[0]}{hint}")


# SolveConfig's flags where they are not --field-name, and their usage-line names.
_SOLVE_SPELLED = {"intervals": ("--intervals", "--controls")}
_SOLVE_METAVARS = {"intervals": "N", "tolerance": "TOL", "max_refinements": "K", "max_intervals": "N",
                   "x0_std": "F", "seed": "S"}


# Every command, in `myriad --help`'s order, with its one-line summary. A command's parser is built whole only when
# that command runs (or for `_parser()`): the others are their names and summaries, so `myriad --help` imports no
# JAX (the registries behind the choices) and no package (equinox, optax, gymnasium). The package commands' parsers
# (add_parser) and run() live in a package's cli.py, whose add_parser says the same summary
# (tests/runtime/test_cold_start.py checks).
_COMMANDS = {
    "solve": "solve one system",
    "sysid": "system identification: fit a model to trajectories, plan on it",
    "sweep": "systems x methods x seeds on one machine or a Ray cluster, as one table",
    "e2e": "end-to-end learning: imitate the true optimum through the planner (Algorithm 2)",
    "rl-reference": "reference scores of any spec (certified optimum, zero control, random); regenerate or check the "
                    "shipped ones",
    "dataset": "an offline dataset (Minari) of a policy's episodes in a system's env",
    "imitate": "imitation baselines: behaviour cloning, DAgger or end-to-end learning from optimal demonstrations",
    "bench": "the reference table (published setting + best over transcriptions)",
}
# The package commands -> their package.
_PACKAGE_COMMANDS = {"sysid": "sysid", "sweep": "sweep", "e2e": "e2e", "rl-reference": "rl", "dataset": "datasets",
                     "imitate": "imitation"}


def _parser(command: str | None = None):
    """The argument parser: every command's whole parser, or with ``command`` that one alone (any other word, e.g.
    ``""``: none) and the others as their names and summaries, enough for the top-level help and its errors."""
    p = _Parser(prog="myriad", description="Trajectory optimisation on myriad systems.")
    p.add_argument("-v", "--verbose", action="store_true", help="tracebacks on internal errors")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, summary in _COMMANDS.items():
        if command is not None and name != command:
            sub.add_parser(name, help=summary)
        elif name in _PACKAGE_COMMANDS:
            importlib.import_module(f".{_PACKAGE_COMMANDS[name]}.cli", __package__).add_parser(sub)
        else:
            {"solve": _add_solve, "bench": _add_bench}[name](sub.add_parser(name, help=summary))
        if name != "sweep" and (command is None or name == command):  # the sweep has its own, for its workers too
            cache = sub.choices[name].add_mutually_exclusive_group()
            cache.add_argument("--cache-dir", metavar="DIR",
                               help="JAX's persistent compilation cache, reused by later runs and safe to delete "
                                    "(default: $MYRIAD_JAX_CACHE, else ~/.cache/myriad/jax)")
            cache.add_argument("--no-cache", action="store_true", help="no persistent compilation cache")
    return p


def _add_solve(s) -> None:
    # The choices come from the registries: a new transcription, solver or integrator appears here by itself.
    from .integrators import INTEGRATORS
    from .solve_config import METHODS, SolveConfig
    from .solvers import SOLVERS

    s.add_argument("system", metavar="NAME|PATH")
    add_arguments(s, SolveConfig, spelled=_SOLVE_SPELLED, metavars=_SOLVE_METAVARS,
                  choices={"transcription": list(METHODS), "solver": list(SOLVERS),
                           "integrator": [n for n, c in INTEGRATORS.items() if c.fixed_step]})
    s.add_argument("--json", metavar="FILE", help="write the solution record (and trajectory) as JSON")
    s.add_argument("--plot", metavar="FILE.png", help="plot states and controls")
    s.add_argument("--error-tolerance", type=float, default=None, metavar="TOL",
                   help="warn (on stderr) when the error estimate, the relative local error of the dynamics on the "
                        "method's grid, exceeds TOL (default: warn only when the re-simulation disagrees)")
    _add_compile(s, "each program runs once or for one solve")


def _add_bench(b) -> None:
    from .solvers import SOLVERS

    b.add_argument("--systems", nargs="+", metavar="NAME", help="default: all shipped systems")
    b.add_argument("--json", metavar="FILE")
    b.add_argument("--markdown", metavar="FILE")
    b.add_argument("--plots", metavar="DIR", help="one PNG per system (published-setting solution)")
    b.add_argument("--published-only", action="store_true", help="skip the other transcriptions")
    b.add_argument("--jobs", type=int, metavar="N",
                   help="processes solving, one system each at a time, this one included (default: one per usable "
                        "core; 1: this process alone)")
    _add_compile(b, "each program runs for one solve")
    b.add_argument("--solver", default=None, choices=list(SOLVERS),
                   help="the NLP solver of every direct transcription in the table (default: ipopt)")


def _add_compile(parser, why: str) -> None:
    parser.add_argument("--compile", choices=("quick", "full"), default="quick",
                        help=f"XLA backend optimisation: quick (level 0, no CPU fusion emitters; the default: {why}, "
                             "and compiling is most of a first run) or full (XLA's default, for timing the solves)")


@contextlib.contextmanager
def _compiler_options(choice: str):
    """``--compile``'s XLA options while the command runs (main() may be called in a process that compiles more)."""
    from .compilation import programs

    previous = programs.compiler_options()
    programs.set_compiler_options(programs.QUICK if choice == "quick" else None)
    try:
        yield
    finally:
        programs.set_compiler_options(previous)


def _configure_jax(args=None):
    import jax

    from .compilation.jax_cache import enable_compilation_cache

    jax.config.update("jax_enable_x64", True)  # trajectory optimisation needs float64
    # Before anything compiles: JAX reads the cache folder once, at its first compilation.
    if args is not None and not getattr(args, "no_cache", False):
        enable_compilation_cache(getattr(args, "cache_dir", None))


def _solve_config(args):
    """The :class:`~myriad.runtime.solve_config.SolveConfig` of the arguments (``ValueError``: a usage error)."""
    from .solve_config import SolveConfig

    return from_args(SolveConfig, args)


def _usage(message):
    print(f"myriad: error: {message}", file=sys.stderr)
    return 2


def _first_error(*errors):
    return next((e for e in errors if e is not None), None)


# `myriad solve SPEC.yaml`: the process compiling the spec beside this one (_compile_spec_aside), or None.
_ASIDE = None


def _compile_spec_aside(argv: list[str]):
    """Compile a spec file of ``argv`` (sympy: about 0.6 s CPU from cold) in a second process while this one imports
    JAX for the solve (about 1.2 s): on two or more cores a new spec's first solve starts that much sooner. The module
    is written where :func:`~myriad.runtime.loader.load` looks for it; any failure there is ignored (load compiles
    again and reports it). Returns the process, or None (no spec file, or one core)."""
    import subprocess

    specs = [a for a in argv if a.lower().endswith((".yaml", ".yml")) and os.path.isfile(a)]
    if len(specs) != 1 or (os.cpu_count() or 1) < 2:
        return None
    code = "import sys; from myriad.runtime.loader import compiled_spec; compiled_spec(sys.argv[1])"
    try:
        return subprocess.Popen([sys.executable, "-c", code, specs[0]], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None


def _cmd_solve(args) -> int:
    _configure_jax(args)
    from . import load
    from .solve_config import SolveConfig

    try:
        config = _solve_config(args)  # checked before the system is even loaded
    except ValueError as exc:
        return _usage(usage_message(exc, SolveConfig, _SOLVE_SPELLED))
    error = _first_error(
        None if args.error_tolerance is None or args.error_tolerance > 0
        else f"--error-tolerance must be positive, got {args.error_tolerance}",
        output_file_error(args.json, "--json"), output_file_error(args.plot, "--plot"),
        plot_format_error(args.plot, "--plot"))
    if error:
        return _usage(error)
    warn_above = args.error_tolerance
    if _ASIDE is not None:  # the spec compiled beside the JAX import: load() finds it
        _ASIDE.wait()
    system = load(args.system)
    if not config.build()[0].uses_solver:  # an indirect method: refused before any work (direct ones enforce them)
        from .system import UnsupportedFeature

        try:
            system.require_schema1_features(f"--transcription {config.transcription}")
        except UnsupportedFeature as exc:
            return _usage(f"{exc}; choose a direct transcription")
    with _compiler_options(args.compile):
        sol = config.solve(system)
    state = "converged" if sol.converged else "NOT CONVERGED"
    print(f"{system.name}: {sol.transcription} + {sol.solver} ({sol.integrator}): {state} after {sol.iterations} "
          f"iterations ({sol.message})")
    grid = "" if sol.intervals is None else f"; grid {sol.intervals} control intervals"
    print(f"  status {sol.status} (solver code {sol.solver_code}){grid}")
    print(f"  cost {sol.cost:.8g}   defect {[f'{d:.2e}' for d in sol.defect] or 'none required'}   "
          f"constraint violation {sol.constraint_violation:.2e}")
    if config.resimulate:
        print(f"  re-simulated (adaptive): cost {sol.simulated_cost:.8g}, defect "
              f"{[f'{d:.2e}' for d in sol.simulated_defect] or '-'}; agreement gap {sol.agreement_gap:.1e} "
              f"(tolerance {sol.agreement_tolerance:.3g})")
    if system.free_horizon:
        lo, hi = system.horizon_bounds
        print(f"  final time T = {sol.final_time:.10g} (free in [{lo:g}, {hi:g}], guess {system.horizon_guess:g})")
    if system.n_path:
        print(f"  path constraints ({', '.join(system.path_constraint_names)}): largest violation over the nodes "
              f"{sol.path_violation:.2e}")
    _report_error_estimate(sol, warn_above)
    _report_refinement(sol)
    if sol.accuracy_warning and sol.refinement is None:  # refinement that stopped short has said why
        print(f"myriad: warning: {sol.accuracy_warning}", file=sys.stderr)
    print(f"  compile {sol.compile_seconds:.2f} s, solve {sol.solve_seconds:.2f} s (last grid)")
    if args.json:
        rec = sol.record()
        rec.update(times=sol.times.tolist(), states=sol.states.tolist(), controls=sol.controls.tolist())
        with open(args.json, "w") as fh:
            json.dump(rec, fh, indent=1)
    if args.plot:
        from .plotting import plot_solution

        plot_solution(sol, args.plot, system)
        print(f"  plot: {args.plot}")
    return 0 if sol.accurate else 1


def _report_refinement(sol):
    if sol.refinement is None:
        return
    r = sol.refinement
    levels = "  ".join(f"{h['intervals']}: {h['error']:.1e}" for h in r["history"])
    print(f"  mesh refinement ({len(r['history'])} grids, intervals: error): {levels}")
    if r["met"]:
        print(f"  refinement met the tolerance {r['tolerance']:.3g}: {r['reason']}")
    else:
        print(f"myriad: warning: mesh refinement stopped before meeting the tolerance {r['tolerance']:.3g}: "
              f"{r['reason']}", file=sys.stderr)


def _report_error_estimate(sol, tolerance):
    import math

    import numpy as np

    if math.isnan(sol.error_estimate):
        why = "not computed by this method" if sol.interval_errors is None else "the trajectory is not finite"
        print(f"  error estimate: none ({why})")
        return
    print(f"  error estimate {sol.error_estimate:.2e} (relative local error of the dynamics, max over "
          f"{sol.interval_errors.size} intervals)")
    if tolerance is not None and sol.error_estimate > tolerance:
        worst = int(np.argmax(sol.interval_errors))
        over = int(np.sum(sol.interval_errors > tolerance))
        # Hermite-Simpson's grid interleaves midpoints: its intervals span two points of sol.times.
        t = sol.times[worst * (sol.times.size - 1) // sol.interval_errors.size]
        print(f"myriad: warning: error estimate {sol.error_estimate:.2e} exceeds the tolerance {tolerance:.3g} "
              f"on {over} of {sol.interval_errors.size} intervals (largest from t = {t:.4g}): the grid is too "
              f"coarse for the dynamics; use more --intervals, a higher-order method, or --tolerance to refine the "
              f"mesh", file=sys.stderr)


def _cmd_package(args) -> int:
    _configure_jax(args)
    return importlib.import_module(f".{_PACKAGE_COMMANDS[args.command]}.cli", __package__).run(args)


def _cmd_bench(args) -> int:
    _configure_jax(args)
    from .bench import markdown_table, run_bench
    from .systems import NAMES

    names = args.systems or list(NAMES)
    unknown = [n for n in names if n not in NAMES]
    error = _first_error(f"--systems: unknown systems {unknown}; shipped: {', '.join(NAMES)}" if unknown else None,
                         output_file_error(args.json, "--json"), output_file_error(args.markdown, "--markdown"),
                         output_folder_error(args.plots, "--plots"),
                         "--jobs must be at least 1" if args.jobs is not None and args.jobs < 1 else None)
    if error:
        return _usage(error)
    if args.plots:
        os.makedirs(args.plots, exist_ok=True)
    t0 = time.perf_counter()
    from .solvers import SOLVERS

    solver = SOLVERS[args.solver]() if args.solver else None
    with _compiler_options(args.compile):
        rows = run_bench(names, alternatives=not args.published_only, solver=solver,
                         progress=lambda s: print(s, flush=True), plots_dir=args.plots, jobs=args.jobs)
    total = time.perf_counter() - t0
    table_seconds = sum(r.main.compile_seconds + r.main.solve_seconds for r in rows)
    table = markdown_table(rows, total)
    print()
    print(table)
    print(f"published-setting table: {sum(1 for r in rows if r.meets)} / {len(rows)} meet their target; "
          f"compile + solve {table_seconds:.1f} s; whole bench {total:.1f} s wall")
    if args.markdown:
        with open(args.markdown, "w") as fh:
            fh.write(table)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump([rec for r in rows for rec in r.records()], fh, indent=1)
    return 0 if all(r.meets is not False for r in rows) else 1


# Python's cyclic garbage collector during a command: a first generation of 50,000 objects, not 700. Tracing a JAX
# program allocates millions of short-lived objects, and at 700 the collector ran about 660 times in a cold
# `myriad solve`, 0.45-0.50 s of its CPU time; at 50,000 it runs 8 times, 0.18 s (2-core AMD EPYC, issue 31). Memory is
# still bounded: a cycle waits for at most 50,000 new objects.
_GC_THRESHOLD = (50_000, 10, 10)


def main(argv=None) -> int:
    """The ``myriad`` command (``argv``: its arguments; None: this process's, as the installed command runs it)."""
    previous, frozen = gc.get_threshold(), gc.get_freeze_count()
    gc.set_threshold(*_GC_THRESHOLD)
    try:
        return _main(argv)
    finally:
        _stop_aside()
        if argv is None:  # the process's command: all it holds lives until the exit, when Python's collector
            # would walk it all again (0.7-0.9 s of a solve's exit, 2-core AMD EPYC): frozen, it is skipped.
            gc.freeze()
        else:  # inside a longer process (tests, a notebook): its collector is left as it was
            gc.set_threshold(*previous)
            if not frozen:
                gc.unfreeze()


def _stop_aside() -> None:
    """End the spec's compiling process if the command stopped before it was needed (a usage error)."""
    global _ASIDE
    if _ASIDE is not None:
        if _ASIDE.poll() is None:
            _ASIDE.kill()
        _ASIDE.wait()
        _ASIDE = None


def _main(argv=None) -> int:
    global _ASIDE
    argv = sys.argv[1:] if argv is None else list(argv)
    # The command's parser alone is built whole: `myriad --help` and the other commands import no other's.
    word = next((a for a in argv if not a.startswith("-")), "")
    folded = [name for name in _COMMANDS if name.lower() == word.lower()]  # as _Parser takes it: SWEEP is sweep
    if folded == ["solve"] and "-h" not in argv and "--help" not in argv:
        _ASIDE = _compile_spec_aside(argv)
    parser = _parser(folded[0] if len(folded) == 1 else "")
    args, extras = parser.parse_known_args(argv)
    if extras:  # reported by the subcommand's parser: its usage, its flags (argparse would show the top level's)
        sub = parser._subparsers._group_actions[0].choices.get(args.command) if args.command else None
        (sub or parser).reject_unknown(extras)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    if error := output_folder_error(getattr(args, "cache_dir", None), "--cache-dir"):  # every command has one
        return _usage(error)
    # What the command's parser imported (JAX, for a solve) lives as long as the process: the collector's full passes
    # skip it from now on (0.18 -> 0.07 s of a cold solve's CPU in those 8 passes).
    gc.freeze()
    try:
        return {"solve": _cmd_solve, "bench": _cmd_bench}.get(args.command, _cmd_package)(args)
    except KeyError as exc:
        print(f"myriad: error: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        from myriad.compiler import SpecError, SpecErrors

        if isinstance(exc, (SpecError, SpecErrors)):
            print(str(exc), file=sys.stderr)
            return 1
        if args.verbose:
            raise
        print(f"myriad: internal error: {type(exc).__name__}: {exc} (rerun with -v for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
