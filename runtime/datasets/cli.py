"""``myriad dataset``: demonstrations of a policy in any system's environment, written as a Minari dataset (or one
``.npz``). Arguments are checked before any work (exit 2); the dataset is written atomically and never overwritten;
exit 1 when a plan of the optimal or noisy policy did not converge or an MPC re-plan failed (the dataset is written,
the episodes named on stderr)."""

from __future__ import annotations

__all__ = ["add_parser", "run"]

_METAVARS = {"episodes": "N", "seed": "S", "name": "NAME", "start_noise": "F", "param_noise": "F", "noise": "F",
             "replan_every": "K", "env": "JSON"}


def add_parser(sub) -> None:
    from ..configs import add_arguments
    from .run import DatasetConfig

    s = sub.add_parser("dataset", help="an offline dataset (Minari) of a policy's episodes in a system's env",
                       epilog="the dataset lands in OUT/myriad/SYSTEM/NAME-v0 (load it with MINARI_DATASETS_PATH=OUT "
                              "and minari.load_dataset('myriad/SYSTEM/NAME-v0')) or, with --format npz, in "
                              "OUT/SYSTEM-NAME-v0.npz; exit 1: a plan did not converge (the dataset is written, "
                              "the episodes named); exit 2: a usage error or the dataset exists, before any work")
    s.add_argument("system", metavar="NAME|PATH")
    s.add_argument("--out", metavar="DIR", help="the datasets' folder, made if missing (default: Minari's own, "
                                               "$MINARI_DATASETS_PATH, else ~/.minari/datasets)")
    add_arguments(s, DatasetConfig, metavars=_METAVARS)


def _minari_root() -> str:
    """Minari's datasets folder, where ``minari.load_dataset`` looks (its ``get_dataset_path``'s rule)."""
    import os

    return os.environ.get("MINARI_DATASETS_PATH") or os.path.join(os.path.expanduser("~"), ".minari", "datasets")


def run(args) -> int:
    from .._command_args import output_folder_error, usage
    from ..configs import from_args, usage_message
    from .run import DatasetConfig, run_dataset
    from .storage import dataset_id, dataset_path

    out = args.out if args.out is not None else _minari_root()
    if error := output_folder_error(out, "--out"):
        return usage("dataset", error)
    try:
        config = from_args(DatasetConfig, args)
    except ValueError as exc:
        return usage("dataset", usage_message(exc, DatasetConfig))
    from ..loader import load

    system = load(args.system)
    from ..rl.env import Env
    from ..system import UnsupportedFeature

    try:
        Env(system, config.options())  # an unbounded control without action_bound, a free final time: refused here
    except UnsupportedFeature as exc:
        return usage("dataset", str(exc))
    except ValueError as exc:
        return usage("dataset", f"{exc} (--env '{{\"action_bound\": B}}')")
    name = config.name or config.policy
    if (existing := dataset_path(out, system.name, name, config.format)).exists():
        return usage("dataset", f"--out {out}: {existing} exists (never overwritten); choose another --out or "
                                f"--name")
    path, episodes = run_dataset(args.system, config, out)
    returns = episodes.returns
    print(f"{system.name}: {len(episodes)} episodes of {config.policy}, return mean {returns.mean():.6g} "
          f"(min {returns.min():.6g}, max {returns.max():.6g})")
    if config.format == "minari":
        print(f"  wrote {path}; load it with MINARI_DATASETS_PATH={out} and "
              f"minari.load_dataset({dataset_id(system.name, name)!r})")
    else:
        print(f"  wrote {path}")
    return _solver_warnings(episodes.info)


def _solver_warnings(info) -> int:
    """Exit 1, saying which, when a plan did not converge or an MPC re-plan failed: such episodes are written but
    are not the optimum's."""
    import sys

    bad = [e for e, s in enumerate(info.get("plan_status", ())) if s != "converged"]
    failed = [e for e, n in enumerate(info.get("replan_failures", ())) if n]
    if bad:
        print(f"myriad dataset: warning: the plans of episodes {bad} did not converge ({info['plan_status'][bad[0]]})",
              file=sys.stderr)
    if failed:
        print(f"myriad dataset: warning: MPC re-plans failed in episodes {failed}", file=sys.stderr)
    return 1 if bad or failed else 0
