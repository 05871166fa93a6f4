"""The config is the interface: every field of every command's config is settable from the shell (by its flag and
by ``--set``), documented, and a bad value is a usage error (exit 2) that names the field."""

from __future__ import annotations

import dataclasses
import enum
from typing import ClassVar, Literal

import pytest

import myriad.runtime
from myriad.runtime.cli import _parser, _solve_config, main
from myriad.runtime.configs import FieldError, build, field_docs, from_args, to_json, usage_message
from myriad.runtime.e2e.cli import read_config as e2e_config
from myriad.runtime.e2e.config import E2EConfig
from myriad.runtime.solve_config import METHODS, SolveConfig
from myriad.runtime.sweep import parse_method
from myriad.runtime.sysid.cli import read_config as sysid_config
from myriad.runtime.sysid.run import SysidConfig


class _Reached(BaseException):
    """Raised by the replaced loader: a usage error must come before any system is loaded."""


@pytest.fixture(autouse=True)
def no_work(monkeypatch):
    def reached(*args, **kwargs):
        raise _Reached

    monkeypatch.setattr(myriad.runtime, "load", reached)


# Per command: its config, the words before the options, the command's own reading of its arguments, and for EVERY
# field a non-default VALUE for `--set FIELD=VALUE`, or (VALUE, words its flag takes, words the field needs beside
# it). A field added without a sample fails test_every_field_has_a_sample_and_a_help_text, so none can be left out
# of the shell.
COMMANDS = {
    "solve": (SolveConfig, ["solve", "van_der_pol"], _solve_config, {
        "transcription": "multiple_shooting", "solver": "ipopt", "integrator": "rk4", "intervals": "20",
        "solver_options": '{"max_iter": 5}', "tolerance": "1e-5", "max_refinements": ("3", None, ["--tolerance", "1"]),
        "max_intervals": ("500", None, ["--tolerance", "1"]), "x0_std": "0.1", "seed": "3", "resimulate": "false",
        "nominal": "true"}),
    "sysid": (SysidConfig, ["sysid", "van_der_pol"], sysid_config, {
        "model": "node", "method": "adam", "trajectories": "5", "rounds": "2", "noise": "0.01", "seed": "3",
        "hidden": ("[8, 8]", ["--hidden", "8", "8"], []), "activation": "relu", "fit": '{"epochs": 5}',
        "refit": '{"epochs": 7}', "sampling": '{"intervals": 50}', "reaim": "2", "epochs": "50",
        "polish": ("null", ["--polish", "0"], ["--model", "node"]), "max_param_error": "0.1", "max_gap": "0.2",
        "declared_noise": "false"}),
    "e2e": (E2EConfig, ["e2e", "cancer_treatment"], e2e_config, {
        "model": "node", "adjoint": ("implicit", ["--gradient", "implicit"], []), "iterations": "5",
        "optimizer": "0.05", "reset_every": "3", "loss": "states", "on_failure": "skip",
        "learn_dynamics": ("false", None, ["--learn-cost", "zeta"]),
        "learn_cost": ('["zeta"]', ["--learn-cost", "zeta"], []),
        "cost_guess": ('[["zeta", 2.0]]', None, ["--learn-cost", "zeta"]),
        "hidden": ("[8, 8]", ["--hidden", "8", "8"], []), "activation": "relu", "planner": "extragradient",
        "implicit_solver": ("interior_point", ["--implicit-solver", "interior_point"], []),
        "checkpoint_every": "2", "snapshot_every": "2", "seed": "3", "init": "sysid", "reaim": "2",
        "soft_state_bounds": "10"}),
}


def _subparser(command):
    return _parser(command)._subparsers._group_actions[0].choices[command]


def _flags(command) -> dict[str, list[str]]:
    return {a.dest: a.option_strings for a in _subparser(command)._actions if a.option_strings}


def _parse(command, words):
    _, head, read, _ = COMMANDS[command]
    return read(_parser(command).parse_args([*head, *words]))


def _sample(command, name):
    """(VALUE, the words of its flag, the words it needs beside it)."""
    sample = COMMANDS[command][3][name]
    text, words, context = (sample, None, []) if isinstance(sample, str) else sample
    if words is None:
        flag = _flags(command)[name][0]
        if text in ("true", "false"):  # a boolean field: --x / --no-x
            words = [flag if text == "true" else "--no-" + flag[2:]]
        else:
            words = [flag, *(text.split() if not text.startswith(("{", "[")) else [text])]
    return text, words, context


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_field_has_a_sample_and_a_help_text(command):
    cls, _, _, samples = COMMANDS[command]
    names = [f.name for f in dataclasses.fields(cls)]
    assert sorted(samples) == sorted(names)
    docs = field_docs(cls)
    assert all(docs.get(n) for n in names), [n for n in names if not docs.get(n)]


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_field_is_settable_by_its_flag_and_by_set(command):
    cls = COMMANDS[command][0]
    for f in dataclasses.fields(cls):
        text, words, context = _sample(command, f.name)
        before = getattr(_parse(command, context), f.name)
        by_flag = getattr(_parse(command, [*context, *words]), f.name)
        by_set = getattr(_parse(command, [*context, "--set", f"{f.name}={text}"]), f.name)
        assert by_flag == by_set != before, f.name


@pytest.mark.parametrize("command", list(COMMANDS))
def test_no_flag_means_the_configs_own_defaults(command):
    assert _parse(command, []) == COMMANDS[command][0]()


def test_solve_flags_keep_their_spellings():
    flags = _flags("solve")
    assert flags["intervals"] == ["--intervals", "--controls"]
    for name in ("transcription", "solver", "integrator", "tolerance", "max_refinements", "max_intervals"):
        assert flags[name] == ["--" + name.replace("_", "-")]
    assert _parse("solve", ["--controls", "30", "--transcription", "fbsm"]) == SolveConfig("fbsm", intervals=30)


def test_every_field_of_the_sweep_config_has_its_argument():
    from myriad.runtime.sweep import SweepConfig

    dests = {a.dest for a in _parser()._subparsers._group_actions[0].choices["sweep"]._actions}
    assert {f.name for f in dataclasses.fields(SweepConfig)} <= dests


@pytest.mark.parametrize("argv, flag", [
    (["sysid", "van_der_pol", "--set", "hidden=[0]"], "--hidden"),
    (["sysid", "van_der_pol", "--set", "trajectories=0"], "trajectories"),
    (["sysid", "van_der_pol", "--set", "epochs=0"], "--epochs"),
    (["sysid", "van_der_pol", "--set", "fit.epochs=x"], "epochs"),
    (["e2e", "cancer_treatment", "--set", "iterations=0"], "--iterations"),
    (["e2e", "cancer_treatment", "--set", "optimizer=-1"], "--lr"),
    (["e2e", "cancer_treatment", "--set", "loss=everything"], "--loss"),
    (["e2e", "cancer_treatment", "--set", "adjoint=sideways"], "adjoint"),
])
def test_a_bad_set_value_of_a_learner_is_a_usage_error_naming_the_field(capsys, argv, flag):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"myriad {argv[0]}: error: ") and flag in err, err


@pytest.mark.parametrize("item, flag", [
    ("intervals=0", "--intervals"),
    ("x0_std=abc", "--x0-std"),
    ("solver_options=[1]", "--solver-options"),
    ("tolerance=-1", "--tolerance"),
    ("resimulate=3", "--resimulate"),
])
def test_a_bad_set_value_is_a_usage_error_naming_the_field(capsys, item, flag):
    assert main(["solve", "van_der_pol", "--set", item]) == 2
    err = capsys.readouterr().err
    assert err.startswith("myriad: error: ") and flag in err, err


@pytest.mark.parametrize("item, words", [("nope=1", "unknown field 'nope'"), ("intervals", "--set expects KEY=VALUE")])
def test_a_malformed_set_is_a_usage_error(capsys, item, words):
    assert main(["solve", "van_der_pol", "--set", item]) == 2
    assert words in capsys.readouterr().err


def test_the_sweep_and_the_cli_build_the_same_config():
    method = parse_method('solve:transcription=trapezoidal,intervals=20,solver_options={"max_iter":50}')
    from myriad.runtime.sweep.kinds import KINDS

    config = KINDS["solve"]().config(method.settings, seed=4)
    assert config == _parse("solve", ["--transcription", "trapezoidal", "--intervals", "20", "--set",
                                      'solver_options={"max_iter":50}', "--seed", "4"])
    assert "seed" not in method.settings and config.build()[0] == METHODS["trapezoidal"].on_grid(20)


# The mechanism on a small config of its own: a tuple, an enum, a literal, nested configs and its docstring.
class Colour(enum.Enum):
    RED = "red"
    BLUE = "blue"


@dataclasses.dataclass(frozen=True)
class Inner:
    """Attributes:
        rate: a rate > 0.
    """

    rate: float = 1.0

    def __post_init__(self):
        if not self.rate > 0:
            raise FieldError(f"rate must be > 0, got {self.rate}", "rate")


@dataclasses.dataclass(frozen=True)
class Fast:
    name: ClassVar[str] = "fast"
    steps: int | None = None


@dataclasses.dataclass(frozen=True)
class Slow:
    name: ClassVar[str] = "slow"
    patience: int = 3


@dataclasses.dataclass(frozen=True)
class Outer:
    """A test config.

    Attributes:
        widths: layer widths,
            one or more.
        colour, shade: what it looks like.
        inner: a nested config.
        opt: maybe an inner.
        way: fast or slow, by its word.
    Raises:
        ValueError: never here.
    """

    widths: tuple[int, ...] = (2, 3)
    colour: Colour = Colour.RED
    shade: Literal["dark", "light"] = "dark"
    inner: Inner = Inner()
    opt: Inner | None = None
    way: Fast | Slow = Fast()


def test_the_mechanism_on_tuples_enums_literals_and_nested_configs():
    import argparse

    assert field_docs(Outer) == {"widths": "layer widths, one or more.", "colour": "what it looks like.",
                                 "shade": "what it looks like.", "inner": "a nested config.",
                                 "opt": "maybe an inner.", "way": "fast or slow, by its word."}
    p = argparse.ArgumentParser()
    from myriad.runtime.configs import add_arguments

    add_arguments(p, Outer)
    args = p.parse_args(["--widths", "4", "5", "--colour", "blue", "--shade", "light", "--set", "inner.rate=2",
                         "--set", 'opt={"rate": 3}'])
    assert from_args(Outer, args) == Outer((4, 5), Colour.BLUE, "light", Inner(2.0), Inner(3))
    assert build(Outer, {"opt.rate": 5, "way": "slow"}) == Outer(opt=Inner(5), way=Slow())
    assert build(Outer, {"way": {"type": "slow", "patience": 7}}).way == Slow(7)
    assert build(Outer, {"way.steps": 4}).way == Fast(4)
    assert to_json(Outer()) == {"widths": [2, 3], "colour": "red", "shade": "dark", "inner": {"rate": 1.0},
                                "opt": None, "way": {"type": "fast", "steps": None}}
    assert build(Outer, to_json(Outer(way=Slow(5)))) == Outer(way=Slow(5))  # the JSON reads back
    from myriad.runtime.integrators import RK4
    from myriad.runtime.learn.dataset import Sampling

    # A word names a concrete subclass of an abstract annotation (Sampling.integrator: AbstractIntegrator).
    assert build(Sampling, {"integrator": "rk4"}).integrator == RK4()
    assert build(Sampling, to_json(Sampling(integrator=RK4()))) == Sampling(integrator=RK4())
    with pytest.raises(ValueError) as info:
        build(Outer, {"inner.rate": -1})
    assert usage_message(info.value, Outer) == "--set inner.rate must be > 0, got -1"
    assert usage_message(ValueError("Outer(shade='x'): expected dark or light"), Outer) == \
        "--shade 'x': expected dark or light"
    assert usage_message(ValueError("Outer: widths must be >= 1"), Outer) == "--widths must be >= 1"
    with pytest.raises(ValueError, match="unknown field 'colr'"):
        build(Outer, {"colr": "red"})
