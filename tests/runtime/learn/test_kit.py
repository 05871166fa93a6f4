"""The learning kit's shared pieces: the loop's stop and checkpoint rules, the meters, the model registry and the run
identity (the learners' own tests cover them in use: tests/runtime/sysid/, tests/runtime/e2e/)."""

from __future__ import annotations

import dataclasses
import enum
import json

import optax
import pytest

from myriad.runtime.e2e.config import E2EConfig
from myriad.runtime.learn.identity import describe, digest, optimizer_identity
from myriad.runtime.learn.loop import Step, Stop, check_run, train
from myriad.runtime.learn.models import MODELS, AbstractModel, NeuralODE, Parametric, make_model, model_class
from myriad.runtime.learn.progress import LineProgressMeter, NoProgressMeter, TqdmProgressMeter, progress_meter
from myriad.runtime.loader import load


class Scripted:
    """A learner whose steps return what a script says: records the steps run and the checkpoints written."""

    desc, unit = "test", "it"

    def __init__(self, script: dict):
        self.script, self.ran, self.saved = script, [], []

    def step(self, index: int) -> Step:
        self.ran.append(index)
        stop = self.script.get(index)
        return Step(stop, "" if stop is None else f"{stop} at {index}")

    def save(self, done: int) -> None:
        self.saved.append(done)


def test_stop_is_one_enum_printed_as_its_word():
    assert issubclass(Stop, enum.Enum) and not issubclass(Stop, str)
    assert str(Stop.MAX_EPOCHS) == "max_epochs" and f"{Stop.COMPLETED}" == "completed"
    assert {s for s in Stop if not s.success} == {Stop.NON_FINITE, Stop.STALLED}


def test_the_loop_runs_the_budget_and_checkpoints_on_schedule_and_at_the_end():
    run = Scripted({})
    assert train(run, start=2, end=9, every=3, progress=False, exhausted=Stop.MAX_EPOCHS) == (Stop.MAX_EPOCHS, "")
    assert run.ran == list(range(2, 9)) and run.saved == [3, 6, 9]
    run = Scripted({})
    assert train(run, start=0, end=4, every=None, progress=False, exhausted=Stop.COMPLETED)[0] is Stop.COMPLETED
    assert run.saved == []
    run = Scripted({})  # nothing left to run (a resume at the end): no step, no checkpoint
    assert train(run, start=5, end=5, every=1, progress=False, exhausted=Stop.COMPLETED)[0] is Stop.COMPLETED
    assert run.ran == run.saved == []


@pytest.mark.parametrize("stop, saved", [(Stop.CONVERGED, [3, 4]), (Stop.EARLY_STOPPING, [3, 4]),
                                         (Stop.STALLED, [3]), (Stop.NON_FINITE, [3])])
def test_a_success_is_checkpointed_where_it_stops_a_failure_never(stop, saved):
    run = Scripted({3: stop})
    assert train(run, start=0, end=10, every=3, progress=False, exhausted=Stop.MAX_EPOCHS) == (stop, f"{stop} at 3")
    assert run.ran == [0, 1, 2, 3] and run.saved == saved


def test_a_stall_at_the_last_step_is_not_checkpointed_unless_due():
    run = Scripted({4: Stop.STALLED})
    assert train(run, start=0, end=5, every=3, progress=False, exhausted=Stop.COMPLETED)[0] is Stop.STALLED
    assert run.saved == [3]


def test_meters_and_argument_checks(capsys):
    assert type(progress_meter(False, 3)) is NoProgressMeter
    assert type(progress_meter(None, 3)) is LineProgressMeter  # stderr is not a terminal under pytest
    with progress_meter(True, 3, desc="bar", unit="epoch") as meter:
        assert isinstance(meter, TqdmProgressMeter)
        meter.update("loss 1")
        meter.update()
    assert "bar" in capsys.readouterr().err
    capsys.readouterr()
    with pytest.raises(ValueError, match="resume=True needs a checkpoint_dir"):
        check_run("x", resume=True, checkpoint_dir=None, progress=None)
    with pytest.raises(ValueError, match="progress must be"):
        check_run("x", resume=False, checkpoint_dir=None, progress="yes")


def test_one_registry_of_model_names_with_the_defaults_on_the_classes():
    assert MODELS == {"parametric": Parametric, "node": NeuralODE}
    for name, cls in MODELS.items():
        assert issubclass(cls, AbstractModel) and cls.label == name
        assert cls.default_method in ("least_squares", "adam") and cls.default_rounds >= 1
    assert (Parametric.default_unroll, NeuralODE.default_unroll) == (10, 5)
    assert (Parametric.default_reaim, NeuralODE.default_reaim) == (0, 6)
    assert (Parametric.default_iterations, NeuralODE.default_iterations) == (1200, 600)
    # None takes the model's default; iterations is not part of a run's identity (a resume may change it)
    assert E2EConfig().iterations == 1200 and E2EConfig(model="node").iterations == 600
    assert E2EConfig(iterations=5).iterations == 5
    assert E2EConfig().identity("x") == E2EConfig(iterations=600).identity("x")
    with pytest.raises(ValueError, match="unknown model 'neural_ode'; expected one of \\('parametric', 'node'\\)"):
        model_class("neural_ode", "E2EConfig")
    system = load("cancer_treatment")
    assert make_model("parametric", system, hidden=(4,), activation="relu") == Parametric(system)
    assert make_model("node", system, hidden=(4,), activation="relu") == NeuralODE(system, (4,), "relu")


@dataclasses.dataclass(frozen=True)
class _Settings:
    rate: float = 0.5
    widths: tuple = (2, 3)


def test_run_identity_describes_without_memory_addresses():
    opt = optax.adam(1e-3)
    desc = {"settings": describe(_Settings()), "f": describe(len), "opt": describe(opt),
            "optimizer": optimizer_identity(opt), "lr": optimizer_identity(0.01)}
    assert desc["settings"] == {"type": "_Settings", "rate": 0.5, "widths": [2, 3]}
    assert desc["f"] == "builtins.len" and desc["opt"] == desc["optimizer"]["custom"] and "0x" not in json.dumps(desc)
    assert desc["lr"] == {"adam": 0.01}
    assert digest(desc) == digest(json.loads(json.dumps(desc))) and len(digest(desc)) == 64


def test_one_spelling_per_model_name_in_the_runtime():
    """The registry's keys are the only model names: no module spells another ("neural_ode" was the Neural ODE's
    second name), and the commands offer exactly the registry's."""
    import ast
    from pathlib import Path

    import myriad.runtime as runtime
    from myriad.runtime.cli import _parser

    root = Path(runtime.__file__).parent
    other = {"neural_ode", "neuralode", "neural-ode", "NODE"}
    found = [(str(p.relative_to(root)), node.value) for p in root.rglob("*.py") if "systems" not in p.parts
             for node in ast.walk(ast.parse(p.read_text())) if isinstance(node, ast.Constant) and node.value in other]
    assert not found, found
    parser = _parser()
    commands = next(a for a in parser._actions if a.choices and "sysid" in a.choices).choices
    for name in ("sysid", "e2e"):
        model = next(a for a in commands[name]._actions if "--model" in a.option_strings)
        assert list(model.choices) == list(MODELS), name


def test_without_a_terminal_the_meter_prints_a_line_every_so_many_seconds(capsys):
    now = [100.0]
    meter = LineProgressMeter(600, 2, "fit van_der_pol", "epoch", seconds=10.0, clock=lambda: now[0])
    for t, postfix in ((104.0, "train 3.0e-01"), (109.9, None), (110.0, "train 2.0e-01"), (115.0, None),
                       (125.0, "train 1.0e-01"), (126.0, None)):
        now[0] = t
        meter.update(postfix)
    meter.close()  # the end, where it stopped: 8 of 600
    assert capsys.readouterr().err.splitlines() == [
        "fit van_der_pol: epoch 5/600, train 2.0e-01, 10.0 s",
        "fit van_der_pol: epoch 7/600, train 1.0e-01, 25.0 s",
        "fit van_der_pol: epoch 8/600, train 1.0e-01, 26.0 s",
    ]
    quiet = LineProgressMeter(3, 0, "short", "it", seconds=10.0, clock=lambda: 0.0)
    quiet.update("loss 1")
    quiet.close()  # a run shorter than the interval prints nothing, not even its end
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("value, seconds", [("2.5", 2.5), ("", 10.0), ("soon", 10.0)])
def test_the_line_interval_is_set_by_the_environment(monkeypatch, capsys, value, seconds):
    monkeypatch.setenv("MYRIAD_PROGRESS_SECONDS", value)
    assert progress_meter(None, 3)._seconds == seconds
    assert ("not a number of seconds" in capsys.readouterr().err) == (value == "soon")
