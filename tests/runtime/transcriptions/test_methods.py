"""The method interface and its glue: one control-grid word for every method, labels from the classes, the CLI
built from the registries, and an indirect method that refuses an NLP solver instead of ignoring it."""

from pathlib import Path

import jax
import numpy as np
import pytest

from myriad.runtime import load, solve
from myriad.runtime.cli import _parser, _solve_config, main
from myriad.runtime.integrators import INTEGRATORS
from myriad.runtime.solve_config import METHODS
from myriad.runtime.solvers import SOLVERS, Ipopt
from myriad.runtime.status import Status
from myriad.runtime.transcriptions import INDIRECT, TRANSCRIPTIONS, ForwardBackwardSweep, MultipleShooting

jax.config.update("jax_enable_x64", True)

SPECS = Path(__file__).parent.parent / "specs"


@pytest.fixture(scope="module")
def lq():
    return load(SPECS / "scalar_lq.yaml")


@pytest.mark.slow
@pytest.mark.parametrize("name", list(METHODS))
def test_on_grid_is_the_same_control_grid_for_every_method(lq, name):
    sol = solve(lq, METHODS[name].on_grid(20), resimulate=False)
    assert sol.converged, sol.message
    assert sol.status is Status.CONVERGED and sol.record()["status"] == "converged"
    # Hermite-Simpson also has a control at each interval's midpoint; its interval ends are the common grid.
    nodes = sol.times[::2] if name == "hermite_simpson" else sol.times
    np.testing.assert_allclose(nodes, np.linspace(0.0, lq.horizon, 21), rtol=0, atol=1e-12)
    assert sol.transcription == name and sol.integrator == METHODS[name].on_grid(20).quadrature


def test_multiple_shooting_on_grid_groups_the_control_intervals():
    assert MultipleShooting.on_grid(100) == MultipleShooting(intervals=20, steps_per_interval=5)
    assert MultipleShooting.on_grid(12) == MultipleShooting(intervals=3, steps_per_interval=4)
    assert MultipleShooting.on_grid(7) == MultipleShooting(intervals=7, steps_per_interval=1)
    assert MultipleShooting.on_grid(30, steps_per_interval=10) == MultipleShooting(intervals=3, steps_per_interval=10)
    with pytest.raises(ValueError, match="multiple of 4"):
        MultipleShooting.on_grid(10, steps_per_interval=4)
    with pytest.raises(ValueError, match="at least 1"):
        MultipleShooting.on_grid(0)


def test_cli_controls_mean_the_control_grid_on_every_method():
    args = _parser().parse_args(["solve", "van_der_pol", "--transcription", "multiple_shooting", "--controls", "100"])
    assert _solve_config(args).build()[0] == MultipleShooting(intervals=20, steps_per_interval=5)
    for name, cls in METHODS.items():
        args = _parser().parse_args(["solve", "van_der_pol", "--transcription", name, "--intervals", "40"])
        assert _solve_config(args).build()[0] == cls.on_grid(40)
    help_text = _parser()._subparsers._group_actions[0].choices["solve"].format_help()
    assert "N uniform intervals (N + 1 control nodes), the same grid for every method" in " ".join(help_text.split())


def test_cli_choices_come_from_the_registries():
    sub = _parser()._subparsers._group_actions[0].choices["solve"]
    choices = {a.dest: a.choices for a in sub._actions if a.choices}
    assert list(choices["transcription"]) == list(METHODS)
    assert list(choices["solver"]) == list(SOLVERS)
    assert set(choices["integrator"]) == {n for n, c in INTEGRATORS.items() if c.fixed_step}


def test_labels_are_the_registry_names():
    for table in (TRANSCRIPTIONS, INDIRECT, SOLVERS, INTEGRATORS):
        for name, cls in table.items():
            assert cls.label == name


def test_the_sweep_refuses_a_solver_it_would_not_use(lq):
    with pytest.raises(ValueError, match="takes no NLP solver"):
        solve(lq, ForwardBackwardSweep(intervals=50), Ipopt())
    assert main(["solve", str(SPECS / "scalar_lq.yaml"), "--transcription", "fbsm", "--solver", "ipopt"]) == 2


def test_cli_usage_errors_come_before_any_work(capsys):
    assert main(["solve", "van_der_pol", "--transcription", "trapezoidal", "--integrator", "rk4"]) == 2
    assert main(["solve", "van_der_pol", "--intervals", "0"]) == 2
    assert main(["solve", "van_der_pol", "--transcription", "multiple_shooting", "--intervals", "0"]) == 2
    err = capsys.readouterr().err
    assert "--integrator applies to the shooting transcriptions" in err and "at least 1" in err
