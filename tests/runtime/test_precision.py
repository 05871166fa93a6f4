"""The solving entry points refuse JAX's default float32 with the fix, instead of failing silently.

The suite's conftest enables float64, so only a fresh subprocess without the x64 line shows what a new user gets.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_SCRIPT = """
import jax
from myriad.runtime import SLSQP, Extragradient, ForwardBackwardSweep, Ipopt, SingleShooting, load, solve, solve_batch
from myriad.runtime.data import default_data
from myriad.runtime.solve import transcribe
vdp = load("van_der_pol")
nlp, data = transcribe(vdp, SingleShooting(intervals=10)), default_data(vdp)
for entry, call in (("solve", lambda: solve(vdp)),
                    ("solve_batch", lambda: solve_batch(vdp, x0=[[1.0, 0.0]])),
                    ("the pure solver extragradient", lambda: Extragradient().solve_fn(
                        nlp)(data, None)),
                    ("Ipopt.solve", lambda: Ipopt().solve(nlp, data)),
                    ("SLSQP.solve", lambda: SLSQP().solve(nlp, data)),
                    ("ForwardBackwardSweep.solve", lambda: ForwardBackwardSweep().solve(vdp))):
    try:
        call()
    except RuntimeError as e:
        print(entry, "REFUSED:", e)
    else:
        print(entry, "RAN")
"""


def _fresh(script: str) -> str:
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    env["JAX_PLATFORMS"] = "cpu"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_solve_in_a_fresh_float32_process_refuses_with_the_fix():
    out = _fresh(_SCRIPT)
    for entry in ("solve", "solve_batch", "the pure solver extragradient", "Ipopt.solve", "SLSQP.solve",
                  "ForwardBackwardSweep.solve"):
        line = next(line for line in out.splitlines() if line.startswith(entry + " "))
        assert "REFUSED" in line, out
        assert f"{entry} needs float64" in line
        assert 'jax.config.update("jax_enable_x64", True)' in line


def test_the_message_does_not_refuse_float64():
    from myriad.runtime.data import require_float64

    require_float64("solve")  # the suite runs in float64: no error


@pytest.mark.parametrize("flag", ["JAX_ENABLE_X64"])
def test_the_environment_variable_is_a_fix_too(flag):
    env = {**os.environ, flag: "1", "JAX_PLATFORMS": "cpu"}
    script = "from myriad.runtime.data import require_float64; require_float64('solve'); print('OK')"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    assert out.stdout.strip() == "OK", out.stderr
