"""``myriad e2e``: learn a model end to end through the planner (Algorithm 2), then judge its plan on the true system.

Arguments are checked before any work; the JSON record and the plots are written atomically; exit 1 when the run
stopped early or the plan on the learned model failed (reason on stderr); implicit solves that did not converge are
reported on stderr (and counted in the record) either way.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from .._command_args import add_training_outputs, first_error, usage
from ..learn.models import MODELS

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    s = sub.add_parser("e2e", help="end-to-end learning: imitate the true optimum through the planner (Algorithm 2)")
    s.add_argument("system", metavar="NAME|PATH")
    s.add_argument("--model", choices=list(MODELS), default="parametric",
                   help="the spec's learnable parameters, or a Neural ODE (default: parametric)")
    s.add_argument("--gradient", choices=["unrolled", "implicit"], default="unrolled",
                   help="reverse mode through K planner steps, or the implicit function theorem at a converged plan")
    s.add_argument("--unroll", type=int, default=None, metavar="K", help="planner steps per iteration "
                   "(default 10 parametric, 5 Neural ODE)")
    s.add_argument("--iterations", type=int, default=None, metavar="N", help="outer iterations (default 600)")
    s.add_argument("--intervals", type=int, default=100, metavar="N",
                   help="the single-shooting control grid: N intervals (default 100, the published setting)")
    s.add_argument("--reset-every", type=int, default=1000, metavar="R",
                   help="restart the planner from its initial guess every R iterations (default 1000, published)")
    s.add_argument("--lr", type=float, default=None, metavar="LR", help="Adam's learning rate (default 1e-2)")
    s.add_argument("--on-failure", choices=["skip", "unrolled", "backtrack"], default="backtrack",
                   help="implicit mode: when a solve does not converge, skip the step, unroll instead, or go back to "
                        "the last parameters whose plan converged and take the step again at half the length")
    s.add_argument("--implicit-solver", choices=["extragradient", "interior_point"], default="extragradient",
                   help="implicit mode: the solve to tolerance (interior_point: Newton steps, much faster where final "
                        "values are required; docs/notes/e2e-node.md)")
    s.add_argument("--soft-state-bounds", type=float, default=None, metavar="C",
                   help="plan the learned model with elastic final-state bounds, penalty C max(1, |J*|) per unit of "
                        "scaled violation (J*: the expert's cost; 10 in Table D). Default: hard bounds")
    s.add_argument("--learn-cost", nargs="+", default=(), metavar="NAME", help="also learn these cost weights")
    s.add_argument("--init", choices=["guess", "sysid"], default="guess",
                   help="where theta starts: the spec's guesses / random weights, or a system-identification fit "
                        "(rounds 1; measured for Neural ODEs in docs/notes/e2e-node.md)")
    s.add_argument("--hidden", type=int, nargs="+", default=None, metavar="W",
                   help="node: hidden widths (default 50 50, the published Cancer Treatment network)")
    s.add_argument("--expert", metavar="FILE.npz", default=None,
                   help="imitate a recorded trajectory of a system-identification dataset (made with x0_std 0 on "
                        "the --intervals grid) instead of the true optimum")
    s.add_argument("--expert-split", choices=["train", "validation", "test"], default="train")
    s.add_argument("--expert-index", type=int, default=0, metavar="I", help="which trajectory of the split (0)")
    s.add_argument("--reaim", type=int, default=None, metavar="K",
                   help="re-aim the final plan at the required final values at most K times from observed true runs "
                        "(default: 6 for a Neural ODE, 0 for a parametric model)")
    s.add_argument("--seed", type=int, default=0, metavar="S")
    add_training_outputs(s, "the training figure (plans over training) and the loss curve")


def _usage(message: str) -> int:
    return usage("e2e", message)


def _implicit_solver(name: str):
    if name == "interior_point":
        from ..solvers.interior_point import InteriorPoint

        return InteriorPoint()
    return None  # the configuration's default extragradient


def run(args) -> int:
    from ..solvers.adjoint import adjoint
    from .config import E2EConfig

    if error := first_error(args):
        return _usage(error)
    if args.intervals < 1:
        return _usage("--intervals must be at least 1")
    options = {k: v for k, v in (("iterations", args.iterations),
                                 ("optimizer", args.lr), ("hidden", args.hidden), ("reaim", args.reaim))
               if v is not None}
    try:
        config = E2EConfig(model=args.model, adjoint=adjoint(args.gradient, args.unroll), on_failure=args.on_failure,
                           learn_cost=tuple(args.learn_cost), seed=args.seed, reset_every=args.reset_every,
                           init=args.init, implicit_solver=_implicit_solver(args.implicit_solver),
                           soft_state_bounds=args.soft_state_bounds, **options)
    except ValueError as exc:
        return _usage(str(exc))
    from ..loader import load

    system = load(args.system)
    if args.model == "parametric" and not system.learnable:
        return _usage(f"{system.name} declares no learnable parameters; use --model node, or mark parameters "
                      f"`learnable: true` (with a `guess`) in its spec")
    unknown = [n for n in config.learn_cost if n not in system.param_names]
    if unknown:
        return _usage(f"--learn-cost {unknown}: not parameters of {system.name} ({', '.join(system.param_names)})")
    from ..transcriptions import SingleShooting
    from .train import run_e2e

    transcription, expert = SingleShooting(intervals=args.intervals), None
    if args.expert is not None:
        from .expert import expert_from_dataset

        try:
            expert = expert_from_dataset(args.expert, system, transcription, split=args.expert_split,
                                         index=args.expert_index)
        except (OSError, ValueError) as exc:
            return _usage(str(exc))
    report = run_e2e(system, config, transcription=transcription, checkpoint_dir=args.checkpoint,
                     resume=args.resume, expert=expert)
    rec = report.record()
    print(f"{report.system}: {config.model} model, {config.gradient} gradients (K = {config.unroll}), "
          f"{report.iterations} iterations in {report.train_seconds:.1f} s ({report.status})")
    for name, value in report.learned.items():
        true = report.true.get(name)
        err = "" if true is None else f"  true {true:.8g}  (relative error {abs(value - true) / abs(true):.1e})"
        print(f"  {name:12s} learned {value:.8g}{err}")
    aimed = report.evaluation.reaim
    if aimed is not None and aimed.misses:
        print(f"  re-aimed at the final values: {aimed.message}")
    print(f"  imitation loss {rec['imitation_loss']:.3e} (converged plan: {rec['plan_imitation_loss']:.3e}); "
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


def _plots(report, folder: Path) -> None:
    from .plots import plot_loss, plot_training

    folder.mkdir(parents=True, exist_ok=True)
    label = f"{report.system} ({report.config.model}, {report.config.gradient})"
    expert = report.evaluation.expert
    if report.history:
        print(f"  plot: {plot_loss(report.history, folder / 'loss.png', f'{label}: imitation loss')}")
    if report.snapshots:
        path = plot_training(report.model.system, expert.times, report.snapshots, expert.controls, expert.states,
                             folder / "training.png", f"{label}: plans over training (light: early), expert (black)")
        print(f"  plot: {path}")
