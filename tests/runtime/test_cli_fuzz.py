"""Every `myriad` command, every flag, bad values (issue 33): a usage error exits 2 with a message that names the flag,
never an internal error or a traceback.

The commands and flags come from the parser itself, so a new command or flag is fuzzed without editing this file. The
commands run in this process through ``main(argv)``; the work each one starts once its arguments are checked is
replaced by a stub that raises :class:`_Started`, so a value the checks let through costs nothing and counts as
accepted. A value that is invalid whatever the command (not a number, NaN, a negative count, a folder that does not
exist, an unknown name) must be refused before that point; a legal-looking one (0, a huge number, an empty word) may
be accepted or refused, but never crash.
"""

from __future__ import annotations

import argparse

import jax
import pytest

from myriad.runtime import cli
from myriad.runtime.configs import parse_value

jax.config.update("jax_enable_x64", True)


class _Started(BaseException):
    """The command got past its checks to its work (a BaseException: ``main`` reports every Exception)."""


# Where each command's work starts, after its checks; replaced by a stub. A new command must add its own here.
_WORK = {
    "solve": "myriad.runtime.solve_config.SolveConfig.solve",
    "bench": "myriad.runtime.bench.run_bench",
    "sysid": "myriad.runtime.sysid.run.run_sysid",
    "e2e": "myriad.runtime.e2e.train.run_e2e",
    "sweep": "myriad.runtime.sweep.run.run_sweep",
    "rl-reference": "myriad.runtime.rl.reference.reference_record",  # the fuzz always passes a NAME
    "dataset": "myriad.runtime.datasets.run.run_dataset",
    "imitate": "myriad.runtime.imitation.run.run_imitation",
}
# A valid value of each positional, by its metavar (a system with learnable parameters: sysid and e2e need one).
_POSITIONAL = {"NAME|PATH": "van_der_pol"}
_MISSING = __file__ + "/missing"  # a folder inside a file: never made, whoever runs the tests
_HUGE = str(10**12)

# (command, flag, value), or (command, field) for --set FIELD={, that a command's checks do not yet refuse as this
# file asks: a non-strict xfail with the reason; remove an entry once fixed (an unexpected pass says so).
_KNOWN: dict[tuple[str, ...], str] = {}


def _commands() -> dict[str, argparse.ArgumentParser]:
    return dict(cli._parser()._subparsers._group_actions[0].choices)


def _flags(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions if a.option_strings and not isinstance(a, argparse._HelpAction)]


def _values(action: argparse.Action) -> list[tuple[str, bool]]:
    """``(value, strict)`` pairs: a strict value must be refused (exit 2); any other may also be accepted."""
    if action.nargs == 0:  # a switch: a value attached to it is refused by argparse
        return []
    if action.choices is not None:
        return [("no_such_choice", True), ("", True)]
    if action.type is int:
        return [("abc", True), ("1.5", True), ("", True), ("nan", True), ("-1", True), ("0", False), (_HUGE, False)]
    if action.type is float:
        return [("abc", True), ("", True), ("nan", True), ("-1", True), ("inf", False), ("0", False),
                ("1e308", False)]
    if action.type is parse_value:  # JSON or a word: broken JSON must not pass as a word
        return [("{", True), ("[1,", True), ("null", False), ("-1", False), ("NaN", False), ("", False)]
    if action.metavar == "KEY=VALUE":
        return [("no_equals_sign", True), ("=1", True), ("no_such_field=1", True)]
    if action.metavar in ("FILE", "FILE.png", "FILE.npz", "DIR"):
        return [(_MISSING + "/x", True), ("", False)]
    return [("no_such_name", False), ("", False), (_MISSING, False)]


def _cases():
    for command, parser in _commands().items():
        for action in _flags(parser):
            flag = action.option_strings[-1] if action.option_strings[0] == "--controls" else action.option_strings[0]
            for value, strict in _values(action):
                short = value.replace(_MISSING, "MISSING")
                known = _KNOWN.get((command, flag, short))
                marks = [pytest.mark.xfail(reason=known)] if known else []
                yield pytest.param(command, flag, value, strict, id=f"{command} {flag} {short!r}", marks=marks)


@pytest.fixture
def run(monkeypatch, capsys):
    """``run(argv) -> (exit code, stderr)``; exit code 0 where the command reached its work."""
    def started(*args, **kwargs):
        raise _Started

    for target in _WORK.values():
        monkeypatch.setattr(target, started)
    # The compilation cache stays this process's own: only the folder's name is resolved.
    monkeypatch.setattr("myriad.runtime.compilation.jax_cache.enable_compilation_cache",
                        lambda requested=None: None)

    def call(argv):
        capsys.readouterr()
        try:
            code = cli.main(argv)
        except _Started:
            code = 0
        except SystemExit as exc:  # argparse
            code = exc.code
        return code, capsys.readouterr().err

    return call


def _positionals(parser: argparse.ArgumentParser) -> list[str]:
    out = []
    for action in parser._actions:
        if not action.option_strings:
            assert action.metavar in _POSITIONAL, f"add a valid value of the positional {action.metavar} to _POSITIONAL"
            out.append(_POSITIONAL[action.metavar])
    return out


def _check(code, err, names, strict):
    assert "internal error" not in err and "Traceback" not in err, err
    assert code in (0, 2), (code, err)
    if strict:
        assert code == 2, f"accepted: {err}"
    if code == 2:
        assert any(n in err for n in names), f"the message does not name {names}: {err}"


def test_every_command_says_where_its_work_starts():
    assert set(_commands()) == set(_WORK), "a command without an entry in _WORK: the fuzz would start its work"


@pytest.mark.parametrize(("command", "flag", "value", "strict"), list(_cases()))
def test_a_bad_value_is_refused_naming_the_flag(run, command, flag, value, strict):
    parser = _commands()[command]
    action = next(a for a in _flags(parser) if flag in a.option_strings)
    code, err = run([command, *_positionals(parser), f"{flag}={value}"])
    _check(code, err, action.option_strings, strict)


@pytest.mark.parametrize("command", list(_commands()))
def test_a_switch_given_a_value_is_refused(run, command):
    parser = _commands()[command]
    for action in _flags(parser):
        if action.nargs == 0 and not isinstance(action, argparse.BooleanOptionalAction):
            flag = action.option_strings[0]
            code, err = run([command, *_positionals(parser), f"{flag}=yes"])
            _check(code, err, action.option_strings, strict=True)


@pytest.mark.parametrize("command", [c for c, p in _commands().items() if any(not a.option_strings
                                                                              for a in p._actions)])
@pytest.mark.parametrize("value", ["no_such_system", _MISSING + "/spec.yaml", ""])
def test_an_unknown_system_is_refused_naming_it(run, command, value):
    code, err = run([command, value])
    _check(code, err, [repr(value), value] if value else ["''", "empty"], strict=True)


@pytest.mark.parametrize("command", [c for c, p in _commands().items() if "--set" in p._option_string_actions])
def test_every_field_set_to_broken_json_is_refused_naming_it(run, command):
    """``--set FIELD={`` for every field of the command's config, the fields read from its own refusal of an unknown
    one (so a new field is covered without editing this file)."""
    head = [command, *_positionals(_commands()[command])]
    _, err = run([*head, "--set", "no_such_field=1"])
    fields = err.rsplit("known: ", 1)[1].strip().split(", ")
    assert len(fields) > 3, err
    failures = []
    for field in fields:
        code, err = run([*head, "--set", f"{field}={{"])
        flags = [o for a in _commands()[command]._actions if a.dest == field for o in a.option_strings]
        named = any(n in err for n in (field, "--set", "--" + field.replace("_", "-"), *flags))
        if (code != 2 or "internal error" in err or "Traceback" in err or not named) and (command, field) not in _KNOWN:
            failures.append(f"{field}: exit {code}, {err.strip()!r}")
    assert not failures, "\n".join(failures)
