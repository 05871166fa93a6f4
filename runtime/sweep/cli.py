"""``myriad sweep``: systems x methods x seeds on a backend, printed as one table (and written as JSON/CSV/Markdown).

Every argument, method setting and system is checked before any work (exit 2); the tables are written atomically;
exit 1 when any task failed or raised (its record says why), 0 when all are ``ok``.
"""

from __future__ import annotations

import sys
import time

from .._command_args import first_error, usage

__all__ = ["add_parser", "run"]

# The config's fields as this command spells them, in its messages.
_SPELLED = {"methods": ("--method",), "systems": ("the systems (NAME|PATH)",)}


def add_parser(sub) -> None:
    from .backends import BACKENDS
    from .kinds import KINDS

    s = sub.add_parser("sweep", help="systems x methods x seeds on one machine or a Ray cluster, as one table")
    s.add_argument("systems", nargs="+", metavar="NAME|PATH")
    s.add_argument("--method", dest="methods", action="extend", nargs="+", metavar="[NAME=]KIND[:KEY=VALUE,...]",
                   help=f"one or more methods; KIND is one of {', '.join(KINDS)}; values are JSON or plain words, "
                        "e.g. trap=solve:transcription=trapezoidal,intervals=20 (default: solve, the published "
                        "setting); see runtime/sweep/README.md")
    s.add_argument("--seeds", type=int, nargs="+", default=[0], metavar="S", help="default: 0")
    s.add_argument("--backend", choices=list(BACKENDS), default="serial",
                   help="serial (this process, default), process (local spawned processes) or ray")
    s.add_argument("--address", metavar="ADDR", help="ray: a running cluster (HOST:PORT or auto); default: start "
                                                      "a local one for this sweep")
    s.add_argument("--workers", type=int, metavar="N", help="process: processes (default: CPU count); ray: tasks "
                                                             "in flight at once")
    cache = s.add_mutually_exclusive_group()
    cache.add_argument("--cache-dir", metavar="DIR", help="the JAX compilation cache the workers share "
                                                          "(default: $MYRIAD_JAX_CACHE, else ~/.cache/myriad/jax)")
    cache.add_argument("--no-cache", action="store_true", help="no persistent compilation cache")
    s.add_argument("--json", metavar="FILE", help="every record, with the sweep's configuration")
    s.add_argument("--csv", metavar="FILE", help="every field of every record, one row per task")
    s.add_argument("--markdown", metavar="FILE", help="the printed table")


def run(args) -> int:
    from ..compilation.jax_cache import compilation_cache_dir as resolve_cache_dir
    from ..configs import usage_message
    from .backends import BACKENDS
    from .backends.base import BackendUnavailable
    from .config import SweepConfig, parse_method
    from .run import run_sweep
    from .table import markdown, write_tables

    if args.address is not None and args.backend != "ray":
        return usage("sweep", "--address applies to --backend ray")
    if args.workers is not None:
        if args.backend == "serial":
            return usage("sweep", "--workers applies to --backend process or ray")
        if args.workers < 1:
            return usage("sweep", "--workers must be at least 1")
    if error := first_error(args, files=("json", "csv", "markdown")):
        return usage("sweep", error)
    cache_dir = None if args.no_cache else resolve_cache_dir(args.cache_dir)
    try:
        methods = [parse_method(text) for text in args.methods or ["solve"]]
    except ValueError as exc:
        return usage("sweep", f"--method: {exc}")
    try:
        config = SweepConfig(systems=args.systems, methods=methods, seeds=args.seeds, cache_dir=cache_dir)
    except ValueError as exc:
        return usage("sweep", usage_message(exc, SweepConfig, _SPELLED))
    try:
        options = {"address": args.address} if args.backend == "ray" else {}
        if args.workers is not None:
            options["workers"] = args.workers
        backend = BACKENDS[args.backend](**options)
        backend.check()
        config.check_systems()
    except (ValueError, KeyError) as exc:
        return usage("sweep", exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc))
    sizes = {"system": len(config.systems), "method": len(config.methods), "seed": len(config.seeds)}
    n = sizes["system"] * sizes["method"] * sizes["seed"]
    grid = " x ".join(f"{k} {w}{'s' * (k != 1)}" for w, k in sizes.items())
    print(f"sweep: {n} tasks ({grid}) on the {backend.name} backend", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    try:
        records = run_sweep(config, backend)
    except BackendUnavailable as exc:
        return usage("sweep", str(exc))
    wall = time.perf_counter() - t0
    print(markdown(records), end="")
    counts = {s: sum(r["status"] == s for r in records) for s in ("ok", "failed", "error")}
    print(f"{counts['ok']} / {n} ok, {counts['failed']} failed, {counts['error']} raised; {wall:.1f} s wall")
    for path in write_tables(records, json_path=args.json, csv_path=args.csv, markdown_path=args.markdown,
                             config=config.record()):
        print(f"  wrote {path}")
    return 0 if counts["ok"] == n else 1
