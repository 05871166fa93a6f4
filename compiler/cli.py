"""``myriadc``: a thin argparse shell over :mod:`compiler.build`.

Exit codes: 0 ok, 1 spec errors or stale output (``--check``), 2 usage. No traceback unless ``-v``.
"""

from __future__ import annotations

import argparse
import difflib
import sys
import time
from pathlib import Path

from .build import build, check_file, compile_file, spec_files
from .errors import CodegenError, SpecError, flatten, report

__all__ = ["main"]

REPO_SPECS = Path(__file__).resolve().parent.parent / "specs"


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # usage errors exit 2, as argparse does, with our prefix
        self.print_usage(sys.stderr)
        print(f"myriadc: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    def flags(default):
        # Sub-commands accept -v/-q too; SUPPRESS keeps their defaults from overwriting the top-level flags.
        parser = argparse.ArgumentParser(add_help=False)
        parser.add_argument("-v", "--verbose", action="store_true", default=default,
                            help="more output; tracebacks on internal errors")
        parser.add_argument("-q", "--quiet", action="store_true", default=default, help="errors only")
        return parser

    common = flags(argparse.SUPPRESS)
    p = _Parser(prog="myriadc", description="Compile myriad YAML specs into JAX systems.", parents=[flags(False)])
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub_add = sub.add_parser

    def add(name, **kw):
        return sub_add(name, parents=[common], **kw)

    sub.add_parser = add
    b = sub.add_parser("build", help="compile specs into modules (default: the package's runtime/systems)")
    b.add_argument("paths", nargs="+", metavar="PATH", help="spec files or folders of *.yaml")
    b.add_argument("-o", "--out", metavar="DIR", help="output folder (a registry __init__.py is written too)")
    b.add_argument("--check", action="store_true", help="write nothing; exit 1 and print the diff if outputs are stale")
    c = sub.add_parser("check", help="validate specs only (no code is generated)")
    c.add_argument("paths", nargs="+", metavar="PATH")
    ls = sub.add_parser("list", help="a table of the systems in specs/ (or the given paths)")
    ls.add_argument("paths", nargs="*", metavar="PATH")
    s = sub.add_parser("show", help="the equations as compiled, with the derived costates and u*")
    s.add_argument("target", metavar="NAME|PATH")
    cd = sub.add_parser("card", help="problem cards: Markdown pages of the equations, variables, optimality "
                        "conditions and recorded reference results")
    cd.add_argument("targets", nargs="+", metavar="NAME|PATH", help="shipped names, spec files or folders of *.yaml")
    cd.add_argument("-o", "--out", metavar="DIR",
                    help="write DIR/NAME.md per spec, and DIR/README.md (an index) for a folder; default: print the "
                         "one card")
    cd.add_argument("--check", action="store_true",
                    help="with -o: write nothing; exit 1 and print the diff if cards are stale or a plot is missing")
    cd.add_argument("--results", metavar="FILE", help="recorded results (default: DIR/results.json with -o, else "
                    "the repository's docs/cards/results.json when there is one)")
    return p


def _report(errors, out=None) -> None:
    """Every error (at most MAX_REPORTED, then how many more), and the count."""
    out = out or sys.stderr  # looked up per call, so redirected or captured stderr gets the messages
    errors = [single for e in errors for single in (flatten(e) if isinstance(e, SpecError) else [e])]
    print(report(errors), file=out)
    n = len(errors)
    print(f"myriadc: {n} error{'s' if n != 1 else ''}", file=out)


def _clean(text: str) -> str:
    """Spec text for the terminal: no escape sequences or control characters from a hostile spec."""
    return "".join(ch if ch.isprintable() else "?" for ch in text)


def _resolve(target: str) -> Path:
    p = Path(target)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    for base in (Path("specs"), REPO_SPECS):
        if (base / f"{target}.yaml").exists():
            return base / f"{target}.yaml"
    names = sorted({q.stem for base in (Path("specs"), REPO_SPECS) if base.is_dir() for q in base.glob("*.yaml")})
    close = difflib.get_close_matches(target, names, n=3)
    hint = f"; did you mean {' or '.join(close)}?" if close else ""
    raise FileNotFoundError(f"no spec named {target!r} (looked for specs/{target}.yaml){hint}")


def _cmd_build(args) -> int:
    t0 = time.perf_counter()
    result = build(args.paths, args.out, check=args.check)
    return _outcome(result, args, t0, "files", f"myriadc build {' '.join(args.paths)}")


def _outcome(result, args, t0: float, what: str, fix: str) -> int:
    """Report a build or card run: errors (1), stale files with their diffs under --check (1), or what was written."""
    if result.errors:
        _report(result.errors)
        return 1
    if args.check:
        for d in result.diffs:
            sys.stdout.write(d)
        if result.stale:
            print(f"myriadc: stale: {', '.join(result.stale)}; run `{fix}`", file=sys.stderr)
            return 1
        if not args.quiet:
            print(f"myriadc: {len(result.unchanged)} {what} up to date ({time.perf_counter() - t0:.2f} s)")
        return 0
    if not args.quiet:
        for w in result.written:
            print(f"wrote {w}")
        print(f"myriadc: {len(result.written)} written, {len(result.unchanged)} unchanged "
              f"({time.perf_counter() - t0:.2f} s)")
    return 0


def _cmd_check(args) -> int:
    errors = []
    files = spec_files(args.paths)
    for f in files:
        try:
            check_file(f)
        except SpecError as exc:  # one, or several (SpecErrors)
            errors.extend(flatten(exc))
    if errors:
        _report(errors)
        return 1
    if not args.quiet:
        print(f"myriadc: {len(files)} spec{'s' if len(files) != 1 else ''} OK")
    return 0


def _cmd_list(args) -> int:
    paths = args.paths or ([Path("specs")] if Path("specs").is_dir() else [REPO_SPECS])
    rows, errors = [], []
    for f in spec_files(paths):
        try:
            sym = check_file(f)
        except SpecError as exc:
            errors.append(exc)
            continue
        s = sym.spec
        fixed = sum(v is not None for v in sym.x_final)
        rows.append((s.name, str(len(s.states)), str(len(s.controls)), _horizon(sym), s.sense[:3],
                     str(fixed), _clean(s.title)))
    head = ("name", "states", "controls", "T", "sense", "fixed x(T)", "title")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    for r in [head, *rows]:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    if errors:
        _report(errors)
        return 1
    return 0


def _horizon(sym) -> str:
    return f"free [{sym.horizon_bounds[0]:g}, {sym.horizon_bounds[1]:g}]" if sym.free_horizon else f"{sym.horizon:g}"


def _cmd_show(args) -> int:
    c = compile_file(_resolve(args.target))
    s = c.symbolic.spec
    print(f"{s.name}: {_clean(s.title)}  ({_clean(s.file)}, sha256 {s.sha256[:12]})")
    print(f"  {_clean(s.description)}")
    sym = c.symbolic
    states = zip((v.name for v in s.states), sym.x_lower, sym.x_upper, sym.x0, sym.x_final)
    print("  states:   " + ", ".join(f"{n} in [{lo:g}, {hi:g}], x0 = {x0:g}"
                                     + (f", x(T) = {xf:g}" if xf is not None else "")
                                     for n, lo, hi, x0, xf in states))
    print("  controls: " + ", ".join(f"{n} in [{lo:g}, {hi:g}]" for n, lo, hi in
                                     zip((v.name for v in s.controls), sym.u_lower, sym.u_upper)))
    if sym.free_horizon:
        lo, hi = sym.horizon_bounds
        print(f"  T free in [{lo:g}, {hi:g}], guess {sym.horizon:g}; sense: {s.sense} (below in minimisation form)")
    else:
        print(f"  T = {sym.horizon:g}; sense: {s.sense} (below in minimisation form)")
    from .card_schema3 import show_lines

    for line in show_lines(sym):  # schema 3: the uncertainty; nothing for earlier schemas
        print(_clean(line))
    width = max(len(k) for k, _ in c.data.summary)
    for k, v in c.data.summary:
        print(f"  {_clean(k).rjust(width)} = {_clean(v)}")
    return 0


def _cmd_card(args) -> int:
    from .card import build_cards, card_file  # sympy's LaTeX printer is only needed here

    targets = [t if Path(t).is_dir() else _resolve(t) for t in args.targets]
    if args.out is None:
        if args.check or len(spec_files(targets)) != 1:
            print("myriadc: error: --check and several specs need -o DIR", file=sys.stderr)
            return 2
        sys.stdout.write(card_file(spec_files(targets)[0], args.results))
        return 0
    t0 = time.perf_counter()
    result = build_cards(targets, args.out, check=args.check, results_path=args.results)
    return _outcome(result, args, t0, "cards", f"myriadc card {' '.join(args.targets)} -o {args.out}` (results and "
                    f"plots: `python bench/cards.py`")


def main(argv=None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        commands = {"build": _cmd_build, "check": _cmd_check, "list": _cmd_list, "show": _cmd_show, "card": _cmd_card}
        return commands[args.command](args)
    except SpecError as exc:  # one, or several (SpecErrors)
        _report(flatten(exc))
        return 1
    except CodegenError as exc:
        print(f"myriadc: error: {exc}", file=sys.stderr)
        return 1
    except FileNotFoundError as exc:
        print(f"myriadc: error: no such file or spec: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # an internal error: say so plainly, traceback only on request
        if args.verbose:
            raise
        print(f"myriadc: internal error: {type(exc).__name__}: {exc} (rerun with -v for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
