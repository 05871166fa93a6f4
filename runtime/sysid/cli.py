"""``myriad sysid``: learn a system's dynamics from sampled trajectories, plan on the model, judge the plan.

Arguments are checked before any work; the JSON record and the plots are written atomically; exit 1 when the fit or
the planning failed (with the reason on stderr).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from .._command_args import add_training_outputs, first_error, usage
from ..learn.models import MODELS

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    s = sub.add_parser("sysid", help="system identification: fit a model to trajectories, plan on it")
    s.add_argument("system", metavar="NAME|PATH")
    s.add_argument("--model", choices=list(MODELS), default="parametric",
                   help="the spec's learnable parameters, or a Neural ODE (default: parametric)")
    s.add_argument("--method", choices=["least_squares", "adam"], default=None,
                   help="least_squares (parametric default) or adam on the trajectory loss (Neural ODE default)")
    s.add_argument("--trajectories", type=int, default=10, metavar="N", help="training trajectories per dataset")
    s.add_argument("--rounds", type=int, default=None, metavar="K",
                   help="datasets in sequence: train, plan, sample around the plan, retrain (default: 6 for a "
                        "Neural ODE, 1 for a parametric model)")
    s.add_argument("--noise", type=float, default=0.0, metavar="F", help="observation noise, fraction of the range")
    s.add_argument("--seed", type=int, default=0, metavar="S")
    s.add_argument("--epochs", type=int, default=None, metavar="E", help="adam: the most epochs (default 1000)")
    s.add_argument("--hidden", type=int, nargs="+", default=[100, 100], metavar="W", help="Neural ODE widths")
    s.add_argument("--activation", choices=["tanh", "sigmoid", "softplus", "relu"], default="tanh",
                   help="Neural ODE activation (the published one is sigmoid)")
    s.add_argument("--polish", type=int, default=None, metavar="N",
                   help="Neural ODE: L-BFGS iterations after each round's Adam fit, anchored on the earlier plans' "
                        "true trajectories (default 300; 0: none)")
    s.add_argument("--reaim", type=int, default=None, metavar="K",
                   help="re-aim the final plan at the required final values at most K times from observed true runs "
                        "(default: 6 for a Neural ODE, 0 for a parametric model)")
    add_training_outputs(s, "loss curve, learned vs true trajectories, vector field (PNG)")


def _usage(message: str) -> int:
    return usage("sysid", message)


def run(args) -> int:

    from .fit import FitConfig
    from .polish import PolishConfig
    from .run import SysidConfig, failed, node_fit_config, run_sysid

    if error := first_error(args):
        return _usage(error)
    if args.epochs is not None and args.epochs < 1:
        return _usage("--epochs must be at least 1")
    model = MODELS[args.model]
    if args.polish is not None and (args.polish < 0 or not model.default_polish):
        return _usage("--polish N (N >= 0) goes with --model node")
    try:
        fit = None
        if args.epochs is not None:  # the model's own recipe (SysidConfig's default), for this many epochs
            fit = node_fit_config(args.epochs) if model.default_method == "adam" else FitConfig(epochs=args.epochs)
        polish = "default" if args.polish is None else (PolishConfig(iterations=args.polish) if args.polish else None)
        config = SysidConfig(model=args.model, method=args.method, trajectories=args.trajectories,
                             rounds=args.rounds, noise=args.noise, seed=args.seed, hidden=tuple(args.hidden),
                             activation=args.activation, fit=fit, polish=polish, reaim=args.reaim)
    except ValueError as exc:
        return _usage(str(exc))
    from ..loader import load

    system = load(args.system)
    if args.model == "parametric" and not system.learnable:
        return _usage(f"{system.name} declares no learnable parameters; use --model node, or mark parameters "
                      f"`learnable: true` (with a `guess`) in its spec")
    report = run_sysid(system, config, checkpoint_dir=args.checkpoint, resume=args.resume)
    rec = report.record()
    print(f"{report.system}: {config.model} model by {config.method}, {report.train_seconds:.1f} s of fitting "
          f"({report.fit_status})")
    for name, value in report.learned.items():
        se = report.standard_errors.get(name, math.nan)
        print(f"  {name:10s} learned {value:.8g}  true {report.true[name]:.8g}  "
              f"(relative error {abs(value - report.true[name]) / max(abs(report.true[name]), 1e-300):.1e}, "
              f"standard error {se:.2g})")
    if report.unidentifiable:
        print(f"  not identifiable from these data: {', '.join(report.unidentifiable)}")
    if report.reaim is not None and report.reaim.misses:
        print(f"  re-aimed at the final values: {report.reaim.message}")
    print(f"  planned on the model, applied to the true system: cost {rec['achieved_cost']} "
          f"(true optimum {rec['optimal_cost']}), defect {rec['achieved_defect'] or 'none required'}")
    if args.json:
        from ..atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(rec, indent=1))
    if args.plots:
        _plots(report, Path(args.plots))
    reason = failed(report)
    if reason:
        print(f"myriad sysid: {report.system}: {reason}", file=sys.stderr)
        return 1
    return 0


def _plots(report, folder: Path) -> None:
    import numpy as np

    from ..integrators import Heun, rollout
    from ..learn.plots import plot_loss
    from .plots import plot_trajectories, plot_vector_field

    folder.mkdir(parents=True, exist_ok=True)
    true, label = report.model.system, f"{report.system} ({report.config.model})"
    if report.history:
        print(f"  plot: {plot_loss(report.history, folder / 'loss.png', f'{label}: training loss')}")
    held_out = report.dataset.test if report.dataset.n_test else report.dataset.validation
    learned = report.model.as_system(report.theta)
    params = learned.default_params()
    h = report.dataset.horizon / report.dataset.intervals
    integrator = report.dataset.sampling.integrator
    integrator = integrator if integrator.fixed_step else Heun()  # adaptive data: compare on the Heun grid

    def predict(u, x):
        return np.asarray(rollout(integrator, lambda x, u, t: learned.dynamics(x, u, t, params), x[0], 0.0, h, u))

    predicted = np.stack([predict(u, x) for u, x in zip(held_out.controls, held_out.states)])
    path = plot_trajectories(true, report.dataset.times, held_out.states, predicted, folder / "trajectories.png",
                             f"{label}: held-out trajectories, true (solid) and learned (dashed)")
    print(f"  plot: {path}")
    if true.n_states == 2:
        opt = report.evaluation.optimum
        path = plot_vector_field(true, learned, opt.times, opt.states, opt.controls, folder / "vector_field.png",
                                 f"{label}: vector field under the optimal controls")
        print(f"  plot: {path}")
