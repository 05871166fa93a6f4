"""`myriad solve` / `myriad bench` refuse bad arguments with exit code 2 before any system is loaded or solved.

Every test replaces the loading, solving and bench functions by ones that raise, so a usage error found only after
the long work (the old behaviour: solve, then die on the missing folder) fails the test instead of passing slowly.
"""

import os

import pytest

import myriad.runtime
import myriad.runtime.bench
from myriad.runtime.cli import main
from myriad.runtime.integrators import INTEGRATORS
from myriad.runtime.solve_config import METHODS, takes_integrator
from myriad.runtime.solvers import SOLVERS


class _Reached(BaseException):
    """Raised by the replaced work functions; a BaseException, so the CLI's own error handling cannot swallow it."""


@pytest.fixture(autouse=True)
def no_work(monkeypatch):
    def reached(*args, **kwargs):
        raise _Reached

    monkeypatch.setattr(myriad.runtime, "load", reached)
    monkeypatch.setattr(myriad.runtime, "solve", reached)
    monkeypatch.setattr(myriad.runtime.bench, "run_bench", reached)


def _usage_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("myriad: error: "), err
    return err


_NO_SOLVER = [name for name, cls in METHODS.items() if not cls.uses_solver]
_NO_INTEGRATOR = [name for name, cls in METHODS.items() if not takes_integrator(cls)]
_FIXED_STEP = [name for name, cls in INTEGRATORS.items() if cls.fixed_step]


def test_the_registries_give_combinations_to_refuse():
    # Guards the parametrisations below against silently becoming empty.
    assert "fbsm" in _NO_SOLVER and {"trapezoidal", "hermite_simpson", "fbsm"} <= set(_NO_INTEGRATOR)


@pytest.mark.parametrize("method", _NO_SOLVER)
@pytest.mark.parametrize("solver", list(SOLVERS))
def test_a_solver_for_a_method_that_takes_none_is_refused(capsys, method, solver):
    err = _usage_error(capsys, ["solve", "van_der_pol", "--transcription", method, "--solver", solver])
    assert f"{method} solves Pontryagin's conditions itself and takes no --solver" in err


@pytest.mark.parametrize("method", _NO_INTEGRATOR)
@pytest.mark.parametrize("integrator", _FIXED_STEP)
def test_an_integrator_for_a_method_without_one_is_refused(capsys, method, integrator):
    err = _usage_error(capsys, ["solve", "van_der_pol", "--transcription", method, "--integrator", integrator])
    assert f"not {method}" in err


@pytest.mark.parametrize("intervals", ["0", "-3"])
def test_a_grid_without_intervals_is_refused(capsys, intervals):
    err = _usage_error(capsys, ["solve", "van_der_pol", "--intervals", intervals])
    assert "--intervals must be an integer >= 1" in err


@pytest.mark.parametrize("tolerance", ["0", "-1e-6", "nan"])
def test_a_non_positive_error_tolerance_is_refused(capsys, tolerance):
    err = _usage_error(capsys, ["solve", "van_der_pol", f"--error-tolerance={tolerance}"])
    assert "--error-tolerance must be positive" in err


def _bad_paths(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    return {
        "missing folder": (str(tmp_path / "no" / "such" / "x.json"), "does not exist; create it first"),
        "folder is a file": (str(a_file / "x.json"), "is not a folder"),
        "a folder, not a file": (str(tmp_path), "is a folder, expected a file name"),
    }


@pytest.mark.parametrize("case", ["missing folder", "folder is a file", "a folder, not a file"])
@pytest.mark.parametrize("option", ["--json", "--plot"])
def test_solve_output_paths_are_checked_first(capsys, tmp_path, option, case):
    path, reason = _bad_paths(tmp_path)[case]
    if option == "--plot":
        path = path.replace(".json", ".png")
    err = _usage_error(capsys, ["solve", "van_der_pol", option, path])
    assert f"{option} {path}" in err and reason in err


def test_the_issue_example(capsys):
    err = _usage_error(capsys, ["solve", "van_der_pol", "--json", "/nonexistent/dir/x.json"])
    assert "/nonexistent/dir does not exist" in err


def test_a_plot_in_an_unknown_format_is_refused(capsys, tmp_path):
    err = _usage_error(capsys, ["solve", "van_der_pol", "--plot", str(tmp_path / "x.xyz")])
    assert "unknown image format .xyz" in err and "png" in err


def test_an_unwritable_folder_is_refused(capsys, tmp_path, monkeypatch):
    # Permission bits cannot make a folder unwritable for root (these tests also run as root), so ask os.access,
    # which is what the check trusts, to say no for this folder.
    real_access = os.access
    locked = str(tmp_path)
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == locked else real_access(p, mode))
    err = _usage_error(capsys, ["solve", "van_der_pol", "--json", str(tmp_path / "x.json")])
    assert "not writable" in err
    err = _usage_error(capsys, ["bench", "--plots", str(tmp_path / "plots")])
    assert f"{locked} is not writable" in err


def test_valid_arguments_reach_the_work(tmp_path):
    with pytest.raises(_Reached):
        main(["solve", "van_der_pol", "--transcription", "fbsm", "--json", str(tmp_path / "x.json"),
              "--plot", str(tmp_path / "x.png"), "--error-tolerance", "1e-3"])
    # A plots folder that does not exist yet is created by the bench, parents included.
    with pytest.raises(_Reached):
        main(["bench", "--systems", "van_der_pol", "--json", str(tmp_path / "b.json"),
              "--markdown", str(tmp_path / "b.md"), "--plots", str(tmp_path / "new" / "plots")])


@pytest.mark.parametrize("case", ["missing folder", "folder is a file", "a folder, not a file"])
@pytest.mark.parametrize("option", ["--json", "--markdown"])
def test_bench_output_files_are_checked_first(capsys, tmp_path, option, case):
    path, reason = _bad_paths(tmp_path)[case]
    err = _usage_error(capsys, ["bench", "--systems", "van_der_pol", option, path])
    assert f"{option} {path}" in err and reason in err


def test_bench_plots_under_a_file_is_refused(capsys, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    err = _usage_error(capsys, ["bench", "--plots", str(a_file / "plots")])
    assert f"{a_file} is a file, not a folder" in err


def test_bench_jobs_must_be_positive(capsys):
    err = _usage_error(capsys, ["bench", "--systems", "van_der_pol", "--jobs", "0"])
    assert "--jobs must be at least 1" in err
