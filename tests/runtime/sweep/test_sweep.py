"""Sweeps: method parsing and checks, the pure task and its failure records, the tables, the CLI, and the process and
Ray backends (a real local Ray cluster) giving the serial backend's records exactly."""

import contextlib
import csv
import io
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import pytest

from myriad.runtime.cli import main
from myriad.runtime.sweep import (
    BACKENDS,
    KINDS,
    AbstractBackend,
    AbstractKind,
    ProcessBackend,
    RayBackend,
    SerialBackend,
    SweepConfig,
    comparable,
    parse_method,
    run_sweep,
)
from myriad.runtime.sweep.table import columns, csv_text, markdown
from myriad.runtime.sweep.tasks import error_record, run

# Two cheap methods: a seeded start state (so the seeds differ) and a solve cut off after one iteration (a failure).
PERTURBED = "pert=solve:transcription=trapezoidal,intervals=10,x0_std=0.1,resimulate=false"
CUT = 'cut=solve:transcription=trapezoidal,intervals=10,solver_options={"max_iter":1},resimulate=false'
SYSTEMS, SEEDS = ("simple_case", "van_der_pol"), (0, 1)


def _config(cache_dir=None) -> SweepConfig:
    return SweepConfig(SYSTEMS, [PERTURBED, CUT], SEEDS, cache_dir=cache_dir)


@pytest.fixture(scope="module")
def serial_records():
    return run_sweep(_config(), SerialBackend())


def test_method_text_is_parsed_into_checked_settings():
    m = parse_method('trap=solve:transcription=trapezoidal,intervals=20,solver_options={"tol":1e-6,"max_iter":50}')
    assert (m.name, m.kind) == ("trap", "solve")
    assert m.settings["intervals"] == 20 and m.settings["solver_options"] == {"tol": 1e-6, "max_iter": 50}
    assert m.settings["resimulate"] is True and m.settings["solver"] is None  # completed with the defaults
    node = parse_method("sysid:model=node,hidden=[8,8],epochs=3")
    assert node.name == "sysid:model=node,hidden=[8,8],epochs=3" and node.settings["hidden"] == [8, 8]
    assert parse_method("solve").settings == parse_method("published=solve").settings


@pytest.mark.parametrize("text, words", [
    ("optimise", "unknown method kind 'optimise'"),
    ("solve:transcriptoin=trapezoidal", "unknown settings ['transcriptoin']"),
    ("solve:transcription=collocation", "unknown transcription 'collocation'"),
    ("solve:intervals=0", "intervals must be an integer >= 1"),
    ("solve:transcription=fbsm,solver=ipopt", "takes no solver"),
    ('solve:solver_options={"max_iters":5}', "solver_options for ipopt"),
    ("solve:x0_std=-1", "x0_std must be a finite number >= 0"),
    ("solve:intervals", "expected KEY=VALUE"),
    ("solve:hidden=[1,2", "unbalanced"),
    ("sysid:model=node,method=least_squares", "least squares fits parametric models only"),
    ("sysid:hidden=[0]", "hidden must be a list of layer widths"),
    ("sysid:noise=2", "noise must be a fraction of the state range in [0, 1]"),
    ("sysid:max_gap=-0.1", "max_gap must be a finite fraction >= 0 or None"),
])
def test_bad_methods_are_refused_with_the_reason(text, words):
    with pytest.raises(ValueError) as info:
        parse_method(text)
    assert words in str(info.value)


def test_sweep_config_refuses_repeats_and_bad_seeds_and_orders_tasks():
    with pytest.raises(ValueError, match="repeated pert"):
        SweepConfig(["simple_case"], [PERTURBED, PERTURBED])
    with pytest.raises(ValueError, match="repeated 1"):
        SweepConfig(["simple_case"], seeds=[1, 1])
    with pytest.raises(ValueError, match="integers >= 0"):
        SweepConfig(["simple_case"], seeds=[-1])
    tasks = _config("~/c").tasks()
    assert [(t["system"], t["method"]["name"], t["seed"]) for t in tasks[:3]] == [
        ("simple_case", "pert", 0), ("simple_case", "pert", 1), ("simple_case", "cut", 0)]
    assert [t["index"] for t in tasks] == list(range(8)) and tasks[0]["cache_dir"] == "~/c"
    json.dumps(tasks)  # a task travels to any worker as JSON-ready data
    with pytest.raises(ValueError, match="declares no learnable parameters"):
        SweepConfig(["simple_case"], ["sysid"]).check_systems()


def test_a_sysid_needing_bounds_the_spec_lacks_is_refused_before_any_work(tmp_path):
    spec = tmp_path / "free.yaml"  # bioreactor without its state's bounds
    text = (Path(__file__).resolve().parents[3] / "specs" / "bioreactor.yaml").read_text()
    spec.write_text(text.replace("bounds: [0, 1], ", "").replace("name: bioreactor", "name: free"))
    with pytest.raises(ValueError, match="state `x` has lower bound -inf.*noise_scale='spread'"):
        SweepConfig([str(spec)], ["sysid:noise=0.05"]).check_systems()
    SweepConfig([str(spec)], ['sysid:noise=0.05,sampling={"noise_scale":"spread"}']).check_systems()


def test_a_sysid_adding_noise_to_a_specs_declared_noise_is_refused_before_any_work():
    spec = str(Path(__file__).resolve().parents[1] / "sysid" / "noisy_oscillator.yaml")  # schema 3, `noise:`
    with pytest.raises(ValueError, match="declares its noise.*declared_noise=false"):
        SweepConfig([spec], ["sysid:noise=0.05"]).check_systems()
    SweepConfig([spec], ["sysid", 'sysid:noise=0.05,declared_noise=false,sampling={"noise_scale":"spread"}']
                ).check_systems()
    with pytest.raises(ValueError, match="declared expects true or false"):
        SweepConfig([spec], ["mpc:declared=1"])


def test_every_kind_and_backend_is_registered():
    import importlib
    import inspect
    import pkgutil

    import myriad.runtime.sweep as sweep

    found = {base: set() for base in (AbstractKind, AbstractBackend)}
    for info in pkgutil.walk_packages(sweep.__path__, prefix=sweep.__name__ + "."):
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            for base in found:
                if inspect.isclass(obj) and issubclass(obj, base) and not inspect.isabstract(obj) \
                        and obj.__module__ == module.__name__:
                    found[base].add(obj)
    assert found[AbstractKind] == set(KINDS.values()) and all(KINDS[c.name] is c for c in found[AbstractKind])
    assert found[AbstractBackend] == set(BACKENDS.values())
    assert all(BACKENDS[c.name] is c for c in found[AbstractBackend])


def test_serial_records_report_successes_failures_and_seeds(serial_records):
    recs = {(r["system"], r["method"], r["seed"]): r for r in serial_records}
    assert [r["index"] for r in serial_records] == list(range(8))
    ok = recs["van_der_pol", "pert", 0]
    assert ok["status"] == "ok" and ok["converged"] and ok["solver_status"] == "converged"
    # The seed moved the start state (clipped to the bounds), and so the optimum.
    assert ok["x0"] != recs["van_der_pol", "pert", 1]["x0"] and ok["cost"] != recs["van_der_pol", "pert", 1]["cost"]
    cut = recs["van_der_pol", "cut", 0]
    assert cut["status"] == "failed" and not cut["converged"] and cut["solver_status"] == "iteration_limit"
    assert cut["iterations"] == 1 and "iterations" in cut["message"]
    json.dumps(serial_records, allow_nan=False)


def test_a_task_that_raises_is_an_error_record_not_a_crash():
    # A parametric fit of a system without learnable parameters raises inside the worker (no driver check here).
    task = SweepConfig(["simple_case"], ["sysid"], cache_dir=None).tasks()[0]
    rec = run(task)
    assert rec["status"] == "error" and rec["error_type"] == "ValueError"
    assert "learnable" in rec["message"] and "Traceback" in rec["traceback"]
    assert (rec["system"], rec["method"], rec["kind"], rec["seed"]) == ("simple_case", "sysid", "sysid", 0)
    json.dumps(rec, allow_nan=False)
    unknown = run({**task, "system": "no_such_system"})
    assert unknown["status"] == "error" and "no_such_system" in unknown["message"]


def test_the_table_names_a_spec_by_its_system_name_not_its_path(tmp_path, monkeypatch):
    monkeypatch.setenv("MYRIAD_CACHE", str(tmp_path))  # the compiled spec goes here, not to the user's cache
    (tmp_path / "mine").mkdir()
    spec = tmp_path / "mine" / "simple_case.yaml"
    spec.write_text((Path(__file__).parents[3] / "specs" / "simple_case.yaml").read_text())
    task = SweepConfig([str(spec)], [PERTURBED], cache_dir=None).tasks()[0]
    rec = run(task)
    assert rec["status"] == "ok" and rec["system"] == str(spec) and rec["system_name"] == "simple_case"
    row = markdown([rec]).splitlines()[2]
    assert row.startswith("| simple_case | pert | 0 | ok |") and "yaml" not in row
    failed = markdown([error_record(task, ValueError("no"))])  # failed before loading: the path
    assert f"- {spec} / pert / seed 0: error" in failed


def test_a_record_a_backend_lost_is_reported_as_an_error():
    class Lossy(AbstractBackend):
        name = "lossy"

        def map(self, tasks):  # hands back the first task only, as a dying worker pool might
            yield {"index": tasks[0]["index"], "status": "ok"}

    recs = run_sweep(SweepConfig(["simple_case"], ["solve"], seeds=[0, 1]), Lossy())
    assert [r["status"] for r in recs] == ["ok", "error"]
    assert "lossy backend returned no record" in recs[1]["message"] and recs[1]["seed"] == 1


def test_tables_markdown_and_csv(serial_records):
    text = markdown(serial_records)
    lines = text.splitlines()
    assert lines[0].startswith("| system | method | seed | status | cost |") and lines[0].endswith("| wall s |")
    assert len([ln for ln in lines if ln.startswith("| ")]) == 1 + 8
    assert sum(ln.startswith("- ") and ": failed: " in ln for ln in lines) == 4  # the cut solves, with the reason
    assert columns(serial_records)[4:-1] == list(KINDS["solve"].columns)
    rows = list(csv.DictReader(io.StringIO(csv_text(serial_records))))
    assert len(rows) == 8 and float(rows[0]["cost"]) == serial_records[0]["cost"]
    assert json.loads(rows[0]["settings"]) == serial_records[0]["settings"]


@pytest.mark.parametrize("argv, words", [
    (["--backend", "serial", "--address", "h:1"], "--address applies to --backend ray"),
    (["--workers", "2"], "--workers applies to --backend process or ray"),
    (["--backend", "process", "--workers", "0"], "--workers must be at least 1"),
    (["--method", "solve:intervals=0"], "intervals must be an integer >= 1"),
    (["--method", "sysid"], "simple_case declares no learnable parameters"),
    (["--seeds", "0", "0"], "--seeds must differ: repeated 0"),
    (["--seeds", "-1"], "--seeds must be integers >= 0, got -1"),
    (["--method", "no_such_kind"], "--method: unknown method kind 'no_such_kind'; known: solve, sysid, mpc"),
    (["--method", "a=solve", "a=solve:intervals=9"], "--method must differ: repeated a; give each method its own"),
    (["--json", "missing-folder/r.json"], "the folder of missing-folder/r.json does not exist"),
])
def test_cli_checks_arguments_before_any_work(argv, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", "simple_case", *argv]) == 2
    assert words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_refuses_an_unknown_system_before_any_work(capsys):
    assert main(["sweep", "simple_case", "no_such_system"]) == 2
    assert "'no_such_system' is neither a shipped system" in capsys.readouterr().err


def test_cli_ray_without_a_cluster_is_a_usage_error_with_the_fix(capsys, monkeypatch):
    def no_cluster(*args, **kwargs):  # what ray.init raises when nothing runs at the address (no cluster started)
        raise ConnectionError("Could not find any running Ray instance.")

    # A stand-in module, not the real one patched: Ray reads its authentication settings once, when first imported,
    # and the real-cluster test below sets them before it imports Ray.
    fake = types.ModuleType("ray")
    fake.is_initialized, fake.init = (lambda: False), no_cluster
    monkeypatch.setitem(sys.modules, "ray", fake)
    assert main(["sweep", "simple_case", "--backend", "ray", "--address", "auto", "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert "--address auto: no Ray cluster" in err and "ray start --head" in err
    assert "internal error" not in err


def test_cli_prints_one_table_and_writes_json_csv_markdown(serial_records, capsys, tmp_path):
    j, c, m = tmp_path / "s.json", tmp_path / "s.csv", tmp_path / "s.md"
    rc = main(["sweep", *SYSTEMS, "--method", PERTURBED, CUT, "--seeds", "0", "1", "--no-cache",
               "--json", str(j), "--csv", str(c), "--markdown", str(m)])
    out = capsys.readouterr().out
    assert rc == 1  # the cut solves failed
    assert out.count("| system | method |") == 1 and "4 / 8 ok, 4 failed, 0 raised" in out
    assert m.read_text() in out
    doc = json.loads(j.read_text())
    assert doc["format"] == "myriad.sweep" and doc["config"]["seeds"] == [0, 1]
    assert [comparable(r) for r in doc["records"]] == [comparable(r) for r in serial_records]
    assert len(list(csv.DictReader(io.StringIO(c.read_text())))) == 8


@pytest.mark.slow
def test_process_backend_gives_the_serial_records(serial_records, tmp_path):
    cache = tmp_path / "jax-cache"
    recs = run_sweep(_config(str(cache)), ProcessBackend(workers=2))
    assert [comparable(r) for r in recs] == [comparable(r) for r in serial_records]
    assert os.getpid() not in {r["pid"] for r in recs}
    assert any(cache.iterdir())  # the workers wrote the shared compilation cache


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    """Stop this cluster's processes (its own process group); ``ray stop`` would end every Ray process on the
    machine, other users' clusters too."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=30)
    deadline = time.monotonic() + 10
    try:
        while time.monotonic() < deadline:
            os.killpg(proc.pid, 0)  # raises once the group is empty
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGKILL)  # what a graceful stop left behind
        proc.wait(timeout=10)
    except ProcessLookupError:
        pass


@pytest.fixture
def ray_address(monkeypatch):
    # Token authentication with a token of this test's own, in the cluster's and this driver's environment: with
    # the mode unset, `ray start` turns it on when ~/.ray/auth_token exists, and a driver given an address does not.
    monkeypatch.setenv("RAY_AUTH_MODE", "token")
    monkeypatch.setenv("RAY_AUTH_TOKEN", secrets.token_hex(32))
    port = _free_port()
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths must fit in 107 bytes
    log = Path(temp) / "start.log"
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0"}
    command = [str(Path(sys.executable).with_name("ray")), "start", "--head", "--block", f"--port={port}",
               "--num-cpus=2", "--object-store-memory=100000000", "--include-dashboard=false",
               f"--temp-dir={temp}", "--disable-usage-stats"]
    with open(log, "wb") as out:
        proc = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while b"Ray runtime started" not in log.read_bytes():
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start did not start:\n{log.read_text()}")
            time.sleep(0.2)
        yield f"127.0.0.1:{port}"
    finally:
        _stop(proc)
        shutil.rmtree(temp, ignore_errors=True)


@pytest.mark.slow
def test_ray_backend_on_a_real_local_cluster_gives_the_serial_records(serial_records, ray_address, tmp_path):
    import ray

    recs = run_sweep(_config(str(tmp_path / "jax-cache")), RayBackend(address=ray_address))
    assert not ray.is_initialized()  # the backend disconnected from the cluster it connected to
    assert [comparable(r) for r in recs] == [comparable(r) for r in serial_records]
    assert os.getpid() not in {r["pid"] for r in recs}
