"""One run reports every independent error of a spec (up to a cap), each at its own line and column.

A pass stops the pipeline only where later checks depend on it: a YAML error stops everything, a bad name stops the
symbolic pass; otherwise each section, entry, expression and check is judged on its own, and a field that only fails
because a field it uses did is not reported twice.
"""

from __future__ import annotations

import re

import pytest

from myriad.compiler import SpecError, SpecErrors, compile_spec
from myriad.compiler.cli import main
from myriad.compiler.errors import MAX_REPORTED

VALID = """\
schema: 1
name: two
title: Two errors
description: A valid spec that each test breaks in two places.
parameters:
  k: {value: 0.5}
  w: {value: 2.0, learnable: true, guess: 1.5}
states:
  x: {initial: 1, bounds: [-3, 3]}
  v: {initial: 0, bounds: [-5, 5]}
controls:
  u: {bounds: [-1, 1]}
dynamics:
  x: v
  v: -w*x - k*v + u
cost:
  sense: minimize
  running: x**2 + u**2
horizon: 10
"""
MESSAGE = re.compile(r"two\.yaml:(\d+):(\d+): error: ([^\n]*)")


def _spec(*edits: tuple[str, str]) -> str:
    text = VALID
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    return text


def _check(tmp_path, monkeypatch, capsys, text: str) -> tuple[int, list[tuple[int, int, str]], str]:
    """``myriadc check`` on the text: exit code, the (line, col, message) of every error, and stderr."""
    (tmp_path / "two.yaml").write_text(text, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    rc = main(["check", "two.yaml"])
    out, err = capsys.readouterr()
    assert "Traceback" not in err + out and "internal error" not in err + out
    return rc, [(int(a), int(b), c) for a, b, c in MESSAGE.findall(err)], err


def test_the_valid_spec_compiles():
    compile_spec(VALID, "two.yaml")


def test_undeclared_symbol_and_negative_horizon(tmp_path, monkeypatch, capsys):
    """The issue's example: the symbol (symbolic pass) and the horizon (check pass), both, in one run."""
    rc, errors, err = _check(tmp_path, monkeypatch, capsys, _spec(("v: -w*x - k*v + u", "v: -w*x - kk*v + u"),
                                                                ("horizon: 10", "horizon: -2")))
    assert rc == 1
    assert [(line, col) for line, col, _ in errors] == [(15, 13), (19, 10)]
    assert "undeclared symbol `kk` (did you mean `k`?)" in errors[0][2]
    assert errors[1][2] == "horizon: horizon must be positive, got -2"
    assert err.rstrip().endswith("myriadc: 2 errors")


def test_two_bad_bounds(tmp_path, monkeypatch, capsys):
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, _spec(("bounds: [-3, 3]", "bounds: [3, -3]"),
                                                              ("u: {bounds: [-1, 1]}", "u: {bounds: [1, -1]}")))
    assert rc == 1
    assert [(line, col) for line, col, _ in errors] == [(9, 27), (12, 15)]
    assert "bounds of `x` are reversed: lower 3 > upper -3" in errors[0][2]
    assert "bounds of `u` are reversed: lower 1 > upper -1" in errors[1][2]


def test_bad_bounds_do_not_also_report_the_initial_value_outside_them(tmp_path, monkeypatch, capsys):
    """x0 = 1 is "outside" [3, -3] only because the bounds are reversed: one error, not two."""
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, _spec(("bounds: [-3, 3]", "bounds: [3, -3]")))
    assert rc == 1 and len(errors) == 1


@pytest.mark.parametrize("parameter, cost, expected", [
    # both found while parsing
    (("guess: 1.5", "guess: 1.5, units: [1, 2]"), ("sense: minimize", "sense: minimise"),
     [(7, 55, "expected a single value"), (17, 10, "`sense` must be `minimize` or `maximize`, got `minimise`")]),
    # both found by the symbolic pass
    (("k: {value: 0.5}", "k: {value: 0.5*q}"), ("running: x**2 + u**2", "running: x**2 + sqr(u)"),
     [(6, 18, "undeclared symbol `q`"), (18, 19, "unknown function `sqr` (did you mean `sqrt`?)")]),
    # the parameter in the symbolic pass, the cost in the check pass
    (("k: {value: 0.5}", "k: {value: 1/0}"), ("running: x**2 + u**2", "running: x**2 + u**2\n  terminal: x*u"),
     [(6, 14, "division by zero"), (19, 13, "the terminal cost uses the control(s) u")]),
], ids=["parse", "symbolic", "symbolic-and-check"])
def test_a_bad_parameter_and_a_bad_cost(tmp_path, monkeypatch, capsys, parameter, cost, expected):
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, _spec(parameter, cost))
    assert rc == 1
    assert [(line, col) for line, col, _ in errors] == [(line, col) for line, col, _ in expected], errors
    for (_, _, message), (_, _, substring) in zip(errors, expected):
        assert substring in message


def test_top_level_fields_are_judged_together(tmp_path, monkeypatch, capsys):
    """A misspelt section is an unknown field and a missing one; a bad entry of another section is found too."""
    text = _spec(("horizon: 10", "horizn: 10"), ("x: {initial: 1, bounds: [-3, 3]}", "x: {initial: 1, bound: 3}"))
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, text)
    assert rc == 1
    assert [(line, col) for line, col, _ in errors] == [(19, 1), (1, 1), (9, 19)], errors
    assert "unknown field `horizn` in the spec (did you mean `horizon`?)" in errors[0][2]
    assert "missing required field `horizon`" in errors[1][2]
    assert "unknown field `bound` in state `x` (did you mean `bounds`?)" in errors[2][2]


def test_an_error_is_reported_once_not_at_every_use(tmp_path, monkeypatch, capsys):
    """k fails; the parameter, definition, equation and bound that use it are not reported again."""
    text = _spec(("k: {value: 0.5}", "k: {value: 0.5 + q}\n  m: {value: 2*k}"),
                 ("guess: 1.5}", "guess: 1.5}\ndefinitions:\n  d: k*x"),
                 ("v: -w*x - k*v + u", "v: -w*x - d*v + u"), ("bounds: [-5, 5]", "bounds: [-5*m, 5]"),
                 ("horizon: 10", "horizon: 0"))
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, text)
    assert rc == 1
    assert [message.split(":")[0] for _, _, message in errors] == ["parameters.k.value", "horizon"], errors


def test_a_yaml_error_stops_everything(tmp_path, monkeypatch, capsys):
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, _spec(("title: Two errors", "title: [unclosed"),
                                                              ("horizon: 10", "horizon: -2")))
    assert rc == 1 and len(errors) == 1 and "invalid YAML" in errors[0][2]


def test_a_bad_name_stops_the_symbolic_pass(tmp_path, monkeypatch, capsys):
    """Expressions resolve by name, so a reserved name is reported alone (with the other bad names)."""
    text = _spec(("k: {value: 0.5}", "exp: {value: 0.5}\n  lambda: {value: 1}"), ("horizon: 10", "horizon: -2"))
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, text)
    assert rc == 1
    assert [(line, col) for line, col, _ in errors] == [(6, 3), (7, 3)], errors
    assert "parameter name `exp` is reserved" in errors[0][2]
    assert "parameter name `lambda` is a Python keyword" in errors[1][2]


def test_a_missing_equation_does_not_stop_the_symbolic_pass(tmp_path, monkeypatch, capsys):
    text = _spec(("  v: -w*x - k*v + u\n", ""), ("running: x**2 + u**2", "running: x**2 + uu**2"))
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, text)
    assert rc == 1
    assert "state `v` has no equation" in errors[0][2]
    assert "undeclared symbol `uu` (did you mean `u`?)" in errors[1][2]
    assert len(errors) == 2


def test_the_cap(tmp_path, monkeypatch, capsys):
    """30 independent errors: the first MAX_REPORTED are printed, and how many more were left out."""
    n = 30
    states = "".join(f"  s{i}: {{initial: 0, bounds: [1, -1]}}\n" for i in range(n))
    dynamics = "".join(f"  s{i}: u\n" for i in range(n))
    text = _spec(("  x: {initial: 1, bounds: [-3, 3]}\n  v: {initial: 0, bounds: [-5, 5]}\n", states),
                 ("  x: v\n  v: -w*x - k*v + u\n", dynamics), ("x**2 + u**2", "u**2"))
    rc, errors, err = _check(tmp_path, monkeypatch, capsys, text)
    assert rc == 1
    assert MAX_REPORTED == 20
    assert len(errors) == MAX_REPORTED
    assert [line for line, _, _ in errors] == list(range(9, 9 + MAX_REPORTED))
    assert f"... and {n - MAX_REPORTED} more errors left out (the first {MAX_REPORTED} are shown)" in err
    assert err.rstrip().endswith(f"myriadc: {n} errors")


def test_compile_spec_raises_them_together():
    """SpecErrors is a SpecError whose location is the first error's; `errors` holds all of them in order."""
    text = _spec(("bounds: [-3, 3]", "bounds: [3, -3]"), ("horizon: 10", "horizon: -2"))
    with pytest.raises(SpecError) as info:
        compile_spec(text, "two.yaml")
    exc = info.value
    assert isinstance(exc, SpecErrors)
    assert [(e.loc.line, e.loc.col) for e in exc.errors] == [(9, 27), (19, 10)]
    assert (exc.loc.line, exc.loc.col) == (9, 27) and exc.message == exc.errors[0].message
    assert str(exc).count(": error: ") == 2


def test_one_error_is_still_a_plain_spec_error():
    with pytest.raises(SpecError) as info:
        compile_spec(_spec(("horizon: 10", "horizon: -2")), "two.yaml")
    assert type(info.value) is SpecError


def test_a_failed_build_with_several_errors_writes_nothing(tmp_path, monkeypatch, capsys):
    (tmp_path / "two.yaml").write_text(_spec(("bounds: [-3, 3]", "bounds: [3, -3]"), ("horizon: 10", "horizon: -2")),
                                       encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    assert main(["build", "two.yaml", "-o", "out"]) == 1
    _, err = capsys.readouterr()
    assert err.count(": error: ") == 2
    assert not (tmp_path / "out").exists()


def test_several_code_execution_attempts_run_nothing(tmp_path, monkeypatch, capsys):
    """Each attempt is reported, none is run (expressions are parsed, never evaluated)."""
    attack = "__import__('os').system('touch PWNED')"
    text = _spec(("k: {value: 0.5}", f'k: {{value: "{attack}"}}'), ("running: x**2 + u**2", f'running: "{attack}"'))
    rc, errors, _ = _check(tmp_path, monkeypatch, capsys, text)
    assert rc == 1 and len(errors) == 2
    assert not (tmp_path / "PWNED").exists()
