"""The cold start's structure (issue 31), not its timing (bench/cold_start.py times it): `import myriad.runtime` and
`myriad --help` import no JAX, sympy or matplotlib; the help still lists every command, each command's own parser
still takes its choices from the registries, and the public names still import.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from myriad.runtime import cli

_HEAVY = ("jax", "sympy", "matplotlib", "scipy", "gymnasium", "equinox", "optax")


def _fresh(code: str) -> dict:
    """Run ``code`` in a new interpreter; it prints a JSON object, returned here."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_import_myriad_runtime_and_the_help_import_no_heavy_library():
    seen = _fresh(f"""
import contextlib, io, json, sys
import myriad.runtime
after_import = [m for m in {_HEAVY!r} if m in sys.modules]
from myriad.runtime.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
    main(["--help"])
print(json.dumps({{"import": after_import, "help": [m for m in {_HEAVY!r} if m in sys.modules],
                  "text": out.getvalue()}}))
""")
    assert seen["import"] == [] and seen["help"] == []
    for name, summary in cli._COMMANDS.items():
        assert name in seen["text"] and summary.split()[0] in seen["text"]


def test_every_command_is_in_the_help_with_its_own_parsers_summary():
    """The top-level help's summaries (cli._COMMANDS) are what each command's own parser says."""
    whole = cli._parser()._subparsers._group_actions[0]
    short = cli._parser("")._subparsers._group_actions[0]
    assert list(short.choices) == list(whole.choices) == list(cli._COMMANDS)
    assert [a.help for a in short._choices_actions] == [a.help for a in whole._choices_actions]
    assert set(cli._PACKAGE_COMMANDS) <= set(cli._COMMANDS)


def test_a_commands_parser_takes_its_choices_from_the_registries():
    from myriad.runtime import METHODS
    from myriad.runtime.integrators import INTEGRATORS
    from myriad.runtime.solvers import SOLVERS

    for built in ("solve", None):  # that command's parser alone (what main builds), and all of them
        solve = cli._parser(built)._subparsers._group_actions[0].choices["solve"]
        choices = {a.dest: a.choices for a in solve._actions if a.choices is not None}
        assert list(choices["transcription"]) == list(METHODS)
        assert list(choices["solver"]) == list(SOLVERS)
        assert list(choices["integrator"]) == [n for n, c in INTEGRATORS.items() if c.fixed_step]
    bench = cli._parser("bench")._subparsers._group_actions[0].choices["bench"]
    assert next(a.choices for a in bench._actions if a.dest == "solver") == list(SOLVERS)


def test_main_builds_the_named_commands_parser_any_case(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["SOLVE", "--help"])
    assert stop.value.code == 0
    assert "--transcription" in capsys.readouterr().out


def test_solve_and_bench_compile_quick_by_default_and_restore_the_options():
    from myriad.runtime.compilation import programs

    for command in ("solve", "bench"):
        sub = cli._parser(command)._subparsers._group_actions[0].choices[command]
        assert next(a for a in sub._actions if a.dest == "compile").default == "quick"
    previous = programs.compiler_options()
    with cli._compiler_options("quick"):
        assert programs.compiler_options() == programs.QUICK
        with cli._compiler_options("full"):
            assert programs.compiler_options() is None
        assert programs.compiler_options() == programs.QUICK
    assert programs.compiler_options() == previous


def test_the_public_names_import_and_the_functions_win_over_their_modules():
    """``solve`` and ``simulate`` are also submodules: importing those first must not hide the functions."""
    seen = _fresh("""
import json
import myriad.runtime.simulate, myriad.runtime.solve
import myriad.runtime as rt
from myriad.runtime import *
print(json.dumps({"missing": [n for n in rt.__all__ if not hasattr(rt, n)],
                  "kinds": [type(rt.solve).__name__, type(rt.simulate).__name__, type(solve).__name__]}))
""")
    assert seen == {"missing": [], "kinds": ["function", "function", "function"]}


@pytest.mark.slow  # seven fresh processes importing JAX
def test_every_package_imports_first_in_a_fresh_process():
    """A lazy ``myriad.runtime`` no longer imports its packages in one fixed order, so an import cycle through two
    packages' ``__init__`` (which tests/runtime/test_layering.py does not count) fails when the wrong one is first."""
    packages = ["indirect", "transcriptions", "solvers", "integrators", "solve_config", "sweep", "compilation"]
    seen = _fresh(f"""
import importlib, json, subprocess, sys
failed = [p for p in {packages!r} if subprocess.run([sys.executable, "-c", "import myriad.runtime." + p],
                                                   capture_output=True).returncode]
print(json.dumps(failed))
""")
    assert seen == []


def test_a_spec_compiled_before_loads_without_the_compiler(tmp_path, monkeypatch):
    from myriad.runtime import loader

    spec = tmp_path / "two_compartment_dosing.yaml"
    spec.write_text(_DOSING)
    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path / "cache"))
    first = loader.load(spec)
    monkeypatch.setattr(loader, "_loaded", {})  # as a new process: only the folder is left

    def refuse(*args, **kwargs):
        raise AssertionError("compiled again")

    import myriad.compiler

    monkeypatch.setattr(myriad.compiler, "compile_file", refuse)
    again = loader.load(spec)
    assert again.name == first.name and again.spec_file == first.spec_file
    assert list(again.param_values) == list(first.param_values)
    spec.write_text(_DOSING.replace("value: 0.6", "value: 0.7"))  # an edit compiles again
    with pytest.raises(AssertionError, match="compiled again"):
        loader.load(spec)


def test_a_spec_compiles_beside_the_jax_import_and_load_finds_it(tmp_path, monkeypatch):
    """`myriad solve SPEC.yaml` compiles the spec in a second process (no JAX imported there) while it imports JAX;
    the module it writes is the one load() imports, and a bad spec there is load()'s to report."""
    spec = tmp_path / "two_compartment_dosing.yaml"
    spec.write_text(_DOSING)
    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    seen = _fresh(f"""
import json, sys
from myriad.runtime.loader import compiled_spec
path = compiled_spec({str(spec)!r})
print(json.dumps({{"path": str(path), "heavy": [m for m in {_HEAVY!r} if m in sys.modules and m != "sympy"]}}))
""")
    assert seen["heavy"] == []
    aside = cli._compile_spec_aside(["solve", "--intervals", "10", str(spec)])
    if aside is not None:  # one core: none is started
        assert aside.wait(timeout=120) == 0
    from myriad.runtime import loader

    assert str(loader.compiled_spec(spec)) == seen["path"]
    assert type(loader.load(spec)).__module__.startswith("myriad_user_systems.")
    assert cli._compile_spec_aside(["solve", "pendulum"]) is None  # a name, not a file: nothing to compile


def test_main_leaves_the_garbage_collector_of_its_caller_as_it_was():
    import gc

    before = gc.get_threshold(), gc.get_freeze_count()
    with pytest.raises(SystemExit):
        cli.main(["solve", "pendulum", "--no-such-flag"])
    assert (gc.get_threshold(), gc.get_freeze_count()) == before


_DOSING = """\
schema: 1
name: two_compartment_dosing
title: Two-compartment dosing
description: Hold the central drug concentration near a target with the least infusion.
parameters:
  k12: {value: 0.6, description: central to peripheral rate}
  k21: {value: 0.3, description: peripheral to central rate}
  k10: {value: 0.4, description: elimination rate}
states:
  c1: {initial: 0, bounds: [0, 10], description: central concentration}
  c2: {initial: 0, bounds: [0, 10], description: peripheral concentration}
controls:
  u: {bounds: [0, 5], description: infusion rate}
dynamics:
  c1: -(k12 + k10)*c1 + k21*c2 + u
  c2: k12*c1 - k21*c2
cost:
  sense: minimize
  running: (c1 - 2)**2 + 0.5*u**2
horizon: 6
"""
