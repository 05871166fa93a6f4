"""``myriad e2e``: learn a model end to end through the planner (Algorithm 2), then judge its plan on the true system.

Exit 1 when the run stopped early or the plan on the learned model failed (reason on stderr); implicit solves that
did not converge are reported on stderr (and counted in the record) either way.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from .._command_args import add_training_outputs, first_error, usage
from ..learn.models import MODELS

__all__ = ["add_parser", "run"]


_METAVARS = {"iterations": "N", "reset_every": "R", "soft_state_bounds": "C", "learn_cost": "NAME", "hidden": "W",
             "reaim": "K", "seed": "S", "checkpoint_every": "N", "snapshot_every": "N", "optimizer": "LR"}


def add_parser(sub) -> None:
    from ..configs import add_arguments
    from ..learn.models import ACTIVATIONS
    from ..solvers.adjoint import ADJOINTS
    from .config import INITS, LOSSES, ON_FAILURE, E2EConfig

    s = sub.add_parser("e2e", help="end-to-end learning: imitate the true optimum through the planner (Algorithm 2)")
    s.add_argument("system", metavar="NAME|PATH")
    # The flags are E2EConfig's fields (--adjoint, --planner, --cost-guess take a word or JSON; --set reaches a nested
    # field), with --lr for the optimizer, and --gradient/--unroll and --implicit-solver as the old spellings of
    # an adjoint and of a solver object.
    add_arguments(s, E2EConfig, skip=("implicit_solver",), spelled={"optimizer": ("--lr",)}, metavars=_METAVARS,
                  choices={"model": list(MODELS), "loss": list(LOSSES), "on_failure": list(ON_FAILURE),
                           "activation": list(ACTIVATIONS), "init": list(INITS)})
    s.add_argument("--gradient", choices=list(ADJOINTS), default=None,
                   help="the adjoint by its name: reverse mode through K planner steps, or the implicit function "
                        "theorem at a converged plan (default: unrolled)")
    s.add_argument("--unroll", type=int, default=None, metavar="K", help="the adjoint's K: planner steps per "
                   "iteration (default 10 parametric, 5 Neural ODE)")
    s.add_argument("--implicit-solver", dest="implicit_solver_name", choices=["extragradient", "interior_point"],
                   default=None, help="implicit mode: the solve to tolerance (interior_point: Newton steps, much "
                   "faster where final values are required; docs/notes/e2e-node.md); --set implicit_solver=... sets "
                   "the object")
    s.add_argument("--intervals", type=int, default=100, metavar="N",
                   help="the single-shooting control grid: N intervals (default 100, the published setting)")
    s.add_argument("--expert", metavar="FILE.npz", default=None,
                   help="imitate a recorded trajectory of a system-identification dataset (made with x0_std 0 on "
                        "the --intervals grid) instead of the true optimum")
    s.add_argument("--expert-split", choices=["train", "validation", "test"], default="train")
    s.add_argument("--expert-index", type=int, default=0, metavar="I", help="which trajectory of the split (0)")
    add_training_outputs(s, "the training figure (plans over training) and the loss curve")


def read_config(args):
    """The :class:`~myriad.runtime.e2e.config.E2EConfig` of the arguments (``ValueError``: a usage error)."""
    from ..configs import from_args
    from ..solvers.adjoint import adjoint
    from ..solvers.interior_point import InteriorPoint
    from .config import E2EConfig

    given = {}
    if args.unroll is not None and args.unroll < 1:
        raise ValueError(f"--unroll must be an integer >= 1 (planner steps per iteration), got {args.unroll}")
    if args.gradient is not None or args.unroll is not None:
        given["adjoint"] = adjoint(args.gradient or "unrolled", args.unroll)
    if args.implicit_solver_name is not None:  # extragradient: the configuration's default one
        given["implicit_solver"] = InteriorPoint() if args.implicit_solver_name == "interior_point" else None
    return from_args(E2EConfig, args, **given)


def run(args) -> int:
    from ..configs import usage_message
    from .config import E2EConfig

    if error := first_error(args):
        return usage("e2e", error)
    if args.intervals < 1:
        return usage("e2e", "--intervals must be at least 1")
    if args.expert_index < 0:
        return usage("e2e", f"--expert-index must be an integer >= 0 (a trajectory of --expert-split), got "
                            f"{args.expert_index}")
    if args.expert is not None and not Path(args.expert).is_file():
        return usage("e2e", f"--expert {args.expert!r}: file not found; give a dataset .npz written by "
                            f"myriad.runtime.learn.dataset.save_dataset (its .json sidecar beside it)")
    try:
        config = read_config(args)
    except ValueError as exc:
        return usage("e2e", usage_message(exc, E2EConfig, {"optimizer": ("--lr",)}))
    from ..loader import load

    system = load(args.system)
    if config.model == "parametric" and not system.learnable:
        return usage("e2e", f"{system.name} declares no learnable parameters; use --model node, or mark parameters "
                      f"`learnable: true` (with a `guess`) in its spec")
    unknown = [n for n in config.learn_cost if n not in system.param_names]
    if unknown:
        return usage("e2e", f"--learn-cost {unknown}: not parameters of {system.name} "
                            f"({', '.join(system.param_names)})")
    from ..transcriptions import SingleShooting
    from .train import run_e2e

    transcription, expert = SingleShooting(intervals=args.intervals), None
    if args.expert is not None:
        from .expert import expert_from_dataset

        try:
            expert = expert_from_dataset(args.expert, system, transcription, split=args.expert_split,
                                         index=args.expert_index)
        except (OSError, ValueError) as exc:
            return usage("e2e", f"--expert {args.expert}: {exc}")
    report = run_e2e(system, config, transcription=transcription, checkpoint_dir=args.checkpoint,
                     resume=args.resume, expert=expert)
    rec = report.record()
    print(f"{report.system}: {config.model} model, {config.adjoint.name} gradients (K = {config.adjoint.unroll}), "
          f"{report.iterations} iterations in {report.train_seconds:.1f} s ({report.status})")
    for name, value in report.learned.items():
        true = report.true.get(name)
        err = "" if true is None else f"  true {true:.8g}  (relative error {abs(value - true) / abs(true):.1e})"
        print(f"  {name:12s} learned {value:.8g}{err}")
    aimed = report.evaluation.reaim
    if aimed is not None and aimed.misses:
        print(f"  re-aimed at the final values: {aimed.message}")
    print(f"  imitation loss {_loss(rec['imitation_loss'])} (converged plan: {_loss(rec['plan_imitation_loss'])}); "
          f"planned on the model, applied to the true system: cost {rec['achieved_cost']} (true optimum "
          f"{rec['optimal_cost']}), defect {rec['achieved_defect'] or 'none required'}")
    if args.json:
        from ..atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(rec, indent=1))
    if args.plots:
        _plots(report, Path(args.plots))
    if report.counts["skipped"] or report.counts["fallback_unrolled"] or report.counts["backtracked"]:
        print(f"myriad e2e: warning: {report.system}: {report.message}", file=sys.stderr)
    if not report.converged:
        print(f"myriad e2e: {report.system}: {report.message}", file=sys.stderr)
        return 1
    return 0


def _loss(value) -> str:
    # A run stopped before its first loss (non-finite at iteration 0) records none: say so rather than crash.
    return "none" if value is None else f"{value:.3e}"


def _plots(report, folder: Path) -> None:
    from ..learn.plots import plot_loss, plot_training

    folder.mkdir(parents=True, exist_ok=True)
    label = f"{report.system} ({report.config.model}, {report.config.adjoint.name})"
    expert = report.evaluation.optimum
    if report.history:  # the imitation loss and the planner's KKT residual (lighter); an exact 0 drawn at 1e-300
        path = plot_loss(report.history, folder / "loss.png", f"{label}: imitation loss", xlabel="iteration",
                         labels=("imitation loss", "planner KKT residual"), ylabel=None, floor=1e-300, second_alpha=0.6)
        print(f"  plot: {path}")
    if report.snapshots:
        path = plot_training(report.model.system, expert.times, report.snapshots, expert.controls, expert.states,
                             folder / "training.png", f"{label}: plans over training (light: early), expert (black)")
        print(f"  plot: {path}")
