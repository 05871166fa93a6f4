"""``myriad imitate``: behaviour cloning, DAgger or the end-to-end learner from optimal demonstrations, scored in the
env.

Arguments are checked before any work (exit 2); the JSON record and the plots are written atomically; exit 1 when
the training failed (a non-finite loss: the reason on stderr and in the record's ``status`` and ``message``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from .._command_args import add_training_outputs, first_error, usage

__all__ = ["add_parser", "run"]

_METAVARS = {"demos": "N", "seed": "S", "start_noise": "F", "held_out": "F", "mismatch": "F", "noise": "F",
             "score_episodes": "N"}


def add_parser(sub) -> None:
    from ..configs import add_arguments
    from .run import ImitateConfig

    s = sub.add_parser("imitate", help="imitation baselines: behaviour cloning, DAgger or end-to-end learning from "
                                       "optimal demonstrations",
                       epilog="exit 0: trained and scored; 1: the training failed (reason on stderr and in the "
                              "record); 2: a usage error, before any work")
    s.add_argument("system", metavar="NAME|PATH")
    # The flags are ImitateConfig's fields (--fit, --dagger and --e2e take JSON; --set fit.epochs=... or
    # --set e2e.iterations=... reaches a nested one).
    add_arguments(s, ImitateConfig, metavars=_METAVARS)
    s.add_argument("--dataset", metavar="PATH", default=None,
                   help="demonstrations from a dataset `myriad dataset` wrote (its Minari folder or .npz) instead of "
                        "collecting --demos optimal episodes")
    add_training_outputs(s, "the fit's loss curve and the policy's episode beside the optimum (PNG)")


def run(args) -> int:
    from ..configs import from_args, usage_message
    from .run import ImitateConfig

    if error := first_error(args):
        return usage("imitate", error)
    try:
        config = from_args(ImitateConfig, args)
    except ValueError as exc:
        return usage("imitate", usage_message(exc, ImitateConfig))
    if args.dataset is not None and not Path(args.dataset).exists():
        return usage("imitate", f"--dataset {args.dataset}: no such file or folder; write one with `myriad dataset`")
    from ..loader import load
    from ..rl.reference import reference_env
    from .e2e import require_learnable

    system = load(args.system)
    try:  # before any work: a model to learn (e2e); else finite controls, for a policy's output to squash into
        if config.method == "e2e":
            require_learnable(system, config.e2e)
        else:
            reference_env(system).require_finite_controls("a policy's output cannot be squashed into them")
    except ValueError as exc:
        return usage("imitate", str(exc))
    if args.dataset is not None:  # another spec's or env version's, or too few episodes: refused before any work
        from ..datasets.storage import load_dataset

        try:
            episodes, _ = load_dataset(args.dataset, system)
        except (OSError, ValueError) as exc:
            return usage("imitate", f"--dataset {args.dataset}: {exc}")
        if len(episodes) < config.demos:
            return usage("imitate", f"--dataset {args.dataset} has {len(episodes)} episodes, fewer than --demos "
                                    f"{config.demos}")
        if config.method == "e2e":
            from .e2e import check_starts

            try:
                check_starts(system, episodes.observations[: config.demos], f"--dataset {args.dataset}")
            except ValueError as exc:
                return usage("imitate", str(exc))
            if episodes.actions.shape[1] != reference_env(system).options.steps:  # the plan is scored on its grid
                return usage("imitate", f"--dataset {args.dataset}: episodes of {episodes.actions.shape[1]} steps; "
                                        f"--method e2e needs the env's own {reference_env(system).options.steps}")
    from .run import run_imitation

    report = run_imitation(system, config, dataset=args.dataset, checkpoint_dir=args.checkpoint, resume=args.resume)
    rec = report.record()
    print(f"{system.name}: {config.method} from {config.demos} demonstrations (seed {config.seed}), "
          f"{sum(report.seconds.values()):.1f} s ({report.status})")
    scores = report.scores
    print(f"  normalised score {scores['normalized_score']:.2f} (return {scores['episode_return']:.6g}); under "
          f"mismatch +-{config.mismatch:g}: {scores['mismatch']['normalized_score']:.2f}; under observation noise "
          f"{config.noise:g}: {scores['noise']['normalized_score']:.2f}")
    if report.e2e is not None:  # the learnt parameters beside the true ones
        print("  learnt " + ", ".join(f"{k} {v:.6g} (true {report.e2e.true.get(k, float('nan')):.6g})"
                                      for k, v in report.e2e.learned.items()))
    if args.json:
        from ..atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(rec, indent=1, allow_nan=False))
    if args.plots:
        from .plots import plot_report

        for path in plot_report(report, Path(args.plots)):
            print(f"  plot: {path}")
    if report.failed:
        print(f"myriad imitate: {system.name}: the training failed ({report.status}): {report.message}",
              file=sys.stderr)
        return 1
    return 0
