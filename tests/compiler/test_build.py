"""The build: committed modules are up to date, output is deterministic, the CLI behaves, new specs work end to end."""

import hashlib
import importlib.util
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from myriad.compiler import build, compile_file
from myriad.compiler.cli import main

from ..helpers import ALL_SPEC_NAMES, ALL_SPECS, ROOT, SPECS_DIR

SYSTEMS_DIR = ROOT / "runtime" / "systems"


def test_every_spec_is_built_and_registered():
    from myriad.runtime import systems

    assert sorted(systems.NAMES) == sorted(ALL_SPEC_NAMES)
    assert len(ALL_SPEC_NAMES) == 18


def test_committed_modules_are_up_to_date(tmp_path, monkeypatch):
    # The committed runtime/systems are goldens: rebuild into a temporary folder and compare bytes.
    monkeypatch.chdir(ROOT)
    result = build([os.path.relpath(SPECS_DIR)], tmp_path)
    assert not result.errors
    for name in [*ALL_SPEC_NAMES, "__init__"]:
        fresh = (tmp_path / f"{name}.py").read_text()
        committed = (SYSTEMS_DIR / f"{name}.py").read_text()
        assert fresh == committed, f"runtime/systems/{name}.py is stale: run `myriadc build specs/`"


def test_check_flag_reports_stale_output(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    spec = os.path.relpath(SPECS_DIR / "simple_case.yaml")
    assert main(["build", spec, "-o", str(tmp_path), "-q"]) == 0
    assert main(["build", spec, "-o", str(tmp_path), "--check"]) == 0
    target = tmp_path / "simple_case.py"
    target.write_text(target.read_text().replace("horizon = 1.0", "horizon = 2.0"))
    capsys.readouterr()
    assert main(["build", spec, "-o", str(tmp_path), "--check"]) == 1
    out, err = capsys.readouterr()
    assert "-    horizon = 2.0" in out and "+    horizon = 1.0" in out
    assert "stale" in err


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.glob("*.py"))}


@pytest.mark.slow
def test_builds_are_byte_identical_across_processes(tmp_path):
    # Different hash seeds change set and dict iteration in sympy; the output must not change.
    digests = []
    for seed in ("0", "12345"):
        out = tmp_path / seed
        env = {**os.environ, "PYTHONHASHSEED": seed}
        subprocess.run([sys.executable, "-m", "myriad.compiler", "build", "specs", "-o", str(out), "-q"],
                       cwd=ROOT, env=env, check=True)
        digests.append(_digest(out))
    assert digests[0] == digests[1]
    assert digests[0] == {k: v for k, v in _digest(SYSTEMS_DIR).items() if k in digests[0]}


NEW_SPEC = textwrap.dedent("""\
    schema: 1
    name: damped_spring
    title: Damped spring
    description: A mass on a damped spring pushed to rest; not shipped, written by a test.
    parameters:
      k: {value: 2.0, learnable: true, guess: 1.0, description: stiffness}
      c: {value: 0.3, description: damping}
    definitions:
      energy: (k*q**2 + v**2)/2
    states:
      q: {initial: 1.0, final: 0, bounds: [-2, 2], description: position}
      v: {initial: 0.0, final: 0, description: velocity}
    controls:
      f: {bounds: [-1, 1], description: force}
    dynamics:
      q: v
      v: -k*q - c*v + f*where(t < 5, 1, 0.5)
    cost:
      sense: minimize
      running: energy + f**2
    horizon: 10
    """)


def test_new_spec_builds_with_cli_and_imports(tmp_path, capsys):
    spec = tmp_path / "damped_spring.yaml"
    spec.write_text(NEW_SPEC)
    out = tmp_path / "generated"
    assert main(["check", str(spec)]) == 0
    assert main(["build", str(spec), "-o", str(out)]) == 0
    assert (out / "__init__.py").exists()
    module_spec = importlib.util.spec_from_file_location("damped_spring_test", out / "damped_spring.py")
    module = importlib.util.module_from_spec(module_spec)
    module_spec.loader.exec_module(module)
    s = module.SYSTEM
    p = s.default_params()
    x, u = np.array([0.5, -0.2]), np.array([0.4])
    np.testing.assert_allclose(s.dynamics(x, u, 1.0, p), [-0.2, -2 * 0.5 + 0.3 * 0.2 + 0.4], rtol=1e-14)
    np.testing.assert_allclose(s.dynamics(x, u, 6.0, p)[1], -2 * 0.5 + 0.3 * 0.2 + 0.2, rtol=1e-14)
    np.testing.assert_allclose(s.running_cost(x, u, 0.0, p), (2 * 0.25 + 0.04) / 2 + 0.16, rtol=1e-14)
    assert s.x_final == (0.0, 0.0)
    assert s.learnable == ("k",) and s.learnable_guesses == (1.0,)
    assert s.optimal_control_kind == "stationary"
    assert module.SPEC_SHA256 == hashlib.sha256(NEW_SPEC.encode()).hexdigest()


@pytest.mark.skipif(os.name != "posix", reason="file modes are POSIX")
def test_built_files_follow_the_umask(tmp_path):
    spec = tmp_path / "damped_spring.yaml"
    spec.write_text(NEW_SPEC)
    out = tmp_path / "generated"
    old = os.umask(0o022)
    try:
        assert main(["build", str(spec), "-o", str(out)]) == 0
    finally:
        os.umask(old)
    for name in ("__init__.py", "damped_spring.py"):
        assert (out / name).stat().st_mode & 0o777 == 0o644, name  # not mkstemp's 0600


def test_loader_compiles_paths_into_cache(tmp_path, monkeypatch):
    from myriad.runtime import load

    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path / "cache"))
    spec = tmp_path / "damped_spring.yaml"
    spec.write_text(NEW_SPEC)
    s1 = load(spec)
    assert s1.name == "damped_spring"
    assert load(str(spec)) is s1  # cached by content
    spec.write_text(NEW_SPEC.replace("value: 0.3", "value: 0.4"))
    s2 = load(spec)
    assert s2.param_values[1] == 0.4 and s2 is not s1
    assert len(list((tmp_path / "cache" / "systems").iterdir())) == 2


def test_header_names_spec_and_hash():
    text = (SYSTEMS_DIR / "pendulum.py").read_text()
    sha = hashlib.sha256((SPECS_DIR / "pendulum.yaml").read_bytes()).hexdigest()
    assert text.splitlines()[0] == (f"# Autogenerated by myriadc from specs/pendulum.yaml (schema 3, sha256 {sha}). "
                                    "Do not edit.")


def test_generated_modules_import_only_jax_and_myriad():
    for path in SYSTEMS_DIR.glob("*.py"):
        imports = [ln for ln in path.read_text().splitlines() if ln.startswith(("import ", "from "))]
        for ln in imports:
            assert ln.split()[1].split(".")[0] in {"math", "jax", "myriad", "importlib"}, (path.name, ln)


@pytest.mark.parametrize("argv,code", [([], 2), (["frobnicate"], 2), (["build"], 2), (["show", "no_such_system"], 2),
                                       (["check", "no/such/file.yaml"], 2)])
def test_cli_usage_errors_exit_2(argv, code, capsys):
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    assert rc == code
    assert "Traceback" not in capsys.readouterr().err


def test_cli_suggests_the_closest_spec_name(capsys):
    assert main(["show", "van_der_poll"]) == 2
    assert "did you mean van_der_pol?" in capsys.readouterr().err


def test_cli_list_and_show(capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ALL_SPEC_NAMES)
    assert main(["show", "predator_prey"]) == 0
    out = capsys.readouterr().out
    assert "dlam_x/dt" in out and "z(T) = 5 is required" in out and "u* (stationary)" in out
    assert main(["show", "rocket_landing"]) == 0
    assert "not derived" in capsys.readouterr().out


def test_all_specs_compile_quickly_enough_to_report():
    # Not a timing assertion (those live in bench/); this just exercises the full pipeline on every spec once.
    for path in ALL_SPECS:
        assert compile_file(path).text


def test_structural_params_are_those_the_constant_fields_use():
    from myriad.runtime import load

    # Tumour: x0 and bounds use pbar = ((b - mu)/d)**(3/2) (through a definition), the budget bound uses A and the
    # control bound a; xi and G appear only in the dynamics.
    assert load("tumour").structural_params == ("b", "d", "mu", "a", "A")
    assert load("predator_prey").structural_params == ("B", "M")
    assert load("rocket_landing").structural_params == ()
