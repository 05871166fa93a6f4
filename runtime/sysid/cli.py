"""``myriad sysid``: learn a system's dynamics from sampled trajectories, plan on the model, judge the plan.

Arguments are checked before any work (exit 2); the JSON record and the plots are written atomically; exit 1 when
the experiment failed its verdict (:func:`.run.failed`; the reason on stderr and in the record's ``failure``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

from .._command_args import add_training_outputs, first_error, usage
from ..learn.models import MODELS

__all__ = ["add_parser", "run"]


_METAVARS = {"trajectories": "N", "rounds": "K", "noise": "F", "seed": "S", "epochs": "E", "hidden": "W", "reaim": "K",
             "max_param_error": "F", "max_gap": "F"}


def add_parser(sub) -> None:
    from ..configs import add_arguments
    from ..learn.models import ACTIVATIONS
    from .run import SysidConfig

    s = sub.add_parser("sysid", help="system identification: fit a model to trajectories, plan on it",
                       epilog="exit 0: passed; 1: the fit or the plan failed, a parameter is off by more than "
                              "--max-param-error and 3 standard errors, or the plan's gap exceeds --max-gap (the "
                              "reason on stderr and in the record's failure); 2: a usage error, before any work")
    s.add_argument("system", metavar="NAME|PATH")
    # The flags are SysidConfig's fields (--fit, --refit, --sampling take JSON; --set reaches a nested field).
    add_arguments(s, SysidConfig, skip=("polish",), metavars=_METAVARS,
                  choices={"model": list(MODELS), "method": ["least_squares", "adam"], "activation": list(ACTIVATIONS)})
    s.add_argument("--polish", type=int, dest="polish_iterations", default=None, metavar="N",
                   help="Neural ODE: L-BFGS iterations after each round's Adam fit, anchored on the earlier plans' "
                        "true trajectories (default 300; 0: none); --set polish=... sets the whole PolishConfig")
    add_training_outputs(s, "loss curve, learned vs true trajectories, vector field (PNG)")


def read_config(args):
    """The :class:`~myriad.runtime.sysid.run.SysidConfig` of the arguments (``ValueError``: a usage error)."""
    from ..configs import from_args
    from .polish import PolishConfig
    from .run import SysidConfig

    config = from_args(SysidConfig, args)
    n = args.polish_iterations
    if n is None:
        return config
    if n < 0 or not MODELS[config.model].default_polish:
        raise ValueError("--polish N (N >= 0) goes with --model node")
    return dataclasses.replace(config, polish=PolishConfig(iterations=n) if n else None)


def run(args) -> int:
    from ..configs import usage_message
    from ..learn.dataset import sampling_scales
    from .run import SysidConfig, data_noise, failed, run_sysid

    if error := first_error(args):
        return usage("sysid", error)
    try:
        config = read_config(args)
    except ValueError as exc:
        return usage("sysid", usage_message(exc, SysidConfig))
    from ..loader import load

    system = load(args.system)
    if config.model == "parametric" and not system.learnable:
        return usage("sysid", f"{system.name} declares no learnable parameters; use --model node, or mark "
                              f"parameters `learnable: true` (with a `guess`) in its spec")
    try:  # the spec's declared noise and the kit's together, or process noise on an integrator without a scheme
        data_noise(system, config)
    except ValueError as exc:
        return usage("sysid", str(exc))
    try:  # a bound the sampling needs and the spec lacks: a usage error, before any work
        sampling_scales(system, dataclasses.replace(config.sampling, noise=config.noise))
    except ValueError as exc:
        return usage("sysid", f"{exc} (a sampling field on the command line: --set sampling.FIELD=VALUE)")
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
