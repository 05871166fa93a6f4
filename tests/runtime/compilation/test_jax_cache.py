"""JAX's persistent compilation cache (``myriad.runtime.compilation.jax_cache``): where it goes, and that a second
process reuses it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from myriad.runtime.compilation.jax_cache import DEFAULT_CACHE_DIR, ENV_VAR, compilation_cache_dir

# A fresh interpreter (JAX reads the cache folder once per process) that configures JAX as the `myriad` command line
# does for ARGV, compiles one small program and reports the cache hits JAX records and the folder in use.
_CHILD = textwrap.dedent("""
    import json, sys
    import jax
    from myriad.runtime.cli import _configure_jax, _parser

    hits = []
    jax.monitoring.register_event_listener(
        lambda event, **kw: hits.append(event) if event == "/jax/compilation_cache/cache_hits" else None)
    _configure_jax(_parser().parse_args(sys.argv[1:]))
    value = jax.jit(lambda x: jax.numpy.sin(x) @ x.T + 1.0)(jax.numpy.ones((3, 3)))
    print(json.dumps({"hits": len(hits), "dir": jax.config.jax_compilation_cache_dir, "value": float(value[0, 0])}))
""")


def _child(*argv: str, env: dict | None = None) -> dict:
    environment = {k: v for k, v in os.environ.items() if k not in (ENV_VAR, "JAX_COMPILATION_CACHE_DIR")}
    environment.update(env or {})
    out = subprocess.run([sys.executable, "-c", _CHILD, *argv], capture_output=True, text=True, env=environment,
                         timeout=300, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _entries(folder) -> set[str]:
    return set(os.listdir(folder)) if os.path.isdir(folder) else set()


def test_folder_resolution(monkeypatch, tmp_path):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert compilation_cache_dir() == os.path.expanduser(DEFAULT_CACHE_DIR)
    assert compilation_cache_dir("~/x") == os.path.join(os.path.expanduser("~"), "x")
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    assert compilation_cache_dir() == str(tmp_path / "env")
    # An explicit folder beats the environment.
    assert compilation_cache_dir(str(tmp_path / "arg")) == str(tmp_path / "arg")
    for off in ("off", "none", "0", ""):
        monkeypatch.setenv(ENV_VAR, off)
        assert compilation_cache_dir() is None


@pytest.mark.slow
def test_second_process_reuses_the_cache(tmp_path):
    folder = tmp_path / "jax"
    first = _child("solve", "van_der_pol", "--cache-dir", str(folder))
    written = _entries(folder)
    assert first["dir"] == str(folder) and first["hits"] == 0 and written, "the first process filled the cache"
    second = _child("bench", env={ENV_VAR: str(folder)})  # the same folder, chosen through the environment
    assert second["dir"] == str(folder)
    assert second["hits"] >= 1, "the second process compiled again instead of reading the cache"
    assert _entries(folder) == written, "nothing new was compiled"
    assert second["value"] == first["value"]


@pytest.mark.slow
def test_no_cache_leaves_jax_without_a_folder(tmp_path):
    result = _child("solve", "van_der_pol", "--no-cache", env={ENV_VAR: str(tmp_path / "jax")})
    assert result["dir"] is None and result["hits"] == 0
    assert not (tmp_path / "jax").exists()


def test_every_command_takes_the_cache_options():
    from myriad.runtime.cli import _parser

    parser = _parser()
    for command in (["solve", "x"], ["bench"], ["sysid", "x"], ["e2e", "x"], ["sweep", "x"]):
        assert parser.parse_args([*command, "--no-cache"]).no_cache
        assert parser.parse_args([*command, "--cache-dir", "d"]).cache_dir == "d"
    assert parser.parse_args(["bench", "--solver", "interior_point"]).solver == "interior_point"
