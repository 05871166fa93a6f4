"""bench/batch_throughput.py on a tiny setting: the parametric CasADi peer of Hermite-Simpson and multiple shooting,
re-posed member by member on one built NLP, reaches the same discrete optimum as myriad's IPOPT at each member's
parameters and x0; (marked slow) the whole bench with the batched interior point reports every member's agreement
in its JSON; bad input is exit 2 naming the flag."""

import json
import os

import pytest

pytest.importorskip("casadi")

SYSTEM = "mould_fungicide"  # one state, one control: the cheapest spec with parameters


@pytest.fixture(scope="module")
def bt():
    """The bench module, imported with the environment it sets for its own process (host devices, BLAS threads)
    undone, so that later tests and the processes they start do not inherit it."""
    saved = {k: os.environ.get(k) for k in ("XLA_FLAGS", "OPENBLAS_NUM_THREADS")}
    from bench import batch_throughput

    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    return batch_throughput


@pytest.mark.parametrize("transcription", ["hermite_simpson", "multiple_shooting"])
def test_the_parametric_casadi_peer_agrees_with_myriad_member_by_member(bt, transcription):
    from myriad.runtime import load
    from myriad.runtime.solvers import Ipopt

    system = load(SYSTEM)
    params, x0 = bt.make_batch(system, 3, 0.1, 0)
    peer = bt.casadi_one_at_a_time(system, SYSTEM, transcription, 6, params, x0, 3)
    mine = bt.one_at_a_time(system, bt.SETTINGS[transcription](6), Ipopt(), params, x0, 3)
    assert all(peer["converged"]) and all(mine["converged"]), (peer["status"], mine["status"])
    for a, b in zip(peer["costs"], mine["costs"]):
        assert a == pytest.approx(b, rel=1e-7)
    # the members are different problems (so agreement is not one repeated answer): the costs spread by several %
    assert max(peer["costs"]) - min(peer["costs"]) > 0.05 * abs(peer["costs"][0])
    assert peer["compile_seconds"] > 0 and peer["seconds"] > 0 and len(peer["iterations"]) == 3


@pytest.mark.slow  # 3-4 s each on a quiet machine, more under load: the interior point compiles a batched program
@pytest.mark.parametrize("transcription", ["hermite_simpson", "multiple_shooting"])
def test_the_whole_bench_reports_every_member(bt, transcription, tmp_path, capsys):
    out = tmp_path / "batch.json"
    assert bt.main(["--systems", SYSTEM, "--transcription", transcription, "--grid", "6", "--batch", "4",
                    "--subset", "2", "--repeat", "1", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    (record,) = data["systems"]
    rows = record["rows"]
    assert len(rows) == 3 and bt.CASADI in rows and all(r["converged"] == r["n"] for r in rows.values()), rows
    members = record["members"]
    assert not members["disagreements"] and not any(members["not_converged"].values())
    assert all(d is not None and d < 1e-7 for d in members["max_relative_difference_to_casadi"].values())
    (kkt,) = record["batched_kkt"].values()
    assert kkt in ("dense", "banded", "riccati") and f"kkt {kkt}" in next(iter(rows))
    assert len(data["load_before"]) == len(data["load_after"]) == 3 and data["head"]
    assert "none differs by more than" in capsys.readouterr().out


@pytest.mark.parametrize("argv, flag", [
    (["--grid", "1"], "--grid"),
    (["--batch", "0"], "--batch"),
    (["--systems", "no_such_system"], "--systems"),
    (["--transcription", "collocation"], "--transcription"),
    (["--json", "/no/such/folder/out.json"], "--json"),
])
def test_bad_input_is_exit_2(bt, argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        bt.main(argv)
    assert exc.value.code == 2
    assert flag in capsys.readouterr().err
