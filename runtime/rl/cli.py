"""``myriad rl-reference``: the reference scores of any spec, or regenerate / check the shipped ones (reference.py).

    myriad rl-reference my/spec.yaml --steps 50 --json out/ref.json   # certified optimum, zero, random (cached)
    myriad rl-reference --write [--systems NAME ...]                  # rewrite reference_scores.json
    myriad rl-reference [--check]                                     # exit 1 when the shipped file is stale
"""

from __future__ import annotations

import json
import sys

__all__ = ["add_parser", "run"]

# Not part of the control problem a reference cost measures (reference.reference_env): no flags of their own.
_NOT_IN_THE_KEY = ("normalize_actions", "max_steps", "start_noise", "randomize", "widen", "process_noise_scale",
                   "observation_noise_scale")


def add_parser(sub) -> None:
    from ..configs import add_arguments
    from ..integrators import INTEGRATORS
    from .env import EnvOptions

    parser = sub.add_parser("rl-reference", help="reference scores of any spec (certified optimum, zero control, "
                            "random); regenerate or check the shipped ones")
    parser.add_argument("target", nargs="?", metavar="NAME|PATH", help="a shipped name, peers/NAME or a spec path: "
                        "print its record (computed once, then read from the cache); without it, the shipped file")
    parser.add_argument("--json", metavar="FILE", help="with SPEC: also write the whole record here")
    parser.add_argument("--scores-dir", metavar="DIR", help="with SPEC: the records' cache folder (default "
                        "$MYRIAD_RL_REFERENCE_CACHE, else $MYRIAD_CACHE/rl-reference, else "
                        "~/.cache/myriad/rl-reference)")
    fixed = sorted(n for n, c in INTEGRATORS.items() if c().fixed_step)
    add_arguments(parser.add_argument_group("the env (with SPEC)"), EnvOptions, choices={"integrator": fixed},
                  skip=_NOT_IN_THE_KEY)
    parser.add_argument("--write", action="store_true",
                        help="solve every shipped system again and rewrite reference_scores.json (minutes)")
    parser.add_argument("--check", action="store_true", help="exit 1 when the shipped scores are stale (the default "
                        "without SPEC or --write)")
    parser.add_argument("--systems", nargs="+", metavar="NAME", help="with --write: only these (the others are kept)")


def _one(args) -> int:
    """Print one spec's record; exit 2 for a bad spec or option, 1 when the optimum is not certified."""
    from ..atomic import atomic_write_text
    from ..configs import from_args, usage_message
    from .env import EnvOptions
    from .optimum import CertificationError
    from .reference import reference_env, reference_record

    try:
        options = from_args(EnvOptions, args)
    except ValueError as e:
        print(f"myriad rl-reference: error: {usage_message(e, EnvOptions)}", file=sys.stderr)
        return 2
    try:
        system = reference_env(args.target, options).system  # the spec and the env checked before certifying
        r = reference_record(system, options, cache_dir=args.scores_dir)
    except (KeyError, ValueError, OSError) as e:  # unknown name, unreadable spec, no bounds for a random policy
        print(f"myriad rl-reference: error: {args.target}: {e}", file=sys.stderr)
        return 2
    except CertificationError as e:
        print(f"myriad rl-reference: not certified: {e}", file=sys.stderr)
        return 1
    c = r["optimal"]["certificate"]
    print(f"{r['system']} (spec {r['spec_sha256'][:12]}, env {r['env']})\n"
          f"  optimal {r['optimal']['cost']:.12g}: {' and '.join(c['methods'])} agree to {c['agreement']:.2e} "
          f"(tolerance {c['tolerance']:g}; {c['costs']})\n"
          f"  zero control {r['zero_control']['cost']:.12g}\n"
          f"  random {r['random']['cost']:.12g} +- {r['random']['std']:.3g} ({r['random']['episodes']} episodes)")
    if "uncertainty" in r:  # a schema 3 spec with uncertain parameters: expected costs under their distributions
        u = r["uncertainty"]
        print(f"  under the declared uncertainty ({u['draws']} draws): nominal plan {u['nominal_plan']['cost']:.8g} "
              f"+- {u['nominal_plan']['se']:.2g}, robust plan ({u['scenarios']} scenarios) "
              f"{u['robust_plan']['cost']:.8g} +- {u['robust_plan']['se']:.2g}")
    if args.json:
        atomic_write_text(args.json, json.dumps(r, indent=1) + "\n")
    return 0


def run(args) -> int:
    from .._command_args import output_file_error, output_folder_error
    from ..systems import NAMES
    from .reference import run as run_reference

    # Before minutes of certifying (a shipped record never touches the cache folder: checked all the same).
    if error := output_file_error(args.json, "--json") or output_folder_error(args.scores_dir, "--scores-dir"):
        print(f"myriad rl-reference: error: {error}", file=sys.stderr)
        return 2
    if args.target is not None:
        if args.write or args.systems:
            print("myriad rl-reference: error: SPEC prints one record; --write/--systems rewrite the shipped file",
                  file=sys.stderr)
            return 2
        return _one(args)
    unknown = sorted(set(args.systems or ()) - set(NAMES))
    if unknown:
        print(f"myriad rl-reference: error: --systems: unknown systems {unknown}", file=sys.stderr)
        return 2
    return run_reference((args.systems or list(NAMES)) if args.write else None, check=args.check)
