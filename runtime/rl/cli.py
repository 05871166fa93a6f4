"""``myriad rl-reference`` (and ``python -m myriad.runtime.rl``): regenerate or check the shipped reference scores."""

from __future__ import annotations

import sys

__all__ = ["add_parser", "run"]


def _arguments(parser) -> None:
    parser.add_argument("--write", action="store_true",
                        help="solve every candidate again and rewrite reference_scores.json (minutes)")
    parser.add_argument("--check", action="store_true", help="exit 1 when the shipped scores are stale (the default "
                        "without --write)")
    parser.add_argument("--systems", nargs="+", metavar="NAME", help="with --write: only these (the others are kept)")


def add_parser(sub) -> None:
    _arguments(sub.add_parser("rl-reference", help="regenerate or check the RL reference scores"))


def run(args) -> int:
    from ..systems import NAMES
    from .reference import run as run_reference

    unknown = sorted(set(args.systems or ()) - set(NAMES))
    if unknown:
        print(f"myriad rl-reference: error: --systems: unknown systems {unknown}", file=sys.stderr)
        return 2
    return run_reference((args.systems or list(NAMES)) if args.write else None, check=args.check)


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m myriad.runtime.rl", description=__doc__.splitlines()[0])
    _arguments(parser)
    return run(parser.parse_args(argv))
