"""The bad-input corpus: every broken spec gets one compiler-style line pointing at the right place, never a traceback.

Each ``bad_specs/*.yaml`` starts with ``# expect: LINE:COL: SUBSTRING``. ``myriadc check`` must exit 1 and print
``FILE:LINE:COL: error: FIELD: ...`` containing SUBSTRING first; ``myriadc build`` must exit 1 and write nothing.
``hostile_text/*.yaml`` are *valid* specs whose text fields try to break out of the generated string literals: they
must compile, import, and keep their text exactly, without running any of it.
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys
import time
from pathlib import Path

import pytest
import yaml

from myriad.compiler import SpecError, SpecErrors, compile_spec
from myriad.compiler.cli import main

HERE = Path(__file__).resolve().parent
BAD = sorted((HERE / "bad_specs").glob("*.yaml"))
HOSTILE = sorted((HERE / "hostile_text").glob("*.yaml"))
EXPECT = re.compile(r"# expect: (\d+):(\d+): (.+)\Z")
MARKER = "PWNED"  # the file the code-execution specs try to create in the working directory


def _expectation(path: Path) -> tuple[int, int, str]:
    first = path.read_bytes().split(b"\n", 1)[0].decode("utf-8")
    m = EXPECT.match(first)
    assert m, f"{path.name}: first line must be `# expect: LINE:COL: SUBSTRING`"
    return int(m.group(1)), int(m.group(2)), m.group(3)


def _shown(path: Path) -> str:
    """The path as myriadc shows it: relative to the working directory when inside it."""
    rel = os.path.relpath(path)
    return str(path) if rel.startswith("..") else rel


def _check_output(capsys, argv) -> tuple[int, str]:
    rc = main(argv)
    out, err = capsys.readouterr()
    for text in (out, err):
        assert "Traceback" not in text
        assert "internal error" not in text
    return rc, err


def test_corpus_size():
    assert len(BAD) >= 40
    assert len(HOSTILE) >= 5
    assert any("path_constraints" in p.read_text(encoding="utf-8") for p in HOSTILE)  # schema 2 text too


def test_every_corpus_file_has_an_expectation():
    for path in BAD:
        _expectation(path)


@pytest.mark.parametrize("path", BAD, ids=[p.stem for p in BAD])
def test_check_reports_the_error(path, tmp_path, monkeypatch, capsys):
    line, col, substring = _expectation(path)
    monkeypatch.chdir(tmp_path)
    rc, err = _check_output(capsys, ["check", str(path)])
    assert rc == 1, err
    first = err.splitlines()[0] if err else ""
    m = re.match(re.escape(_shown(path)) + r":(\d+):(\d+): error: (.*)\Z", first)
    assert m, f"not a one-line compiler message: {first!r}"
    assert (int(m.group(1)), int(m.group(2))) == (line, col), first
    assert substring in m.group(3), first
    # The offending source line and a caret under the column follow the message.
    lines = err.splitlines()
    if len(lines) > 2 and lines[2].strip() == "^":
        assert lines[2].index("^") - 4 == col - 1, err
    assert not (tmp_path / MARKER).exists()


@pytest.mark.parametrize("path", BAD, ids=[p.stem for p in BAD])
def test_failed_build_writes_nothing(path, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    rc, err = _check_output(capsys, ["build", str(path), "-o", str(out)])
    assert rc == 1, err
    assert err.splitlines()[0].startswith(f"{_shown(path)}:")
    assert not out.exists() or not any(out.rglob("*")), sorted(out.rglob("*"))
    assert not (tmp_path / MARKER).exists()


def test_code_execution_specs_run_nothing(tmp_path, monkeypatch, capsys):
    """Every spec that tries to create the marker file, through every entry point, with cwd where it would land."""
    attempts = [p for p in BAD if MARKER in p.read_text(encoding="utf-8")]
    assert len(attempts) >= 8
    monkeypatch.chdir(tmp_path)
    for path in attempts:
        with pytest.raises((SpecError, SpecErrors)):
            compile_spec(path.read_text(encoding="utf-8"), path.name)
        assert main(["check", str(path)]) == 1
        assert main(["build", str(path), "-o", str(tmp_path / "out")]) == 1
        assert not (tmp_path / MARKER).exists(), f"{path.name} ran code"
    capsys.readouterr()


def test_non_utf8_file(tmp_path, monkeypatch, capsys):
    path = tmp_path / "binary.yaml"
    raw = b"schema: 1\nname: binary\ntitle: \xff\xfe\x00\x81 not text\n"
    path.write_bytes(raw)
    monkeypatch.chdir(tmp_path)
    rc, err = _check_output(capsys, ["check", str(path)])
    assert rc == 1
    # Line 3, column 8: the first bad byte, right after "title: ".
    assert err.startswith(f"binary.yaml:3:8: error: <document>: file is not UTF-8 text: byte 0xff at offset "
                          f"{raw.index(0xff)}; save the file as UTF-8"), err
    rc, err = _check_output(capsys, ["build", str(path), "-o", str(tmp_path / "out")])
    assert rc == 1 and not (tmp_path / "out").exists()
    assert err.startswith("binary.yaml:3:8: error:"), err


def test_non_utf8_byte_after_multibyte_text_is_located_by_character(tmp_path, monkeypatch, capsys):
    path = tmp_path / "accents.yaml"
    path.write_bytes("schema: 1\ntitle: café \u00e9\u00e9".encode() + b"\xc3(\n")  # \xc3( is a broken sequence
    monkeypatch.chdir(tmp_path)
    rc, err = _check_output(capsys, ["check", str(path)])
    assert rc == 1
    assert err.startswith("accents.yaml:2:15: error:"), err


def test_alias_bomb_is_rejected_fast():
    """A full-size billion-laughs document (10 levels of 10 aliases) is refused at the first alias, quickly."""
    levels = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, 10):
        levels.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    text = "schema: 1\nname: bomb\ntitle: t\ndescription: d\nsource: &s x\nreference: {note: *s}\n" + "\n".join(levels)
    t0 = time.perf_counter()
    with pytest.raises(SpecError) as info:
        compile_spec(text, "bomb.yaml")
    assert time.perf_counter() - t0 < 2
    assert info.value.one_line().startswith("bomb.yaml:6:19: error: ")
    assert "YAML aliases" in info.value.message


def test_command_line_prints_message_line_and_caret(tmp_path):
    """The installed entry point, out of process: one message, the source line, a caret; exit 1; no traceback."""
    import subprocess

    path = HERE / "bad_specs" / "undeclared_symbol.yaml"
    line, col, substring = _expectation(path)
    proc = subprocess.run([sys.executable, "-m", "myriad.compiler", "check", str(path)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    message, source, caret, summary = proc.stderr.splitlines()
    assert message.startswith(f"{path}:{line}:{col}: error: dynamics.x: ") and substring in message
    assert source == "    " + path.read_text(encoding="utf-8").splitlines()[line - 1]
    assert caret == " " * (4 + col - 1) + "^"
    assert summary == "myriadc: 1 error"


def test_usage_errors_exit_2(tmp_path, capsys):
    assert main(["check", str(tmp_path / "missing.yaml")]) == 2
    assert main([]) == 2
    with pytest.raises(SystemExit) as info:
        main(["frobnicate"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err


# -- hostile text: valid specs whose text must survive code generation verbatim ----------------------------------


def _import(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[name]
    return module


@pytest.mark.parametrize("path", HOSTILE, ids=[p.stem for p in HOSTILE])
def test_hostile_text_stays_text(path, tmp_path, monkeypatch, capsys):
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    rc, err = _check_output(capsys, ["build", str(path), "-o", str(out)])
    assert rc == 0, err
    generated = out / f"{doc['name']}.py"
    compile(generated.read_text(encoding="utf-8"), str(generated), "exec", dont_inherit=True)
    module = _import(generated, f"_hostile_{doc['name']}")
    system = module.SYSTEM
    assert system.title == doc["title"]
    assert system.description == doc["description"]
    assert type(system).__doc__ == doc["description"]
    assert module.__doc__ == f"{doc['title']}: generated JAX system (minimisation form).\n\n{doc['description']}"
    assert system.source == doc.get("source", "")
    states, controls = doc["states"].values(), doc["controls"].values()
    assert system.state_descriptions == tuple(s.get("description", "") for s in states)
    assert system.state_units == tuple(s.get("units", "") for s in states)
    assert system.control_descriptions == tuple(c.get("description", "") for c in controls)
    assert system.control_units == tuple(c.get("units", "") for c in controls)
    assert system.param_descriptions == tuple(p.get("description", "") for p in doc["parameters"].values())
    paths = doc.get("path_constraints", {})
    assert system.path_constraint_names == tuple(paths)
    assert system.path_constraint_descriptions == tuple(c.get("description", "") for c in paths.values())
    if "note" in doc.get("reference", {}):
        assert system.reference["note"] == doc["reference"]["note"]
    assert not (tmp_path / MARKER).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing else appeared in the working directory
