"""``myriad rl-reference``: regenerate or check the shipped reference scores (reference.py)."""

from __future__ import annotations

import sys

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    parser = sub.add_parser("rl-reference", help="regenerate or check the RL reference scores")
    parser.add_argument("--write", action="store_true",
                        help="solve every candidate again and rewrite reference_scores.json (minutes)")
    parser.add_argument("--check", action="store_true", help="exit 1 when the shipped scores are stale (the default "
                        "without --write)")
    parser.add_argument("--systems", nargs="+", metavar="NAME", help="with --write: only these (the others are kept)")


def run(args) -> int:
    from ..systems import NAMES
    from .reference import run as run_reference

    unknown = sorted(set(args.systems or ()) - set(NAMES))
    if unknown:
        print(f"myriad rl-reference: error: --systems: unknown systems {unknown}", file=sys.stderr)
        return 2
    return run_reference((args.systems or list(NAMES)) if args.write else None, check=args.check)
