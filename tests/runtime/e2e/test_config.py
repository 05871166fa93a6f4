"""E2EConfig's own checks (no learning): each bad value is refused on construction naming its field, and
``myriad e2e`` respells the field as its flag (tests/runtime/test_cli_fuzz.py feeds every flag bad values)."""

from __future__ import annotations

import pytest

from myriad.runtime.cli import main
from myriad.runtime.e2e import E2EConfig


@pytest.mark.parametrize("value", [{"a": 1.5}, [["a", 1.5]], (("a", 1.5),)])
def test_cost_guess_is_a_mapping_or_pairs(value):
    config = E2EConfig(learn_dynamics=False, learn_cost=("a",), cost_guess=value)
    assert config.cost_guess == (("a", 1.5),)


@pytest.mark.parametrize("value", ["{", "a", None, -1, float("nan"), [1, 2], [["a"]], {"a": "x"}, {"a": float("inf")},
                                   {"a": True}, [[1, 2]]])
def test_a_bad_cost_guess_is_refused_naming_the_field_and_the_form(value):
    with pytest.raises(ValueError, match=r"cost_guess must map names in learn_cost to finite numbers, e\.g\."):
        E2EConfig(learn_dynamics=False, learn_cost=("a",), cost_guess=value)


@pytest.mark.parametrize(("field", "value", "words"), [
    ("hidden", (-1,), "hidden must be a list of layer widths >= 1"),
    ("hidden", (), "hidden must be a list of layer widths >= 1"),
    ("hidden", (8, 0), "hidden must be a list of layer widths >= 1"),
    ("activation", "{", "activation must be one of sigmoid, softplus, tanh, relu, got '{'"),
    ("activation", ["tanh"], "activation must be one of"),
])
def test_the_network_is_checked_whichever_model_is_learned(field, value, words):
    for model in ("parametric", "node"):  # a parametric run ignores the network, but a wrong one is still a mistake
        with pytest.raises(ValueError, match=words):
            E2EConfig(model=model, **{field: value})


@pytest.mark.parametrize(("argv", "words"), [
    (["--unroll", "0"], "--unroll must be an integer >= 1 (planner steps per iteration), got 0"),
    (["--expert-index", "-1"], "--expert-index must be an integer >= 0"),
    (["--expert", "no/such/file.npz"], "--expert 'no/such/file.npz': file not found; give a dataset .npz"),
    (["--cost-guess", "[1,", "--learn-cost", "a"], "--cost-guess must map names in learn_cost to finite numbers"),
    (["--hidden", "-1"], "--hidden must be a list of layer widths >= 1"),
    (["--set", "activation={"], "--activation must be one of sigmoid, softplus, tanh, relu"),
])
def test_cli_names_the_flag_and_the_fix(argv, words, capsys):
    assert main(["e2e", "cancer_treatment", *argv]) == 2
    assert words in capsys.readouterr().err
