"""bench/ipm_scaling.py on a tiny setting: Van der Pol by trapezoidal collocation at N = 10 and 20, myriad's IPOPT,
CasADi + IPOPT (and, marked slow, the interior point) agree on the discrete optimum, the growth exponent is fitted,
the JSON is complete; the limit skips larger N; bad input is exit 2 naming the flag."""

import json

import pytest

pytest.importorskip("casadi")

from bench import ipm_scaling as scaling  # noqa: E402  (after the skip: the bench imports casadi)


def _tiny_run(tmp_path, solvers):
    out = tmp_path / "scaling.json"
    assert scaling.main(["--transcriptions", "trapezoidal", "--intervals", "10", "20", "--repeat", "1",
                         "--solvers", *solvers, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert [r["intervals"] for r in data["rows"]] == [10, 20]
    for row in data["rows"]:
        recs = row["solvers"]
        assert set(recs) == set(solvers)
        assert all(r["converged"] and len(r["warm"]) == 1 and r["cold_seconds"] > 0 for r in recs.values()), recs
        assert row["max_relative_cost_difference"] < 1e-6 and not row["costs_differ"]
    # the discrete optimum moves with N (trapezoidal is order 2): a row's agreement is not a repeated answer
    c10, c20 = (r["solvers"]["ipopt"]["cost"] for r in data["rows"])
    assert abs(c10 - c20) > 1e-4
    fits = data["exponents"]["trapezoidal"]
    assert data["fit_from"] == 10 and all(f["points"] == 2 and f["exponent"] is not None for f in fits.values())
    assert set(data["compile_exponents"]["trapezoidal"]) == set(solvers)
    return data


def test_ipopt_and_casadi_agree_and_fit(tmp_path, capsys):
    """A few seconds: myriad's IPOPT and the CasADi peer on trapezoidal collocation, the table and the JSON."""
    data = _tiny_run(tmp_path, ["ipopt", "casadi"])
    assert data["openblas_num_threads"] is not None and len(data["load_before"]) == 3
    text = capsys.readouterr().out
    assert "| trapezoidal | 20 |" in text and "Growth exponent" in text and "load average" in text


@pytest.mark.slow  # about 25 s under load: the interior point compiles its program at each N
def test_the_interior_point_agrees_with_both(tmp_path):
    data = _tiny_run(tmp_path, ["interior_point", "ipopt", "casadi"])
    assert all(r["solvers"]["interior_point"]["compile_seconds"] > 0 for r in data["rows"])


def test_the_limit_skips_larger_n():
    states = {"history": [(100, 1.0, 0.0), (200, 8.0, 0.0)], "skip": None}  # N^3: 64 s predicted at 400
    assert scaling.skip_reason(states, 400, 120.0) is None
    assert "over the limit at N=800" in scaling.skip_reason(states, 800, 120.0)
    assert scaling.skip_reason(states, 1600, 1e9) == states["skip"]  # once skipped, larger N stay skipped


def test_a_compile_that_does_not_grow_is_not_extrapolated():
    """20 s of compile at every N and a linear 0.1 -> 0.4 s solve: 21.6 s predicted at 1600, not 4 x 20; a build
    that grows (CasADi's single shooting: 0.33 -> 16 s) is extrapolated as it grew."""
    states = {"history": [(100, 0.1, 20.0), (400, 0.4, 20.0)], "skip": None}
    assert scaling.predicted_seconds(states["history"], 1600)[0] == pytest.approx(21.6)
    assert scaling.skip_reason(states, 1600, 90.0) is None
    growing = [(100, 0.11, 0.33), (400, 1.5, 16.0)]
    assert scaling.predicted_seconds(growing, 1600)[0] > 500.0


def test_kkt_per_transcription():
    _, ip = scaling._checked(["--kkt", "dense", "--kkt", "trapezoidal=banded"])
    assert ip["trapezoidal"].kkt == "banded" and ip["hermite_simpson"].kkt == ip["single_shooting"].kkt == "dense"


@pytest.mark.parametrize("argv, flag", [
    (["--intervals", "1", "4"], "--intervals"),
    (["--intervals", "4", "4"], "--intervals"),
    (["--repeat", "0"], "--repeat"),
    (["--system", "no_such_system"], "--system"),
    (["--kkt", "no_such_method"], "--kkt"),
    (["--kkt", "collocation=banded"], "--kkt"),
    (["--transcriptions", "collocation"], "--transcriptions"),
    (["--max-seconds", "0"], "--max-seconds"),
    (["--json", "/no/such/folder/out.json"], "--json"),
])
def test_bad_input_is_exit_2(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        scaling.main(argv)
    assert exc.value.code == 2
    assert flag in capsys.readouterr().err
