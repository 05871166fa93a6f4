"""The benchmark scripts: each measures one claim and prints its figures. Run one from the repository root as
``python -m bench.NAME [--help]``; bench/README.md lists them, what each prints and how long it takes.

Importing the package sets what every bench shares, before any of them imports JAX (``python -m`` runs this first):

- float64: JAX reads ``JAX_ENABLE_X64`` when it loads, so the scripts never set it themselves (the published figures
  are float64 figures; ``rl_throughput`` alone measures JAX's float32 default unless ``--x64``, and says so);
- ``STARTED``, the process's start, for the benches that report their import time.

Each script sets its own device and BLAS-thread defaults (``JAX_PLATFORMS``, ``OPENBLAS_NUM_THREADS``), which differ
between them for reasons given there, before it imports JAX or NumPy.
"""

import os
import sys
import time

STARTED = time.perf_counter()

os.environ["JAX_ENABLE_X64"] = "1"  # read when JAX loads; also inherited by the rows run in spawned processes
if "jax" in sys.modules:  # JAX already loaded (a test imported a bench module): the variable came too late
    sys.modules["jax"].config.update("jax_enable_x64", True)
